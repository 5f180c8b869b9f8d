function [file, line, fn, index] = ol_where(ctx, err)
% OL_WHERE  The innermost frame of an error's stack in the filter's own files: its file (in
% the user's folder), line and function ('' and NaN when the error did not arise in them).
  file = '';
  line = NaN;
  fn = '';
  index = 0;
  for i = 1:numel(err.stack)
    frame = err.stack(i);
    mapped = ol_user_path(ctx, frame.file);
    if ~isempty(mapped)
      file = mapped;
      line = frame.line;
      fn = frame.name;
      index = i;
      return;
    end
  end
end
