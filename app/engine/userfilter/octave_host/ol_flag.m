function flag = ol_flag(value, name)
% OL_FLAG  An outlier test's answer as true or false (an error names the function).
  if ~(islogical(value) || isnumeric(value)) || ~isscalar(value) || isnan(value)
    error('OrientationLab:output', '%s returned %s, expected true or false', name, ol_describe(value));
  end
  flag = value ~= 0;
end
