function [ctx, x, P, stop, do_f, do_norm] = ol_pair(ctx, name, args, x, P, t, do_f, do_norm)
% OL_PAIR  One update and the normalisation after it, each call on its own and checked: the
% loop's slow path (ol_run_block runs the pair in one go and comes here when something in it
% failed, or while one of the two is not written). name: the update ('tu_qw', 'mu_g', 'mu_m';
% '': the normalisation alone), args its arguments after x and P. A function that raises
% OrientationLab:notWritten is skipped (do_f or do_norm false from now on); any other error, or
% a returned x that is not a real, finite 4x1 or P a 4x4, pauses the filter (stop, ctx.problem).
  stop = false;
  if do_f && ~isempty(name)
    [ctx, x, P, stop, do_f] = call(ctx, name, args, x, P, t);
  end
  if do_norm && ~stop
    [ctx, x, P, stop, do_norm] = call(ctx, 'mu_normalizeQ', {}, x, P, t);
  end
end

function [ctx, x, P, stop, keep] = call(ctx, name, args, x, P, t)
  stop = false;
  keep = true;
  try
    [x2, P2] = feval(name, x, P, args{:});
  catch err
    [ctx, keep, stop] = ol_failed(ctx, err, name, t);
    return;
  end
  if ~ol_good_state(x2, P2)
    ctx.problem = ol_state_problem(ctx, name, x2, P2, t);
    stop = true;
    return;
  end
  x = x2;
  P = P2;
end
