function [x, P] = mu_g(x, P, yacc, Ra, g0)
% MU_G  Task 6: eq. (7), H = [dQ/dq_i' g0] (eqs. 2f-2i) for g0 = [0; 0; g].
  q0 = x(1); q1 = x(2); q2 = x(3); q3 = x(4); g = g0(3);
  H = 2*g*[-q2, q3, -q0, q1; q1, q0, q3, q2; 2*q0, 0, 0, 2*q3];
  yhat = g*[2*(q1*q3 - q0*q2); 2*(q2*q3 + q0*q1); 2*(q0^2 + q3^2) - 1];
  S = H*P*H' + Ra;
  K = P*H'/S;
  x = x + K*(yacc - yhat);
  IKH = eye(4) - K*H;
  P = IKH*P*IKH' + K*Ra*K';
end
