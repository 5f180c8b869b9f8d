function q = ol_R2q(R)
% OL_R2Q  Eq. (2b) made safe: divides by the largest of the four q_i^2, never by ~0;
% unit length, q0 >= 0.
  tr = R(1,1) + R(2,2) + R(3,3);
  [~, k] = max([tr, R(1,1), R(2,2), R(3,3)]);
  switch k
    case 1
      s = 2 * sqrt(max(1 + tr, 0));
      q = [s/4; (R(3,2)-R(2,3))/s; (R(1,3)-R(3,1))/s; (R(2,1)-R(1,2))/s];
    case 2
      s = 2 * sqrt(max(1 + R(1,1) - R(2,2) - R(3,3), 0));
      q = [(R(3,2)-R(2,3))/s; s/4; (R(1,2)+R(2,1))/s; (R(1,3)+R(3,1))/s];
    case 3
      s = 2 * sqrt(max(1 - R(1,1) + R(2,2) - R(3,3), 0));
      q = [(R(1,3)-R(3,1))/s; (R(1,2)+R(2,1))/s; s/4; (R(2,3)+R(3,2))/s];
    otherwise
      s = 2 * sqrt(max(1 - R(1,1) - R(2,2) + R(3,3), 0));
      q = [(R(2,1)-R(1,2))/s; (R(1,3)+R(3,1))/s; (R(2,3)+R(3,2))/s; s/4];
  end
  q = q / norm(q);
  if q(1) < 0
    q = -q;
  end
end
