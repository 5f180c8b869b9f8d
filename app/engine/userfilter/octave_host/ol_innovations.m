function [nu, S] = ol_innovations(X, Pcols, Y, sensor, g0, m0, Ra, Rm)
% OL_INNOVATIONS  For each accelerometer (sensor 0) or magnetometer (1) reading Y(:, i) with the
% prior X(:, i), P = reshape(Pcols(:, i), 4, 4): the innovation nu = y - Q(q)' v0 and its
% covariance S = H P H' + R (eqs. 7, 8; H from eqs. 2f-2i), v0 = g0 or m0: what the consistency
% view shows. nu is 3 x m, S 3 x 3 x m.
  m = columns(X);
  nu = zeros(3, m);
  S = zeros(3, 3, m);
  if m == 0
    return;
  end
  V0 = repmat(g0, 1, m);
  R = repmat(Ra, [1, 1, m]);
  mags = sensor == 1;
  if any(mags)
    V0(:, mags) = repmat(m0, 1, sum(mags));
    R(:, :, mags) = repmat(Rm, [1, 1, sum(mags)]);
  end
  q0 = X(1, :); q1 = X(2, :); q2 = X(3, :); q3 = X(4, :);
  a = V0(1, :); b = V0(2, :); c = V0(3, :);
  % Q(q)' v0, row by row of Q(q)' (the columns of eq. 2a)
  nu(1, :) = Y(1, :) - ((2*(q0.^2+q1.^2)-1).*a + 2*(q1.*q2+q0.*q3).*b + 2*(q1.*q3-q0.*q2).*c);
  nu(2, :) = Y(2, :) - (2*(q1.*q2-q0.*q3).*a + (2*(q0.^2+q2.^2)-1).*b + 2*(q2.*q3+q0.*q1).*c);
  nu(3, :) = Y(3, :) - (2*(q1.*q3+q0.*q2).*a + 2*(q2.*q3-q0.*q1).*b + (2*(q0.^2+q3.^2)-1).*c);
  % H(:, i) = dQ/dq_i' v0
  H = zeros(3, 4, m);
  H(1, 1, :) = 2*(2*q0.*a + q3.*b - q2.*c);
  H(2, 1, :) = 2*(-q3.*a + 2*q0.*b + q1.*c);
  H(3, 1, :) = 2*(q2.*a - q1.*b + 2*q0.*c);
  H(1, 2, :) = 2*(2*q1.*a + q2.*b + q3.*c);
  H(2, 2, :) = 2*(q2.*a + q0.*c);
  H(3, 2, :) = 2*(q3.*a - q0.*b);
  H(1, 3, :) = 2*(q1.*b - q0.*c);
  H(2, 3, :) = 2*(q1.*a + 2*q2.*b + q3.*c);
  H(3, 3, :) = 2*(q0.*a + q3.*b);
  H(1, 4, :) = 2*(q0.*b + q1.*c);
  H(2, 4, :) = 2*(-q0.*a + q2.*c);
  H(3, 4, :) = 2*(q1.*a + q2.*b + 2*q3.*c);
  % S = H P H' + R for all readings at once: HP(r, l) = sum_k H(r, k) P(k, l), then
  % S(r, j) = sum_l HP(r, l) H(j, l)
  P = reshape(Pcols, 4, 4, m);
  HP = zeros(3, 4, m);
  for r = 1:3
    for l = 1:4
      HP(r, l, :) = H(r, 1, :) .* P(1, l, :) + H(r, 2, :) .* P(2, l, :) ...
                    + H(r, 3, :) .* P(3, l, :) + H(r, 4, :) .* P(4, l, :);
    end
  end
  for r = 1:3
    for j = 1:3
      S(r, j, :) = R(r, j, :) + HP(r, 1, :) .* H(j, 1, :) + HP(r, 2, :) .* H(j, 2, :) ...
                   + HP(r, 3, :) .* H(j, 3, :) + HP(r, 4, :) .* H(j, 4, :);
    end
  end
end
