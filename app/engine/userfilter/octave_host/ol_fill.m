function out = ol_fill(values, before)
% OL_FILL  Each NaN in a row of values replaced by the latest value before it (`before` for
% those at the start), as a column.
  n = numel(values);
  index = (1:n) .* (values == values);
  last = cummax(index);
  padded = [before, values];
  out = padded(last + 1)';
end
