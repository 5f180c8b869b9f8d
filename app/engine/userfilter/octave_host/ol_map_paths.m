function text = ol_map_paths(ctx, text)
% OL_MAP_PATHS  Paths of the running copy in a message as paths in the user's folder.
  text = strrep(text, [ctx.code_real, filesep], [ctx.folder, filesep]);
  text = strrep(text, [ctx.code_dir, filesep], [ctx.folder, filesep]);
end
