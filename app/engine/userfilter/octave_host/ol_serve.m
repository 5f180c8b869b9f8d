function ol_serve(code_dir, folder)
% OL_SERVE  Answer Orientation Lab's requests until stdin ends: start (load the filter's folder),
% rows (run a block of samples through the course's loop, ol_run_block), reset (a fresh state),
% snapshot and restore (the state as bytes). Every request gets exactly one reply; an error of
% this host's own becomes the reply's problem (the filter pauses), never the end of the process.
  cd(code_dir);
  ctx = [];
  while true
    [h, a, ok] = ol_read_frame();
    if ~ok
      return;
    end
    try
      ctx = ol_answer(ctx, h, a, code_dir, folder);
    catch err
      p = ol_problem('exception', ['Orientation Lab''s Octave host failed: ', err.message], ...
                     ol_report(err), NaN, NaN, NaN, NaN);
      if isstruct(ctx)
        ctx.problem = p;
      end
      reply = struct('op', h.op, 'problem', p, 'missing', {{}}, 'notes', {{}}, 'error', ...
                     p.message);
      entries = cell(0, 4);
      if strcmp(h.op, 'rows')
        n = numel(a.t);
        reply.id = h.id;
        reply.epoch = h.epoch;
        reply.run = 0;
        reply.seconds = 0;
        reply.paused_at = 0;
        reply.last_out = -1;
        entries = {'q', '<f8', [n, 4], NaN(n, 4); 'flags', '|i1', [n, 3], -ones(n, 3)};
      elseif isfield(h, 'epoch')
        reply.epoch = h.epoch;
      end
      ol_write_frame(reply, entries);
    end
  end
end

function ctx = ol_answer(ctx, h, a, code_dir, folder)
  switch h.op
    case 'start'
      ctx = ol_load(code_dir, folder, h.settings);
      ol_write_frame(struct('op', 'start', 'problem', ctx.problem, ...
                            'missing', {ol_missing(ctx)}, 'notes', {ctx.notes}));
    case 'rows'
      want = ~isfield(h, 'innovations') || h.innovations;
      [ctx, reply, entries] = ol_run_block(ctx, a.t, a.given, a.values, want);
      reply.op = 'rows';
      reply.id = h.id;
      reply.epoch = h.epoch;
      reply.problem = ctx.problem;
      reply.missing = ol_missing(ctx);
      reply.notes = ctx.notes;
      ol_write_frame(reply, entries);
    case 'reset'
      keep = ctx.problem;
      if isempty(ctx.s)                     % the folder did not load: nothing to reset
        ol_write_frame(struct('op', 'reset', 'epoch', h.epoch, 'problem', ctx.problem, ...
                              'missing', {ol_missing(ctx)}, 'notes', {ctx.notes}));
        return;
      end
      if isfield(h, 'settings') && isstruct(h.settings)
        ctx = ol_configure(ctx, h.settings);
      else
        ctx.state = ol_new_state(ctx.s);
      end
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
