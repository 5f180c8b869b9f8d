function [still, st] = ol_standstill(st, s, T, G, V)
% OL_STANDSTILL  The standstill light of each row: neither the gyroscope (|omega - bias| above
% rest_gyr_threshold) nor the accelerometer (a reading farther than rest_acc_threshold from its
% low-pass 0.9 a_k-1 + 0.1 a_k) has moved for rest_min_duration. It depends on the readings
% only, so it is computed over the block at once; st carries still_since and the low-pass.
  n = numel(T);
  still = zeros(n, 1);
  if n == 0
    return;
  end
  W = V(1:3, :);
  A = V(4:6, :);
  gyr = G(1, :) & sum(W .^ 2, 1) <= 1e12;
  aa = sum(A .^ 2, 1);
  acc = G(2, :) & aa <= 1e12 & aa >= 1e-12;
  moving = gyr & sum((W - s.gyr_bias) .^ 2, 1) > s.rest_gyr_threshold^2;
  readings = A(:, acc);
  if ~isempty(readings)
    if ~st.has_smooth
      st.acc_smooth = readings(:, 1);
      st.has_smooth = true;
    end
    if columns(readings) == 1                     % filter() takes one column as a vector
      smooth = 0.9 * st.acc_smooth + 0.1 * readings;
    else
      smooth = filter(0.1, [1, -0.9], readings, 0.9 * st.acc_smooth', 2);
    end
    st.acc_smooth = smooth(:, end);
    moving(acc) = moving(acc) | sum((readings - smooth) .^ 2, 1) > s.rest_acc_threshold^2;
  end
  if st.still_since ~= st.still_since                       % NaN: the first reading starts it
    first = find(gyr | acc, 1);
    moving(first) = true;
  end
  index = cummax((1:n) .* moving);
  since = [st.still_since, T'];
  since = since(index + 1);
  still = (since == since & T' - since >= s.rest_min_duration)';
  st.still_since = since(end);
end
