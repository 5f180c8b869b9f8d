function [x, P] = mu_normalizeQ(x, P)
% MU_NORMALIZEQ  Make q a unit quaternion with q0 >= 0 (the note after task 5).
%
%   [x, P] = mu_normalizeQ(x, P)
%
% The EKF does not keep |q| = 1: divide x(1:4) by its norm, and change the sign of q when
% q0 < 0 (q and -q are the same rotation). You may also carry P along with the normalisation
% (its Jacobian J = (I - q q'/|q|^2)/|q|: P = J P J').
%
% Orientation Lab calls it after every update. Until you write it, the step is skipped and q
% is normalised for display only.
  error('OrientationLab:notWritten', 'mu_normalizeQ is not written yet');
end
