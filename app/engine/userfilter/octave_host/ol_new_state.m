function st = ol_new_state(s)
% OL_NEW_STATE  The loop's state before the first sample: x = q = (1, 0, 0, 0), P = I (the
% course's filterTemplate), nothing seen yet; m0 from the settings when they give one.
  st = struct();
  st.x = [1; 0; 0; 0];
  st.P = eye(4);
  st.t = NaN;
  st.started = false;
  st.heading_known = false;
  st.omega = zeros(3, 1);
  st.omega_t = -Inf;
  st.has_omega = false;
  st.acc = zeros(3, 1);
  st.has_acc = false;
  st.mag = zeros(3, 1);
  st.mag_t = -Inf;
  st.has_mag = false;
  st.m0 = s.m0;
  if isempty(s.m0)
    st.L = NaN;
  else
    st.L = norm(s.m0);
  end
  st.acc_out = false;
  st.mag_out = false;
  st.still_since = NaN;
  st.acc_smooth = zeros(3, 1);
  st.has_smooth = false;
end
