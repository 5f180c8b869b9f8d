function text = ol_describe(v)
% OL_DESCRIBE  A value in a few words: its size and class, or the number.
  if (isnumeric(v) || islogical(v)) && isscalar(v)
    text = num2str(v);
  elseif isnumeric(v) || islogical(v) || ischar(v)
    text = sprintf('a %s %s', strjoin(arrayfun(@num2str, size(v), 'UniformOutput', false), 'x'), class(v));
  else
    text = sprintf('a %s', class(v));
  end
end
