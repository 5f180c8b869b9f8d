function bytes = ol_pack(value)
% OL_PACK  A value made of structs, numbers, logicals and text as bytes (ol_unpack reads them):
% the state of a snapshot. Doubles keep every bit.
  bytes = uint8(pack(value))';
end

function b = pack(v)
  if isstruct(v)
    names = fieldnames(v);
    b = [uint8('S'), typecast(uint32(numel(names)), 'uint8')];
    for i = 1:numel(names)
      name = uint8(names{i});
      b = [b, typecast(uint32(numel(name)), 'uint8'), name, pack(v.(names{i}))];
    end
  elseif ischar(v)
    text = unicode2native(v, 'utf-8');
    b = [uint8('C'), typecast(uint32(numel(text)), 'uint8'), text];
  elseif iscell(v)
    b = [uint8('L'), typecast(uint32(numel(v)), 'uint8')];
    for i = 1:numel(v)
      b = [b, pack(v{i})];
    end
  else
    kind = 'D';
    if islogical(v)
      kind = 'B';
    end
    d = double(v);
    b = [uint8(kind), typecast(uint32(rows(d)), 'uint8'), typecast(uint32(columns(d)), 'uint8'), ...
         typecast(d(:)', 'uint8')];
  end
  b = uint8(b);
end
