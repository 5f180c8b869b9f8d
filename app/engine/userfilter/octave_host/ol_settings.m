function s = ol_settings(wire)
% OL_SETTINGS  The settings struct a filter's functions see, from Orientation Lab's active
% settings (Calibrate's results, a profile, --settings): the course's names, column vectors.
  s = struct();
  s.g = wire.g;
  s.g0 = column(wire.g0);
  s.m0 = column(wire.m0);
  s.Rw = wire.Rw;
  s.Ra = wire.Ra;
  s.Rm = wire.Rm;
  s.gyr_bias = column(wire.gyr_bias);
  s.acc_gate = wire.acc_gate;
  s.mag_gate = wire.mag_gate;
  s.mag_alpha = wire.mag_alpha;
  e = wire.ekf;
  names = {'max_dt', 'gyr_hold_s', 'no_gyro_random_walk', 'initial_attitude_std', ...
           'rest_gyr_threshold', 'rest_acc_threshold', 'rest_min_duration'};
  for i = 1:numel(names)
    value = e.(names{i});
    if ischar(value)
      value = str2double(value);      % "inf"
    end
    s.(names{i}) = value;
  end
end

function v = column(v)
  if isempty(v)
    v = [];
  else
    v = reshape(double(v), [], 1);
  end
end
