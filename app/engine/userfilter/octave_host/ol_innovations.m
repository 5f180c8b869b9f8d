function [nu, S] = ol_innovations(X, P, Y, sensor, g0, m0, Ra, Rm)
% OL_INNOVATIONS  For each accelerometer (sensor 0) or magnetometer (1) reading Y(:, i) with the
% prior state X(:, i) and covariance P(:, i) (a 4x4 as a column): the innovation
% nu = y - Q(q)' v0 and its covariance S = H P H' + R (eqs. 7, 8; H(:, i) = dQ/dq_i' v0 from eqs.
% 2f-2i), v0 = g0 or m0: what the consistency view shows. nu is 3 x m, S 3 x 3 x m. All readings
% at once, one statement per quantity (Octave's interpreter charges per statement).
  m = columns(X);
  if m == 0
    nu = zeros(3, 0);
    S = zeros(3, 3, 0);
    return;
  end
  if m <= 4                              % a few readings: cheaper one by one
    nu = zeros(3, m);
    S = zeros(3, 3, m);
    for i = 1:m
      if sensor(i) == 1
        [nu(:, i), S(:, :, i)] = ol_innovation(X(:, i), reshape(P(:, i), 4, 4), Y(:, i), m0, Rm);
      else
        [nu(:, i), S(:, :, i)] = ol_innovation(X(:, i), reshape(P(:, i), 4, 4), Y(:, i), g0, Ra);
      end
    end
    return;
  end
  mags = sensor == 1;
  V0 = g0(:, ones(1, m));
  R = Ra(:)(:, ones(1, m));
  if any(mags)
    V0(:, mags) = m0(:, ones(1, sum(mags)));
    R(:, mags) = Rm(:)(:, ones(1, sum(mags)));
  end
  q0 = X(1, :); q1 = X(2, :); q2 = X(3, :); q3 = X(4, :);
  a = V0(1, :); b = V0(2, :); c = V0(3, :);
  % Q(q)' v0: the columns of eq. (2a) times v0
  nu = Y - [(2*(q0.^2+q1.^2)-1).*a + 2*(q1.*q2+q0.*q3).*b + 2*(q1.*q3-q0.*q2).*c;
            2*(q1.*q2-q0.*q3).*a + (2*(q0.^2+q2.^2)-1).*b + 2*(q2.*q3+q0.*q1).*c;
            2*(q1.*q3+q0.*q2).*a + 2*(q2.*q3-q0.*q1).*b + (2*(q0.^2+q3.^2)-1).*c];
  % H (3x4) as 12 rows, column by column: H(r, i) is row r + 3 (i - 1)
  H = 2 * [2*q0.*a + q3.*b - q2.*c;
       -q3.*a + 2*q0.*b + q1.*c;
       q2.*a - q1.*b + 2*q0.*c;
       2*q1.*a + q2.*b + q3.*c;
       q2.*a + q0.*c;
       q3.*a - q0.*b;
       q1.*b - q0.*c;
       q1.*a + 2*q2.*b + q3.*c;
       q0.*a + q3.*b;
       q0.*b + q1.*c;
       -q0.*a + q2.*c;
       q1.*a + q2.*b + 2*q3.*c];
  % H P (3x4), the same way; P(k, l) is row k + 4 (l - 1) of P
  HP = [H(1, :) .* P(1, :) + H(4, :) .* P(2, :) + H(7, :) .* P(3, :) + H(10, :) .* P(4, :);
        H(2, :) .* P(1, :) + H(5, :) .* P(2, :) + H(8, :) .* P(3, :) + H(11, :) .* P(4, :);
        H(3, :) .* P(1, :) + H(6, :) .* P(2, :) + H(9, :) .* P(3, :) + H(12, :) .* P(4, :);
        H(1, :) .* P(5, :) + H(4, :) .* P(6, :) + H(7, :) .* P(7, :) + H(10, :) .* P(8, :);
        H(2, :) .* P(5, :) + H(5, :) .* P(6, :) + H(8, :) .* P(7, :) + H(11, :) .* P(8, :);
        H(3, :) .* P(5, :) + H(6, :) .* P(6, :) + H(9, :) .* P(7, :) + H(12, :) .* P(8, :);
        H(1, :) .* P(9, :) + H(4, :) .* P(10, :) + H(7, :) .* P(11, :) + H(10, :) .* P(12, :);
        H(2, :) .* P(9, :) + H(5, :) .* P(10, :) + H(8, :) .* P(11, :) + H(11, :) .* P(12, :);
        H(3, :) .* P(9, :) + H(6, :) .* P(10, :) + H(9, :) .* P(11, :) + H(12, :) .* P(12, :);
        H(1, :) .* P(13, :) + H(4, :) .* P(14, :) + H(7, :) .* P(15, :) + H(10, :) .* P(16, :);
        H(2, :) .* P(13, :) + H(5, :) .* P(14, :) + H(8, :) .* P(15, :) + H(11, :) .* P(16, :);
        H(3, :) .* P(13, :) + H(6, :) .* P(14, :) + H(9, :) .* P(15, :) + H(12, :) .* P(16, :)];
  % S = H P H' + R (3x3, column by column)
  S = R + [HP(1, :) .* H(1, :) + HP(4, :) .* H(4, :) + HP(7, :) .* H(7, :) + HP(10, :) .* H(10, :);
       HP(2, :) .* H(1, :) + HP(5, :) .* H(4, :) + HP(8, :) .* H(7, :) + HP(11, :) .* H(10, :);
       HP(3, :) .* H(1, :) + HP(6, :) .* H(4, :) + HP(9, :) .* H(7, :) + HP(12, :) .* H(10, :);
       HP(1, :) .* H(2, :) + HP(4, :) .* H(5, :) + HP(7, :) .* H(8, :) + HP(10, :) .* H(11, :);
       HP(2, :) .* H(2, :) + HP(5, :) .* H(5, :) + HP(8, :) .* H(8, :) + HP(11, :) .* H(11, :);
       HP(3, :) .* H(2, :) + HP(6, :) .* H(5, :) + HP(9, :) .* H(8, :) + HP(12, :) .* H(11, :);
       HP(1, :) .* H(3, :) + HP(4, :) .* H(6, :) + HP(7, :) .* H(9, :) + HP(10, :) .* H(12, :);
       HP(2, :) .* H(3, :) + HP(5, :) .* H(6, :) + HP(8, :) .* H(9, :) + HP(11, :) .* H(12, :);
       HP(3, :) .* H(3, :) + HP(6, :) .* H(6, :) + HP(9, :) .* H(9, :) + HP(12, :) .* H(12, :)];
  S = reshape(S, 3, 3, m);
end
