function [ctx, reply, entries] = ol_run_block(ctx, T, given, values, want_innovations)
% OL_RUN_BLOCK  The course's filterTemplate loop over a block of samples.
%
% T (n x 1) times [s] on the phone's clock; given (n x 3) whether the row gives the gyroscope,
% accelerometer and magnetometer; values (n x 9) their readings [rad/s, m/s^2, uT]. For each row,
% as filterTemplate does and in this order:
%   1. the time update to the row's time: tu_qw with the latest gyroscope rate (held from its
%      sample, eq. 5) minus the bias, then mu_normalizeQ; without a recent gyroscope sample q
%      stays and P grows (task 12);
%   2. a gyroscope sample becomes the rate from now on;
%   3. an accelerometer sample: the start (tilt) on the first one; then the outlier test of
%      task 8 (acc_outlier, the student's or the course's), mu_g and mu_normalizeQ;
%   4. a magnetometer sample: the heading on the first one after the start (m0 from it unless
%      the settings give m0); then the outlier test of task 11 (mag_outlier), mu_m and
%      mu_normalizeQ.
% A function that raises OrientationLab:notWritten is skipped (x and P stay); any other error, a
% returned x that is not 4x1 or P not 4x4, or a non-finite state pauses the filter
% (ctx.problem). want_innovations (default true): also the innovations of each reading for the
% consistency view. Returns the reply's header fields and arrays (see ol_serve). seconds and
% elapsed are the loop's time (the filter's work, what each row costs); block_seconds the whole
% block's: its fixed part (~1 ms: the work after the loop) is paid once per block, and blocks
% handed over close together go as one (app.engine.userfilter.octave_remote), so the engine
% budgets with the cost per row of the loop.
%
% Written for Octave's interpreter, where every statement costs: inside the loop only what the
% filter's state depends on; what does not (the standstill light), or can wait (the
% innovations, the lights of the rows between two readings, the display quaternion) is computed
% after it over all rows at once.
  started = tic;
  n = numel(T);
  if isstruct(ctx.problem)                 % paused (or the folder did not load): nothing runs
    reply = struct('run', 0, 'seconds', 0, 'elapsed', toc(started), 'paused_at', 0, ...
                   'last_out', -1);
    entries = {'q', '<f8', [n, 4], NaN(n, 4); 'flags', '|i1', [n, 3], -ones(n, 3)};
    return;
  end
  V = values';
  G = given' ~= 0;
  Xout = NaN(4, n);
  acc_light = NaN(1, n);
  mag_light = NaN(1, n);
  prior_x = zeros(4, 2 * n);           % x, P before each accelerometer / magnetometer test
  prior_P = zeros(16, 2 * n);
  inn_row = zeros(1, 2 * n);
  inn_sensor = zeros(1, 2 * n);
  m = 0;
  paused_at = -1;
  s = ctx.s;
  st = ctx.state;
  x = st.x; P = st.P; tcur = st.t;
  started = st.started; heading_known = st.heading_known;
  omega = st.omega; omega_t = st.omega_t;
  last_mag = st.mag; mag_t = st.mag_t; m0 = st.m0; L = st.L;
  acc_out = st.acc_out; mag_out = st.mag_out;
  Rw = s.Rw; Ra = s.Ra; Rm = s.Rm; g0 = s.g0; bias = s.gyr_bias;
  g_norm = sqrt(g0' * g0);
  acc_gate = s.acc_gate; mag_gate = s.mag_gate; alpha = s.mag_alpha;
  max_dt = s.max_dt; gyr_hold = s.gyr_hold_s; walk = 0.25 * s.no_gyro_random_walk^2;
  do_tu = islogical(ctx.missing.tu_qw);
  do_g = islogical(ctx.missing.mu_g);
  do_m = islogical(ctx.missing.mu_m);
  do_norm = islogical(ctx.missing.mu_normalizeQ);
  own_acc_test = ctx.has.acc_outlier;
  own_mag_test = ctx.has.mag_outlier;
  o4 = ones(1, 4); o41 = ones(4, 1); o5 = ones(5, 1);
  keep_inn = nargin < 5 || want_innovations;
  yes = true;
  beat = 64;
  k = 0;
  if tcur ~= tcur && n > 0                              % NaN: nothing seen yet
    tcur = T(1);
  end
  clock = tic;
  while k < n
    k = k + 1;
    t = T(k);
    % ---- 1. the time update to t ------------------------------------------------------------
    if t > tcur
      dt = t - tcur;
      if started && dt <= max_dt
        if tcur - omega_t <= gyr_hold && do_tu && do_norm
          try                                        % eq. (5)-(6), then |q| = 1: one go
            [x1, P1] = tu_qw(x, P, omega - bias, dt, Rw);
            [x1, P1] = mu_normalizeQ(x1, P1);
            c = o4 * ([x1, P1] * o5 + P1 * o41);       % fails unless 4x1 and 4x4; NaN: not finite
            if c - c ~= 0, error('OrientationLab:check', 'not a state'); end
            x = x1; P = P1;
          catch
            [ctx, x, P, stop, do_tu, do_norm] = ol_pair(ctx, 'tu_qw', {omega - bias, dt, Rw}, ...
                                                        x, P, t, do_tu, do_norm);
            if stop, paused_at = k - 1; break; end
          end
        elseif tcur - omega_t <= gyr_hold
          [ctx, x, P, stop, do_tu, do_norm] = ol_pair(ctx, 'tu_qw', {omega - bias, dt, Rw}, ...
                                                      x, P, t, do_tu, do_norm);
          if stop, paused_at = k - 1; break; end
        else                                         % no gyroscope: q stays, P grows (task 12)
          Sb = [-x(2), -x(3), -x(4); x(1), -x(4), x(3); x(4), x(1), -x(2); -x(3), x(2), x(1)];
          P = P + (walk * dt) * (Sb * Sb');
          [ctx, x, P, stop, ~, do_norm] = ol_pair(ctx, '', {}, x, P, t, false, do_norm);
          if stop, paused_at = k - 1; break; end
        end
      end
      tcur = t;
    end
    % ---- 2. the gyroscope ---------------------------------------------------------------------
    if G(1, k)
      v = V(1:3, k);
      if v' * v <= 1e12                                 % finite and not absurd
        omega = v; omega_t = t;
      end
    end
    % ---- 3. the accelerometer -----------------------------------------------------------------
    if G(2, k)
      v = V(4:6, k);
      vv = v' * v;
      if vv <= 1e12 && vv >= 1e-12
        if started
          if own_acc_test
            try
              acc_out = ol_flag(acc_outlier(v, g0, s), 'acc_outlier');
            catch err
              [ctx, own_acc_test, stop] = ol_failed(ctx, err, 'acc_outlier', t);
              if stop, paused_at = k - 1; break; end
            end
          end
          if ~own_acc_test
            e = sqrt(vv) - g_norm;
            acc_out = e > acc_gate || -e > acc_gate;
          end
          acc_light(k) = acc_out;
          if keep_inn                            % the prior, for the consistency view
            m = m + 1; prior_x(:, m) = x; prior_P(:, m) = P(:); inn_row(m) = k;
          end
          if ~acc_out && do_g && do_norm
            try
              [x1, P1] = mu_g(x, P, v, Ra, g0);
              [x1, P1] = mu_normalizeQ(x1, P1);
              c = o4 * ([x1, P1] * o5 + P1 * o41);
              if c - c ~= 0, error('OrientationLab:check', 'not a state'); end
              x = x1; P = P1;
            catch
              [ctx, x, P, stop, do_g, do_norm] = ol_pair(ctx, 'mu_g', {v, Ra, g0}, x, P, t, ...
                                                          do_g, do_norm);
              if stop, paused_at = k - 1; break; end
            end
          elseif ~acc_out
            [ctx, x, P, stop, do_g, do_norm] = ol_pair(ctx, 'mu_g', {v, Ra, g0}, x, P, t, ...
                                                        do_g, do_norm);
            if stop, paused_at = k - 1; break; end
          end
        else
          [x, P, heading_known] = ol_start(v, last_mag, t - mag_t <= 0.1, s.initial_attitude_std);
          started = yes;
          if heading_known && isempty(m0)
            [m0, L] = ol_m0_from(x, last_mag);
          end
        end
      end
    end
    % ---- 4. the magnetometer ------------------------------------------------------------------
    if G(3, k)
      v = V(7:9, k);
      vv = v' * v;
      if vv <= 1e12 && vv >= 1e-12
        last_mag = v; mag_t = t;
        if heading_known
          if own_mag_test
            try
              [flag, L2] = mag_outlier(v, L, s);
              mag_out = ol_flag(flag, 'mag_outlier');
              L = ol_number(L2, 'mag_outlier', 'L');
            catch err
              [ctx, own_mag_test, stop] = ol_failed(ctx, err, 'mag_outlier', t);
              if stop, paused_at = k - 1; break; end
            end
          end
          if ~own_mag_test
            strength = sqrt(vv);
            if L ~= L
              L = strength;
            end
            e = strength - L;
            mag_out = e > mag_gate || -e > mag_gate;
            L = (1 - alpha) * L + alpha * strength;
          end
          mag_light(k) = mag_out;
          if keep_inn
            m = m + 1; prior_x(:, m) = x; prior_P(:, m) = P(:); inn_row(m) = k; inn_sensor(m) = 1;
          end
          if ~mag_out && do_m && do_norm
            try
              [x1, P1] = mu_m(x, P, v, m0, Rm);
              [x1, P1] = mu_normalizeQ(x1, P1);
              c = o4 * ([x1, P1] * o5 + P1 * o41);
              if c - c ~= 0, error('OrientationLab:check', 'not a state'); end
              x = x1; P = P1;
            catch
              [ctx, x, P, stop, do_m, do_norm] = ol_pair(ctx, 'mu_m', {v, m0, Rm}, x, P, t, ...
                                                          do_m, do_norm);
              if stop, paused_at = k - 1; break; end
            end
          elseif ~mag_out
            [ctx, x, P, stop, do_m, do_norm] = ol_pair(ctx, 'mu_m', {v, m0, Rm}, x, P, t, ...
                                                        do_m, do_norm);
            if stop, paused_at = k - 1; break; end
          end
        elseif started
          [x, P, heading_known] = ol_heading(x, P, v, m0, s.initial_attitude_std);
          if heading_known && isempty(m0)
            [m0, L] = ol_m0_from(x, v);
          end
        end
      end
    end
    Xout(:, k) = x;
    if k >= beat
      beat = k + 64;
      ol_progress(k, clock);
    end
  end
  loop_seconds = toc(clock);          % the filter's work (Python's child: the time in step)
  % ---- after the loop: what the rows show, over all of them at once ---------------------------
  if paused_at >= 0
    done = paused_at;
  else
    done = n;
  end
  norms = sqrt(sum(Xout(:, 1:done) .^ 2, 1));
  if do_norm && done > 0
    off = find(abs(norms - 1) > 1e-3, 1);
    if ~isempty(off)
      ctx.problem = ol_state_problem(ctx, 'mu_normalizeQ', Xout(:, off), P, T(off), norms(off));
      done = off - 1;
      paused_at = done;
    end
  end
  if done > 0 && ~isreal(Xout) && ~isstruct(ctx.problem)
    off = find(any(imag(Xout(:, 1:done)) ~= 0, 1), 1);
    message = sprintf(['x became complex at t = %.3f s (a square root or log of a negative ', ...
                       'number?)'], T(off));
    ctx.problem = ol_problem('output', message, message, ctx.folder, NaN, NaN, T(off));
    done = off - 1;
    paused_at = done;
  end
  if ~do_norm && done > 0
    ctx = ol_note(ctx, 'q is normalised for display: mu_normalizeQ is not written yet');
  end
  q = real(Xout(:, 1:done)) ./ norms(1:done);
  flip = q(1, :) < 0;
  q(:, flip) = -q(:, flip);
  [still, st] = ol_standstill(st, s, T(1:done), G(:, 1:done), V(:, 1:done));
  Q = NaN(n, 4);
  F = -ones(n, 3);
  if done > 0
    Q(1:done, :) = q';
    F(1:done, 1) = ol_fill(acc_light(1:done), st.acc_out);
    F(1:done, 2) = ol_fill(mag_light(1:done), st.mag_out);
    F(1:done, 3) = still;
    Q(done + 1:n, :) = repmat(Q(done, :), n - done, 1);       % after a pause: the latest output
    F(done + 1:n, :) = repmat(F(done, :), n - done, 1);
    st.acc_out = F(done, 1) ~= 0;
    st.mag_out = F(done, 2) ~= 0;
  end
  keep = inn_row(1:m) <= done;
  rows = inn_row(keep);
  sensors = inn_sensor(keep);
  m = numel(rows);
  Y = zeros(3, m);
  accepted = zeros(1, m);
  for code = 0:1
    these = sensors == code;
    Y(:, these) = V(4 + 3 * code:6 + 3 * code, rows(these));
    accepted(these) = F(rows(these), 1 + code)' == 0;
  end
  [nu, S] = ol_innovations(prior_x(:, keep), prior_P(:, keep), Y, sensors, g0, m0, Ra, Rm);
  st.x = x; st.P = P; st.t = tcur;
  st.started = started; st.heading_known = heading_known;
  st.omega = omega; st.omega_t = omega_t;
  st.mag = last_mag; st.mag_t = mag_t; st.m0 = m0; st.L = L;
  ctx.state = st;
  reply = struct('run', done, 'seconds', loop_seconds, 'elapsed', loop_seconds, ...
                 'block_seconds', toc(started), 'paused_at', paused_at, 'last_out', done - 1);
  entries = {'q', '<f8', [n, 4], Q; 'flags', '|i1', [n, 3], F};
  if done > 0
    entries(end + 1, :) = {'P', '<f8', [4, 4], P(1:4, 1:4)};
  end
  entries = [entries; {'inn_row', '<i4', m, rows - 1; ...
                       'inn_sensor', '|i1', m, sensors; ...
                       'inn_nu', '<f8', [m, 3], nu'; ...
                       'inn_S', '<f8', [m, 3, 3], permute(S, [3, 1, 2]); ...
                       'inn_accepted', '|u1', m, accepted}];
end
