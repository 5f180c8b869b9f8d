function p = ol_problem(kind, message, details, file, line, fn, t)
% OL_PROBLEM  Why the filter is paused, as the engine reads it (NaN: none).
  p = struct('kind', kind, 'message', ol_one_line(message), 'details', details, ...
             'file', file, 'line', line, 'function', fn, 't_s', t);
end
