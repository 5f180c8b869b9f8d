function outlier = acc_outlier(yacc, g0, s)
% ACC_OUTLIER  Task 8: is this accelerometer reading an outlier (skip mu_g)?
%
%   outlier = acc_outlier(yacc, g0, s)
%
%   yacc   3x1 accelerometer reading [m/s^2]
%   g0     3x1 gravity in the world frame, [0; 0; g]
%   s      the settings (s.acc_gate [m/s^2], ...; see filter_settings.m)
%
% Return true to skip the update: the phone accelerates, so yacc is not only gravity. The
% course's test: |norm(yacc) - g| > s.acc_gate. Orientation Lab shows the result as the
% "Acc disturbed" light (the kit's setAccDist).
%
% Until you write it, it says so and Orientation Lab uses the course's test. (Delete this file
% to use the course's test without the note.)
  error('OrientationLab:notWritten', 'acc_outlier (task 8) is not written yet');
end
