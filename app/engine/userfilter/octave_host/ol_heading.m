function [x, P, known] = ol_heading(x, P, mag, m0, start_std)
% OL_HEADING  The heading from the first magnetometer reading after a tilt-only start: turn
% about up so the reading's horizontal part points along m0's (north when m0 is not known yet).
  m_world = ol_Qq(x) * mag;
  known = m_world(1)^2 + m_world(2)^2 >= 1e-6;
  if ~known
    return;
  end
  if isempty(m0)
    ref = [0; 1; 0];
  else
    ref = m0;
  end
  psi = atan2(ref(1) * m_world(2) - ref(2) * m_world(1), ref(1) * m_world(1) + ref(2) * m_world(2));
  x = ol_turn_up(x, -psi);
  x = x / norm(x);
  if x(1) < 0
    x = -x;
  end
  G = ol_Sq(x);
  P = start_std^2 / 4 * (G * G');
end
