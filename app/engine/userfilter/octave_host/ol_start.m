function [x, P, heading_known] = ol_start(acc, mag, fresh_mag, start_std)
% OL_START  The first orientation, from the first accelerometer reading (tilt) and, when a
% magnetometer reading came within 0.1 s and is not along gravity, its heading (TRIAD: east
% along mag x up, north = up x east); else heading 0 until the first magnetometer reading.
% P = start_std^2/4 S(q) S(q)' (plus 1/4 S(q) S(q)' while the heading is unknown).
  up = acc / norm(acc);
  heading_known = fresh_mag && norm(cross(mag, up)) > 1e-6 * norm(mag);
  if heading_known
    east = cross(mag, up);
    east = east / norm(east);
    x = ol_R2q([east'; cross(up, east)'; up']);
  else
    if abs(up(1)) < 0.9
      ref = [1; 0; 0];
    else
      ref = [0; 1; 0];
    end
    north = cross(up, ref);
    north = north / norm(north);
    q = ol_R2q([cross(north, up)'; north'; up']);
    x = ol_turn_up(q, -2 * atan2(q(4), q(1)));
    x = x / norm(x);
    if x(1) < 0
      x = -x;
    end
  end
  G = ol_Sq(x);
  P = start_std^2 / 4 * (G * G');
  if ~heading_known
    P = P + (G * G') / 4;
  end
end
