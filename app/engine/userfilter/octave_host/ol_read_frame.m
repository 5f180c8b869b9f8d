function [header, arrays, ok] = ol_read_frame()
% OL_READ_FRAME  The next request from stdin: its header (a struct) and arrays (a struct of
% name -> array); ok is false at the end of the input.
  header = struct();
  arrays = struct();
  ok = false;
  magic = fread(stdin, 4, 'uint8=>char')';
  if numel(magic) < 4
    return;
  end
  if ~strcmp(magic, 'OLF1')
    error('OrientationLab:protocol', 'a request that is not a frame');
  end
  len = fread(stdin, 1, 'uint32=>double', 0, 'ieee-le');
  text = fread(stdin, len, 'uint8=>uint8')';
  header = jsondecode(native2unicode(text, 'utf-8'));
  listed = {};
  if isfield(header, 'arrays')
    listed = header.arrays;
    header = rmfield(header, 'arrays');
  end
  for i = 1:numel(listed)
    entry = listed{i};
    name = entry{1};
    shape = reshape(double(entry{3}), 1, []);
    count = prod(shape);
    switch entry{2}
      case '<f8'
        data = fread(stdin, count, 'double=>double', 0, 'ieee-le');
      case '<i4'
        data = fread(stdin, count, 'int32=>double', 0, 'ieee-le');
      case '|i1'
        data = fread(stdin, count, 'int8=>double');
      case '|u1'
        data = fread(stdin, count, 'uint8=>double');
      otherwise
        error('OrientationLab:protocol', 'an array of type %s', entry{2});
    end
    if numel(shape) > 1
      % C order: the last index runs fastest
      data = permute(reshape(data, fliplr(shape)), numel(shape):-1:1);
    end
    arrays.(name) = data;
  end
  ok = true;
end
