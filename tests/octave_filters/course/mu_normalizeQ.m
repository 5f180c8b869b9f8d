function [x, P] = mu_normalizeQ(x, P)
% MU_NORMALIZEQ  q / |q| with q0 >= 0, and P through the Jacobian of that map,
% J = (I - q q'/|q|^2)/|q|, so that P keeps no part along q.
  n = norm(x);
  J = (eye(4) - x*x'/n^2)/n;
  x = x/n;
  if x(1) < 0
    x = -x;
    J = -J;
  end
  P = J*P*J';
  P = (P + P')/2;
end
