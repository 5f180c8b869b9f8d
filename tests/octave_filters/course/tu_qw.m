function [x, P] = tu_qw(x, P, omega, T, Rw)
% TU_QW  Task 4, solved: q_k = F q_{k-1} + G v, F = I + T/2 S(omega), G = T/2 S-bar(q).
  F = eye(4) + T/2*Somega(omega);
  G = T/2*Sq(x);
  x = F*x;
  P = F*P*F' + G*Rw*G';
end
