function text = ol_report(err)
% OL_REPORT  An error's message and where it arose, as text.
  text = err.message;
  for i = 1:numel(err.stack)
    text = [text, sprintf("\n  %s at line %d [%s]", err.stack(i).name, err.stack(i).line, ...
                          err.stack(i).file)];
  end
end
