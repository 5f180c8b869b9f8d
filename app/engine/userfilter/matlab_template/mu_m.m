function [x, P] = mu_m(x, P, mag, m0, Rm)
% MU_M  Task 9: the EKF measurement update with the magnetometer.
%
%   [x, P] = mu_m(x, P, mag, m0, Rm)
%
%   mag    3x1 magnetometer reading [uT], phone frame
%   m0     3x1 Earth field in the world frame, [0; sqrt(mx^2 + my^2); mz]
%   Rm     3x3 magnetometer noise covariance
%
% Eq. (8) with f_m = 0: mag = Q(q)' m0 + e_m; H = [Q0'*m0, Q1'*m0, Q2'*m0, Q3'*m0] from
% dQqdq (eqs. 2f-2i); then the same EKF update as in mu_g.
%
% Orientation Lab calls it for each magnetometer reading that the outlier test of task 11 lets
% through (mag_outlier.m), then mu_normalizeQ. m0 comes from the settings (Calibrate) or from
% the first reading after the start. Until you write it, the step is skipped.
  error('OrientationLab:notWritten', 'mu_m (task 9) is not written yet');
end
