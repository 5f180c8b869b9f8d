function ctx = ol_note(ctx, text)
% OL_NOTE  A remark that does not stop the filter (each once, at most 20).
  if ~any(strcmp(ctx.notes, text)) && numel(ctx.notes) < 20
    ctx.notes{end + 1} = text;
  end
end
