function [m0, L] = ol_m0_from(x, mag)
% OL_M0_FROM  Task 9's m0 = (0, sqrt(mx^2 + my^2), mz) of a reading in the levelled world
% frame, and the field strength L = |m0| the outlier test of task 11 starts from.
  m = ol_Qq(x) * mag;
  m0 = [0; hypot(m(1), m(2)); m(3)];
  L = norm(m0);
end
