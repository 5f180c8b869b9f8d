function [x, P] = mu_g(x, P, yacc, Ra, g0)
% MU_G  Task 6, solved: y_a = Q(q)' g0 + e_a (eq. 7 with f_a = 0), the Joseph form for P.
  [Q0, Q1, Q2, Q3] = dQqdq(x);
  H = [Q0'*g0, Q1'*g0, Q2'*g0, Q3'*g0];
  S = H*P*H' + Ra;
  K = P*H'/S;
  x = x + K*(yacc - Qq(x)'*g0);
  IKH = eye(4) - K*H;
  P = IKH*P*IKH' + K*Ra*K';
end
