function [ctx, keep, stop] = ol_failed(ctx, err, name, t)
% OL_FAILED  An error in a call of the student's function `name`. 'Not written yet'
% (OrientationLab:notWritten) skips the function from now on (keep false); any other error
% pauses the filter (stop true, ctx.problem).
  keep = true;
  stop = true;
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
