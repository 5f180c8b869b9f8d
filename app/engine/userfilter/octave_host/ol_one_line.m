function text = ol_one_line(text)
% OL_ONE_LINE  A message on one line of at most 300 characters.
  text = strtrim(regexprep(text, '\s+', ' '));
  if numel(text) > 300
    text = [text(1:299), '...'];
  end
end
