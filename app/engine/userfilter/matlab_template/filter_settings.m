function s = filter_settings(s)
% FILTER_SETTINGS  Your filter's settings: change the fields you want and return s.
%
%   s = filter_settings(s)
%
% s arrives with Orientation Lab's settings (Calibrate's results, a profile, --settings), in
% the course's names:
%   s.Rw, s.Ra, s.Rm   3x3 noise covariances of the gyroscope, accelerometer, magnetometer
%   s.g0               3x1 gravity, [0; 0; g]
%   s.m0               3x1 Earth field [0; horizontal; vertical] in uT, or [] (the default):
%                      from the first magnetometer reading after the start
%   s.gyr_bias         3x1 gyroscope bias [rad/s], subtracted before tu_qw
%   s.acc_gate         task 8's gate [m/s^2]      s.mag_gate, s.mag_alpha: task 11's
%   s.max_dt           a longer time step [s] is a pause and is not integrated
%   s.gyr_hold_s       a gyroscope sample drives tu_qw at most this long [s]
%   s.no_gyro_random_walk    [rad/sqrt(s)] how fast P grows without a gyroscope (task 12)
%   s.initial_attitude_std   [rad] P at the start
%   s.rest_gyr_threshold, s.rest_acc_threshold, s.rest_min_duration: the Standstill light
%
% Your values win over Orientation Lab's. For example, with your task-2 results:
%   s.Ra = diag([0.0220 0.0226 0.0614]);
%   s.m0 = [0; 18.4; -41.5];
end
