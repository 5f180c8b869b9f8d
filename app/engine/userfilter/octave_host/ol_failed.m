function [ctx, keep, stop] = ol_failed(ctx, err, name, t, x, P)
% OL_FAILED  An error in a call of the student's function `name` (x and P: what the loop holds
% after it). 'Not written yet' (OrientationLab:notWritten) skips the function from now on (keep
% false); a state the function returned that is not a 4x1 x and 4x4 P (the loop's check of it
% failed) or any other error pauses the filter (stop true, ctx.problem).
  keep = true;
  stop = true;
  if nargin >= 6 && any(strcmp(name, {'tu_qw', 'mu_g', 'mu_m', 'mu_normalizeQ'})) ...
     && ~ol_good_state(x, P)
    ctx.problem = ol_state_problem(ctx, name, x, P, t);
    return;
  end
  if strcmp(err.identifier, 'OrientationLab:notWritten')
    keep = false;
    stop = false;
    [file, line] = ol_where(ctx, err);
    where = '';
    if ~isempty(file)
      [~, base, ext] = fileparts(file);
      where = sprintf('%s%s:%d', base, ext, line);
    end
    if isfield(ctx.missing, name)
      ctx.missing.(name) = where;
    else
      ctx = ol_note(ctx, sprintf('%s is not written yet: the course''s test is used', name));
    end
    return;
  end
  ctx.problem = ol_error_problem(ctx, err, name, t, 'exception');
end
