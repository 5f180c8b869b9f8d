function mapped = ol_user_path(ctx, file)
% OL_USER_PATH  A path in the running copy of the folder as the same file in the user's folder
% ('' for a file elsewhere).
  mapped = '';
  for root = {ctx.code_dir, ctx.code_real}
    prefix = [root{1}, filesep];
    if strncmp(file, prefix, numel(prefix))
      mapped = fullfile(ctx.folder, file(numel(prefix) + 1:end));
      return;
    end
  end
end
