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
% A reading counts when it is finite and not absurd (|v|^2 at most 1e12; the accelerometer's and
% magnetometer's at least 1e-12). A function that raises OrientationLab:notWritten is skipped
% (x and P stay); any other error, a returned x that is not 4x1 or P not 4x4, or a non-finite
% state pauses the filter (ctx.problem). want_innovations (default true): also the innovations
% of each reading for the consistency view. Returns the reply's header fields and arrays (see
% ol_serve). seconds and elapsed are the loop's time (the filter's work, what each row costs);
% block_seconds the whole block's: its fixed part (~1 ms: the work before and after the loop) is
% paid once per block, and blocks handed over close together go as one
% (app.engine.userfilter.octave_remote), so the engine budgets with the cost per row of the loop.
%
% Written for Octave's interpreter, where every statement costs: the loop holds only what the
% filter's state depends on. What depends on the readings and times alone is worked out before
% it over all rows at once (which readings count, the time steps, the gyroscope rate held for
% each row and whether it is recent, where the start is, the course's accelerometer test, the
% magnetometer's strength); what can wait (the innovations, the lights of the rows between two
% readings, the standstill light, the display quaternion) is computed after it.
  block_clock = tic;
  n = numel(T);
  if isstruct(ctx.problem)                 % paused (or the folder did not load): nothing runs
    reply = struct('run', 0, 'seconds', 0, 'elapsed', toc(block_clock), 'paused_at', 0, ...
                   'last_out', -1);
    entries = {'q', '<f8', [n, 4], NaN(n, 4); 'flags', '|i1', [n, 3], -ones(n, 3)};
    return;
  end
  V = values';
  G = given' ~= 0;
  Tr = reshape(T, 1, n);
  s = ctx.s;
  st = ctx.state;
  x = st.x; P = st.P;
  heading_known = st.heading_known;
  m0 = st.m0; L = st.L;
  acc_out = st.acc_out; mag_out = st.mag_out;
  Rw = s.Rw; Ra = s.Ra; Rm = s.Rm; g0 = s.g0;
  mag_gate = s.mag_gate; kept = 1 - s.mag_alpha;
  walk = 0.25 * s.no_gyro_random_walk^2;
  do_tu = islogical(ctx.missing.tu_qw);
  do_g = islogical(ctx.missing.mu_g);
  do_m = islogical(ctx.missing.mu_m);
  do_norm = islogical(ctx.missing.mu_normalizeQ);
  own_acc_test = ctx.has.acc_outlier;
  own_mag_test = ctx.has.mag_outlier;
  keep_inn = nargin < 5 || want_innovations;
  % ---- before the loop: what the readings and times alone decide, for every row ---------------
  A = V(4:6, :);
  M = V(7:9, :);
  aa = sum(A .^ 2, 1);
  mm = sum(M .^ 2, 1);
  gyr = G(1, :) & sum(V(1:3, :) .^ 2, 1) <= 1e12;       % finite and not absurd
  acc = G(2, :) & aa <= 1e12 & aa >= 1e-12;
  mag = G(3, :) & mm <= 1e12 & mm >= 1e-12;
  t0 = st.t;
  if t0 ~= t0 && n > 0                                  % NaN: nothing seen yet
    t0 = T(1);
  end
  if t0 == t0
    tc = cummax([t0, Tr]);          % the time reached before row k: tc(k); after it: tc(k + 1)
  else
    tc = NaN(1, n + 1);             % stays NaN (no time is later than NaN)
  end
  DT = Tr - tc(1:n);
  latest_g = cummax([0, (1:n) .* gyr]);        % the latest gyroscope row up to row k - 1: (k)
  latest_m = cummax([0, (1:n) .* mag]);
  W_seen = [st.omega, V(1:3, :)];              % column j + 1: row j's reading (1: the state's)
  Wt_seen = [st.omega_t, Tr];
  M_seen = [st.mag, M];
  Mt_seen = [st.mag_t, Tr];
  Om = W_seen(:, latest_g(1:n) + 1) - s.gyr_bias;
  held = tc(1:n) - Wt_seen(latest_g(1:n) + 1) <= s.gyr_hold_s;
  if st.started
    first = 0;                                 % the row that starts (tilt): before the block
  else
    first = find(acc, 1);
    if isempty(first)
      first = n + 1;
    end
  end
  after_start = (1:n) > first;
  moves = Tr > tc(1:n) & after_start & DT <= s.max_dt;
  TU = moves & held;                           % tu_qw and mu_normalizeQ
  GROW = moves & ~held;                        % no gyroscope: q stays, P grows
  ACC = acc & after_start;                     % the test, mu_g and mu_normalizeQ
  MAG = mag & (after_start | (1:n) == first);  % the heading, or the test, mu_m and mu_normalizeQ
  off_g = sqrt(aa) - sqrt(g0' * g0);
  acc_course = off_g > s.acc_gate | -off_g > s.acc_gate;      % the course's test (task 8)
  strength = sqrt(mm);
  pulled = s.mag_alpha * strength;
  % ---- the loop: what the filter's state depends on -----------------------------------------
  Xout = NaN(4, n);
  acc_light = NaN(1, n);
  mag_light = NaN(1, n);
  if keep_inn                                  % x, P before each accelerometer / magnetometer test
    prior_xa = zeros(4, n); prior_Pa = zeros(4, 4, n);
    prior_xm = zeros(4, n); prior_Pm = zeros(4, 4, n);
  end
  o4 = ones(1, 4); o41 = ones(4, 1); o5 = ones(5, 1);
  paused_at = -1;
  stage = 0;                                   % where a pause came: 1, 3 or 4 (the steps above)
  beat = 64;
  clock = tic;
  for k = 1:n
    % ---- 1. the time update to the row's time ------------------------------------------------
    if TU(k)
      if do_tu && do_norm
        try                                          % eq. (5)-(6), then |q| = 1: one go
          [x1, P1] = tu_qw(x, P, Om(:, k), DT(k), Rw);
          [x1, P1] = mu_normalizeQ(x1, P1);
          c = o4 * ([x1, P1] * o5 + P1 * o41);       % fails unless 4x1 and 4x4; NaN: not finite
          if c - c ~= 0, error('OrientationLab:check', 'not a state'); end
          x = x1; P = P1;
        catch
          [ctx, x, P, stop, do_tu, do_norm] = ol_pair(ctx, 'tu_qw', {Om(:, k), DT(k), Rw}, ...
                                                      x, P, Tr(k), do_tu, do_norm);
          if stop, paused_at = k - 1; stage = 1; break; end
        end
      else
        [ctx, x, P, stop, do_tu, do_norm] = ol_pair(ctx, 'tu_qw', {Om(:, k), DT(k), Rw}, ...
                                                    x, P, Tr(k), do_tu, do_norm);
        if stop, paused_at = k - 1; stage = 1; break; end
      end
    elseif GROW(k)                                   % task 12
      Sb = [-x(2), -x(3), -x(4); x(1), -x(4), x(3); x(4), x(1), -x(2); -x(3), x(2), x(1)];
      P = P + (walk * DT(k)) * (Sb * Sb');
      [ctx, x, P, stop, ~, do_norm] = ol_pair(ctx, '', {}, x, P, Tr(k), false, do_norm);
      if stop, paused_at = k - 1; stage = 1; break; end
    end
    % ---- 2. the gyroscope: its rate is held for the next rows (Om, before the loop) ----------
    % ---- 3. the accelerometer ----------------------------------------------------------------
    if ACC(k)
      if own_acc_test
        try
          acc_out = ol_flag(acc_outlier(A(:, k), g0, s), 'acc_outlier');
        catch err
          [ctx, own_acc_test, stop] = ol_failed(ctx, err, 'acc_outlier', Tr(k));
          if stop, paused_at = k - 1; stage = 3; break; end
        end
      end
      if ~own_acc_test
        acc_out = acc_course(k);
      end
      acc_light(k) = acc_out;
      if keep_inn                                    % the prior, for the consistency view
        prior_xa(:, k) = x; prior_Pa(:, :, k) = P;
      end
      if ~acc_out && do_g && do_norm
        try
          [x1, P1] = mu_g(x, P, A(:, k), Ra, g0);
          [x1, P1] = mu_normalizeQ(x1, P1);
          c = o4 * ([x1, P1] * o5 + P1 * o41);
          if c - c ~= 0, error('OrientationLab:check', 'not a state'); end
          x = x1; P = P1;
        catch
          [ctx, x, P, stop, do_g, do_norm] = ol_pair(ctx, 'mu_g', {A(:, k), Ra, g0}, x, P, ...
                                                      Tr(k), do_g, do_norm);
          if stop, paused_at = k - 1; stage = 3; break; end
        end
      elseif ~acc_out
        [ctx, x, P, stop, do_g, do_norm] = ol_pair(ctx, 'mu_g', {A(:, k), Ra, g0}, x, P, ...
                                                    Tr(k), do_g, do_norm);
        if stop, paused_at = k - 1; stage = 3; break; end
      end
    elseif k == first                                % the start
      j = latest_m(k) + 1;
      [x, P, heading_known] = ol_start(A(:, k), M_seen(:, j), Tr(k) - Mt_seen(j) <= 0.1, ...
                                       s.initial_attitude_std);
      if heading_known && isempty(m0)
        [m0, L] = ol_m0_from(x, M_seen(:, j));
      end
    end
    % ---- 4. the magnetometer -----------------------------------------------------------------
    if MAG(k)
      if heading_known
        if own_mag_test
          try
            [flag, L2] = mag_outlier(M(:, k), L, s);
            mag_out = ol_flag(flag, 'mag_outlier');
            L = ol_number(L2, 'mag_outlier', 'L');
          catch err
            [ctx, own_mag_test, stop] = ol_failed(ctx, err, 'mag_outlier', Tr(k));
            if stop, paused_at = k - 1; stage = 4; break; end
          end
        end
        if ~own_mag_test                             % the course's test (task 11)
          if L ~= L
            L = strength(k);
          end
          e = strength(k) - L;
          mag_out = e > mag_gate || -e > mag_gate;
          L = kept * L + pulled(k);
        end
        mag_light(k) = mag_out;
        if keep_inn
          prior_xm(:, k) = x; prior_Pm(:, :, k) = P;
        end
        if ~mag_out && do_m && do_norm
          try
            [x1, P1] = mu_m(x, P, M(:, k), m0, Rm);
            [x1, P1] = mu_normalizeQ(x1, P1);
            c = o4 * ([x1, P1] * o5 + P1 * o41);
            if c - c ~= 0, error('OrientationLab:check', 'not a state'); end
            x = x1; P = P1;
          catch
            [ctx, x, P, stop, do_m, do_norm] = ol_pair(ctx, 'mu_m', {M(:, k), m0, Rm}, x, P, ...
                                                        Tr(k), do_m, do_norm);
            if stop, paused_at = k - 1; stage = 4; break; end
          end
        elseif ~mag_out
          [ctx, x, P, stop, do_m, do_norm] = ol_pair(ctx, 'mu_m', {M(:, k), m0, Rm}, x, P, ...
                                                      Tr(k), do_m, do_norm);
          if stop, paused_at = k - 1; stage = 4; break; end
        end
      else
        [x, P, heading_known] = ol_heading(x, P, M(:, k), m0, s.initial_attitude_std);
        if heading_known && isempty(m0)
          [m0, L] = ol_m0_from(x, M(:, k));
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
    k = paused_at + 1;                % the rows whose time and readings were taken: a pause in
    timed = k - (stage == 1);         % step 1 comes before the row's time and gyroscope, in 3
    magged = k - (stage ~= 4);        % before its magnetometer
  else
    done = n;
    timed = n;
    magged = n;
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
  if keep_inn                          % the readings tested, in the order the loop took them
    tested_a = reshape(find(acc_light(1:done) == acc_light(1:done)), 1, []);
    tested_m = reshape(find(mag_light(1:done) == mag_light(1:done)), 1, []);
    [rows, order] = sort([2 * tested_a, 2 * tested_m + 1]);
    sensors = mod(rows, 2);
    rows = (rows - sensors) / 2;
    prior_x = [prior_xa(:, tested_a), prior_xm(:, tested_m)](:, order);
    prior_P = [reshape(prior_Pa(:, :, tested_a), 16, []), ...
               reshape(prior_Pm(:, :, tested_m), 16, [])](:, order);
  else
    rows = zeros(1, 0);
    sensors = zeros(1, 0);
    prior_x = zeros(4, 0);
    prior_P = zeros(16, 0);
  end
  m = numel(rows);
  Y = zeros(3, m);
  accepted = zeros(1, m);
  for code = 0:1
    these = sensors == code;
    Y(:, these) = V(4 + 3 * code:6 + 3 * code, rows(these));
    accepted(these) = F(rows(these), 1 + code)' == 0;
  end
  [nu, S] = ol_innovations(prior_x, prior_P, Y, sensors, g0, m0, Ra, Rm);
  j = latest_g(timed + 1) + 1;
  st.omega = W_seen(:, j); st.omega_t = Wt_seen(j);
  j = latest_m(magged + 1) + 1;
  st.mag = M_seen(:, j); st.mag_t = Mt_seen(j);
  st.t = tc(timed + 1);
  st.started = first <= timed;
  st.x = x; st.P = P;
  st.heading_known = heading_known;
  st.m0 = m0; st.L = L;
  ctx.state = st;
  reply = struct('run', done, 'seconds', loop_seconds, 'elapsed', loop_seconds, ...
                 'block_seconds', toc(block_clock), 'paused_at', paused_at, 'last_out', done - 1);
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
