function value = ol_unpack(bytes)
% OL_UNPACK  The value ol_pack wrote.
  bytes = uint8(bytes(:))';
  [value, ~] = unpack(bytes, 1);
end

function [v, at] = unpack(b, at)
  kind = char(b(at));
  at = at + 1;
  count = double(typecast(b(at:at + 3), 'uint32'));
  at = at + 4;
  switch kind
    case 'S'
      v = struct();
      for i = 1:count
        len = double(typecast(b(at:at + 3), 'uint32'));
        name = char(b(at + 4:at + 3 + len));
        at = at + 4 + len;
        [field, at] = unpack(b, at);
        v.(name) = field;
      end
    case 'C'
      v = native2unicode(b(at:at + count - 1), 'utf-8');
      at = at + count;
    case 'L'
      v = cell(1, count);
      for i = 1:count
        [v{i}, at] = unpack(b, at);
      end
    otherwise
      cols = double(typecast(b(at:at + 3), 'uint32'));
      at = at + 4;
      n = count * cols;
      v = reshape(typecast(b(at:at + 8 * n - 1), 'double'), count, cols);
      at = at + 8 * n;
      if kind == 'B'
        v = logical(v);
      end
  end
end
