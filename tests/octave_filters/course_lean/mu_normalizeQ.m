function [x, P] = mu_normalizeQ(x, P)
% MU_NORMALIZEQ  q / |q| with q0 >= 0; P through the Jacobian J = (I - q q'/|q|^2)/|q| of that
% map (with the sign).
  n = sqrt(x'*x);
  s = 1 - 2*(x(1) < 0);
  J = s*(eye(4) - (x*x')/(n*n))/n;
  x = s*x/n;
  P = J*P*J';
  P = (P + P')/2;
end
