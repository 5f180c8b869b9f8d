function [x, P] = mu_m(x, P, mag, m0, Rm)
% MU_M  Task 9: eq. (8), H = [dQ/dq_i' m0] (eqs. 2f-2i).
  q0 = x(1); q1 = x(2); q2 = x(3); q3 = x(4); a = m0(1); b = m0(2); c = m0(3);
  H = 2*[2*q0*a + q3*b - q2*c,  2*q1*a + q2*b + q3*c,  q1*b - q0*c,           q0*b + q1*c;
         -q3*a + 2*q0*b + q1*c, q2*a + q0*c,           q1*a + 2*q2*b + q3*c, -q0*a + q2*c;
         q2*a - q1*b + 2*q0*c,  q3*a - q0*b,           q0*a + q3*b,           q1*a + q2*b + 2*q3*c];
  Q = [2*(q0^2+q1^2)-1, 2*(q1*q2-q0*q3), 2*(q1*q3+q0*q2);
       2*(q1*q2+q0*q3), 2*(q0^2+q2^2)-1, 2*(q2*q3-q0*q1);
       2*(q1*q3-q0*q2), 2*(q2*q3+q0*q1), 2*(q0^2+q3^2)-1];
  S = H*P*H' + Rm;
  K = P*H'/S;
  x = x + K*(mag - Q'*m0);
  IKH = eye(4) - K*H;
  P = IKH*P*IKH' + K*Rm*K';
end
