function list = ol_missing(ctx)
% OL_MISSING  The course's functions not written yet, in the course's order:
% {'mu_g (mu_g.m:12)', ...}.
  list = {};
  names = {'tu_qw', 'mu_g', 'mu_m', 'mu_normalizeQ'};
  for i = 1:numel(names)
    where = ctx.missing.(names{i});
    if ischar(where)
      if isempty(where)
        list{end + 1} = names{i};
      else
        list{end + 1} = sprintf('%s (%s)', names{i}, where);
      end
    end
  end
end
