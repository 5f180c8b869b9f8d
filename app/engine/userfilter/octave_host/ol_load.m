function ctx = ol_load(code_dir, folder, wire)
% OL_LOAD  Load the filter's folder: which of the course's functions it has (a missing file is
% a step not written yet), whether it has its own outlier tests (acc_outlier.m, mag_outlier.m)
% and settings (filter_settings.m), each of those files parsed (a syntax error does not load);
% then the settings and a fresh state.
  ctx = struct();
  ctx.code_dir = code_dir;
  ctx.code_real = canonicalize_file_name(code_dir);
  ctx.folder = folder;
  ctx.problem = NaN;
  ctx.notes = {};
  ctx.missing = struct('tu_qw', false, 'mu_g', false, 'mu_m', false, 'mu_normalizeQ', false);
  ctx.has = struct('acc_outlier', false, 'mag_outlier', false, 'filter_settings', false);
  ctx.s = [];
  ctx.state = [];
  listing = dir(fullfile(code_dir, '*.m'));
  present = {listing.name};
  course = fieldnames(ctx.missing);
  optional = fieldnames(ctx.has);
  found = 0;
  for name = [course; optional]'
    file = [name{1}, '.m'];
    if any(strcmp(present, file))
      try
        __parse_file__(fullfile(code_dir, file));
      catch err
        ctx.problem = ol_error_problem(ctx, err, name{1}, NaN, 'load');
        return;
      end
      if isfield(ctx.has, name{1})
        ctx.has.(name{1}) = true;
      else
        found = found + 1;
      end
    else
      if isfield(ctx.missing, name{1})
        ctx.missing.(name{1}) = '';
      end
      other = present(strcmpi(present, file));
      if ~isempty(other)
        ctx = ol_note(ctx, sprintf('%s is not used: the function must be called %s (case matters)', ...
                                   other{1}, name{1}));
      end
    end
  end
  if found == 0
    message = sprintf(['%s has none of tu_qw.m, mu_g.m, mu_m.m, mu_normalizeQ.m: a MATLAB filter ', ...
                       'is a folder of the course''s functions (orientation-lab new-filter --matlab ', ...
                       'DIR writes one)'], folder);
    ctx.problem = ol_problem('load', message, message, folder, NaN, NaN, NaN);
    return;
  end
  ctx = ol_configure(ctx, wire);
end
