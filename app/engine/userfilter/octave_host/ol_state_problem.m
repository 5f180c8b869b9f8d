function p = ol_state_problem(ctx, name, x, P, t, nq)
% OL_STATE_PROBLEM  What is wrong with the x and P a function returned, in one line.
  file = fullfile(ctx.folder, [name, '.m']);
  if nargin >= 6
    what = sprintf('q is not a unit quaternion after %s: |q| = %.6g (divide x(1:4) by its norm)', ...
                   name, nq);
  elseif ~isnumeric(x) || ~isnumeric(P)
    what = sprintf('%s returned x of class %s and P of class %s, expected numbers', name, ...
                   class(x), class(P));
  elseif ~isequal(size(x), [4, 1]) || ~isequal(size(P), [4, 4])
    what = sprintf('%s returned x of size %s and P of size %s, expected x 4x1 and P 4x4', ...
                   name, dims(x), dims(P));
  elseif ~isreal(x) || ~isreal(P)
    what = sprintf('%s returned a complex x or P (a square root or log of a negative number?)', ...
                   name);
  elseif ~all(isfinite(x))
    what = sprintf('%s returned a non-finite x = %s', name, mat2str(x', 4));
  else
    what = sprintf('%s returned a non-finite P (NaN or Inf)', name);
  end
  message = sprintf('%s.m: %s at t = %.3f s', name, what, t);
  p = ol_problem('output', message, what, file, NaN, name, t);
end

function text = dims(v)
  text = strjoin(arrayfun(@num2str, size(v), 'UniformOutput', false), 'x');
end
