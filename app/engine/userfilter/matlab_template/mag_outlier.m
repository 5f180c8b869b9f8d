function [outlier, L] = mag_outlier(mag, L, s)
% MAG_OUTLIER  Task 11: is this magnetometer reading disturbed (skip mu_m)?
%
%   [outlier, L] = mag_outlier(mag, L, s)
%
%   mag    3x1 magnetometer reading [uT]
%   L      the expected field strength so far [uT] (starts as norm(m0))
%   s      the settings (s.mag_gate [uT], s.mag_alpha, ...; see filter_settings.m)
%
% Return true to skip the update, and the new L: Orientation Lab keeps L between calls and
% hands it back to you with the next reading. The course's test: outlier when
% |norm(mag) - L| > s.mag_gate, with L following the strength as an AR(1) filter,
% L = (1 - s.mag_alpha) L + s.mag_alpha norm(mag). Shown as the "Mag disturbed" light
% (the kit's setMagDist).
%
% Until you write it, it says so and Orientation Lab uses the course's test. (Delete this file
% to use the course's test without the note.)
  error('OrientationLab:notWritten', 'mag_outlier (task 11) is not written yet');
end
