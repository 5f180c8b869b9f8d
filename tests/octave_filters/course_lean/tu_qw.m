function [x, P] = tu_qw(x, P, omega, T, Rw)
% TU_QW  Task 4: q_k = F q_k-1 + G v, F = I + T/2 S(omega), G = T/2 S-bar(q), eqs. (2d), (2e).
  a = T/2*omega;
  F = [1, -a(1), -a(2), -a(3); a(1), 1, a(3), -a(2); a(2), -a(3), 1, a(1); a(3), a(2), -a(1), 1];
  G = T/2*[-x(2), -x(3), -x(4); x(1), -x(4), x(3); x(4), x(1), -x(2); -x(3), x(2), x(1)];
  x = F*x;
  P = F*P*F' + G*Rw*G';
end
