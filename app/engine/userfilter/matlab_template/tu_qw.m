function [x, P] = tu_qw(x, P, omega, T, Rw)
% TU_QW  Task 4: the EKF time update with the gyroscope as input (model 4a).
%
%   [x, P] = tu_qw(x, P, omega, T, Rw)
%
%   x      4x1 state, the quaternion q = [q0; q1; q2; q3]
%   P      4x4 state covariance
%   omega  3x1 measured angular rate [rad/s] (the gyroscope bias is already subtracted)
%   T      time since the previous sample [s]
%   Rw     3x3 covariance of the angular-rate noise v (eq. 5)
%
% Eq. (6), task 3: q_k = F(omega) q_k-1 + G(q) v, with F = I + T/2 S(omega) (eq. 2d, Somega)
% and G = T/2 S-bar(q) (eq. 2e, Sq); then P = F P F' + G Rw G'.
%
% Orientation Lab calls it before every sample, with the latest gyroscope rate, and calls
% mu_normalizeQ after it. Until you write it, it says so and the step is skipped (x and P stay).
  error('OrientationLab:notWritten', 'tu_qw (task 4) is not written yet');
end
