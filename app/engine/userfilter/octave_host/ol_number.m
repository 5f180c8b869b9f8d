function v = ol_number(value, name, what)
% OL_NUMBER  A returned number, checked (an error names the function and the output).
  if ~isnumeric(value) || ~isreal(value) || ~isscalar(value) || ~isfinite(value)
    error('OrientationLab:output', '%s returned %s = %s, expected a finite number', name, what, ...
          ol_describe(value));
  end
  v = double(value);
end
