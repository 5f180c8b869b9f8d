function [x, P] = mu_m(x, P, mag, m0, Rm)
% MU_M  Task 9, solved: y_m = Q(q)' m0 + e_m (eq. 8 with f_m = 0), the Joseph form for P.
  [Q0, Q1, Q2, Q3] = dQqdq(x);
  H = [Q0'*m0, Q1'*m0, Q2'*m0, Q3'*m0];
  S = H*P*H' + Rm;
  K = P*H'/S;
  x = x + K*(mag - Qq(x)'*m0);
  IKH = eye(4) - K*H;
  P = IKH*P*IKH' + K*Rm*K';
end
