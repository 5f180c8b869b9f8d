function s = ol_check_settings(s)
% OL_CHECK_SETTINGS  The settings after filter_settings.m, checked: matrices 3x3, vectors of 3
% (as columns), numbers; an error names the field.
  if ~isstruct(s) || ~isscalar(s)
    error('OrientationLab:settings', 'filter_settings must return a struct (got a %s)', class(s));
  end
  for name = {'Rw', 'Ra', 'Rm'}
    v = s.(name{1});
    if ~isnumeric(v) || ~isreal(v) || ~isequal(size(v), [3, 3]) || ~all(isfinite(v(:)))
      error('OrientationLab:settings', 'filter_settings: s.%s must be a finite 3x3 matrix (got %s)', ...
            name{1}, describe(v));
    end
    s.(name{1}) = double(v);
  end
  for name = {'g0', 'm0', 'gyr_bias'}
    v = s.(name{1});
    if strcmp(name{1}, 'm0') && isempty(v)
      s.m0 = [];
      continue;
    end
    if ~isnumeric(v) || ~isreal(v) || numel(v) ~= 3 || ~all(isfinite(v(:)))
      error('OrientationLab:settings', 'filter_settings: s.%s must be 3 finite numbers (got %s)', ...
            name{1}, describe(v));
    end
    s.(name{1}) = reshape(double(v), 3, 1);
  end
  for name = {'acc_gate', 'mag_gate', 'mag_alpha', 'max_dt', 'gyr_hold_s', 'no_gyro_random_walk', ...
              'initial_attitude_std', 'rest_gyr_threshold', 'rest_acc_threshold', 'rest_min_duration'}
    v = s.(name{1});
    if ~isnumeric(v) || ~isreal(v) || ~isscalar(v) || isnan(v)
      error('OrientationLab:settings', 'filter_settings: s.%s must be a number (got %s)', ...
            name{1}, describe(v));
    end
    s.(name{1}) = double(v);
  end
end

function text = describe(v)
  if isnumeric(v) || islogical(v)
    text = sprintf('%s %s', strjoin(arrayfun(@num2str, size(v), 'UniformOutput', false), 'x'), class(v));
  else
    text = sprintf('a %s', class(v));
  end
end
