function [nu, S] = ol_innovation(x, P, y, v0, R)
% OL_INNOVATION  For y = Q(q)' v0 + e (eqs. 7 and 8): the innovation y - Q(q)' v0 and its
% covariance S = H P H' + R, H = [dQ/dq0' v0, ..., dQ/dq3' v0] (eqs. 2f-2i): what the
% consistency view shows for the prior x, P.
  q0 = x(1); q1 = x(2); q2 = x(3); q3 = x(4);
  a = v0(1); b = v0(2); c = v0(3);
  % columns dQ/dqi' v0
  H = 2 * [2*q0*a + q3*b - q2*c,  2*q1*a + q2*b + q3*c,  q1*b - q0*c,            q0*b + q1*c;
           -q3*a + 2*q0*b + q1*c, q2*a + q0*c,            q1*a + 2*q2*b + q3*c,  -q0*a + q2*c;
           q2*a - q1*b + 2*q0*c,  q3*a - q0*b,            q0*a + q3*b,           q1*a + q2*b + 2*q3*c];
  nu = y - ol_Qq(x)' * v0;
  S = H * P * H' + R;
end
