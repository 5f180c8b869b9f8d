function q = ol_turn_up(q, angle)
% OL_TURN_UP  The orientation q turned about the world's up axis by angle [rad]:
% (cos(angle/2), 0, 0, sin(angle/2)) * q.
  c = cos(angle / 2); s = sin(angle / 2);
  q = [c*q(1) - s*q(4); c*q(2) - s*q(3); c*q(3) + s*q(2); c*q(4) + s*q(1)];
end
