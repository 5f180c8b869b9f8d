function S = Somega(w)
% SOMEGA  S(omega) of eq. (2d): dq/dt = 1/2 S(omega) q (row 3 ends in wx, as eq. 2d).
  wx = w(1); wy = w(2); wz = w(3);
  S = [0,  -wx, -wy, -wz;
       wx,  0,   wz, -wy;
       wy, -wz,  0,   wx;
       wz,  wy, -wx,  0];
end
