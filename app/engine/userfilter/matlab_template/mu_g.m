function [x, P] = mu_g(x, P, yacc, Ra, g0)
% MU_G  Task 6: the EKF measurement update with the accelerometer.
%
%   [x, P] = mu_g(x, P, yacc, Ra, g0)
%
%   yacc   3x1 accelerometer reading [m/s^2], phone frame
%   Ra     3x3 accelerometer noise covariance
%   g0     3x1 gravity in the world frame (East-North-Up), [0; 0; g]
%
% Eq. (7) with f_a = 0: yacc = Q(q)' g0 + e_a. Q(q) is Qq(q) (eq. 2a); its derivatives
% dQ/dq_i (eqs. 2f-2i, dQqdq) give the Jacobian H = [Q0'*g0, Q1'*g0, Q2'*g0, Q3'*g0].
% Then the EKF update: S = H P H' + Ra, K = P H' / S, x = x + K (yacc - Q(q)' g0), P = P - K S K'.
%
% Orientation Lab calls it for each accelerometer reading that the outlier test of task 8 lets
% through (acc_outlier.m), then mu_normalizeQ. Until you write it, the step is skipped.
  error('OrientationLab:notWritten', 'mu_g (task 6) is not written yet');
end
