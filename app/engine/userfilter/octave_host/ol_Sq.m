function S = ol_Sq(q)
% OL_SQ  S-bar(q) of eq. (2e), Orientation Lab's own copy.
  S = [-q(2), -q(3), -q(4); q(1), -q(4), q(3); q(4), q(1), -q(2); -q(3), q(2), q(1)];
end
