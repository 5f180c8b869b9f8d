function ol_write_frame(header, entries)
% OL_WRITE_FRAME  Write one reply to stdout: header (a struct) and the arrays in entries, a cell
% array with one row {name, type, shape, value} per array: type one of '<f8', '<i4', '|i1',
% '|u1'; shape the array's shape as the reply gives it (C order: the last index runs fastest);
% value the array as a matrix of that shape (a vector for a 1-D shape).
  if nargin < 2
    entries = cell(0, 4);
  end
  n = rows(entries);
  listed = cell(1, n);
  for i = 1:n
    listed{i} = {entries{i, 1}, entries{i, 2}, num2cell(entries{i, 3})};
  end
  header.arrays = listed;
  text = unicode2native(jsonencode(header), 'utf-8');
  fwrite(stdout, uint8('OLF1'));
  fwrite(stdout, numel(text), 'uint32', 0, 'ieee-le');
  fwrite(stdout, text);
  for i = 1:n
    value = entries{i, 4};
    if numel(entries{i, 3}) > 1
      value = permute(value, ndims(value):-1:1);
    end
    switch entries{i, 2}
      case '<f8'
        fwrite(stdout, value, 'double', 0, 'ieee-le');
      case '<i4'
        fwrite(stdout, value, 'int32', 0, 'ieee-le');
      case '|i1'
        fwrite(stdout, value, 'int8');
      case '|u1'
        fwrite(stdout, value, 'uint8');
    end
  end
  fflush(stdout);
end
