function p = ol_error_problem(ctx, err, called, t, kind)
% OL_ERROR_PROBLEM  An Octave error in the student's code as the problem that pauses the
% filter: "mu_g.m:12 in mu_g: <Octave's message>" (file and line where the error arose in the
% student's files; a syntax error: where Octave's parser stopped).
  message = ol_map_paths(ctx, err.message);
  lines = strsplit(message, "\n");
  first = strtrim(lines{1});
  parse = regexp(err.message, 'parse error near line (\d+) of file (.*?\.m)', 'tokens', 'once');
  fn = called;
  if ~isempty(parse)
    line = str2double(parse{1});
    file = ol_user_path(ctx, parse{2});
    if isempty(file)
      file = parse{2};
    end
    [~, fn] = fileparts(file);
    rest = strtrim(strjoin(lines(2:end), ' '));
    rest = strtrim(regexprep(rest, '>>>.*', ''));
    if isempty(rest)
      rest = 'syntax error';
    end
    [~, base, ext] = fileparts(file);
    head = sprintf('%s%s:%d: parse error: %s', base, ext, line, rest);
    p = ol_problem(kind, head, message, file, line, fn, t);
    return;
  end
  [file, line, where_fn] = ol_where(ctx, err);
  if isempty(file)
    file = fullfile(ctx.folder, [called, '.m']);
    [~, base, ext] = fileparts(file);
    head = sprintf('%s%s in %s: %s', base, ext, called, first);
  else
    fn = where_fn;
    [~, base, ext] = fileparts(file);
    head = sprintf('%s%s:%d in %s: %s', base, ext, line, fn, first);
  end
  details = message;
  if ~isempty(err.stack)
    details = [details, sprintf("\n\nCalled from (most recent call first):")];
    for i = 1:numel(err.stack)
      frame = err.stack(i);
      mapped = ol_user_path(ctx, frame.file);
      if ~isempty(mapped)
        details = [details, sprintf("\n  %s at line %d [%s]", frame.name, frame.line, mapped)];
      end
    end
  end
  if ~strcmp(err.identifier, '')
    details = [details, sprintf("\n(%s)", err.identifier)];
  end
  p = ol_problem(kind, head, details, file, line, fn, t);
end
