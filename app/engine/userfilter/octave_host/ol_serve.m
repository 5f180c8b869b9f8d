function ol_serve(code_dir, folder)
% OL_SERVE  Answer Orientation Lab's requests until stdin ends: start (load the filter's folder),
% rows (run a block of samples through the course's loop, ol_run_block), reset (a fresh state),
% snapshot and restore (the state as bytes).
  cd(code_dir);
  ctx = [];
  while true
    [h, a, ok] = ol_read_frame();
    if ~ok
      return;
    end
    switch h.op
      case 'start'
        ctx = ol_load(code_dir, folder, h.settings);
        ol_write_frame(struct('op', 'start', 'problem', ctx.problem, ...
                              'missing', {ol_missing(ctx)}, 'notes', {ctx.notes}));
      case 'rows'
        [ctx, reply, entries] = ol_run_block(ctx, a.t, a.given, a.values);
        reply.op = 'rows';
        reply.id = h.id;
        reply.epoch = h.epoch;
        reply.problem = ctx.problem;
        reply.missing = ol_missing(ctx);
        reply.notes = ctx.notes;
        ol_write_frame(reply, entries);
      case 'reset'
        if isfield(h, 'settings') && isstruct(h.settings)
          ctx = ol_configure(ctx, h.settings);
        end
        keep = ctx.problem;
        ctx.state = ol_new_state(ctx.s);
        if ~(isfield(h, 'fresh') && h.fresh) && isstruct(keep) && ~isstruct(ctx.problem)
          ctx.problem = keep;
        end
        ol_write_frame(struct('op', 'reset', 'epoch', h.epoch, 'problem', ctx.problem, ...
                              'missing', {ol_missing(ctx)}, 'notes', {ctx.notes}));
      case 'snapshot'
        bytes = ol_pack(struct('state', ctx.state, 'problem', ctx.problem));
        ol_write_frame(struct('op', 'snapshot', 'error', NaN), ...
                       {'state', '|u1', numel(bytes), bytes});
      case 'restore'
        saved = ol_unpack(a.state);
        ctx.state = saved.state;
        ctx.problem = saved.problem;
        ol_write_frame(struct('op', 'restore', 'error', NaN, 'problem', ctx.problem, ...
                              'missing', {ol_missing(ctx)}, 'notes', {ctx.notes}));
      otherwise
        error('OrientationLab:protocol', 'unknown request %s', h.op);
    end
  end
end
