function good = ol_good_state(x, P)
% OL_GOOD_STATE  Whether x is a real, finite 4x1 and P a real, finite 4x4.
  good = false;
  try
    good = isfloat(x) && isfloat(P) && all(size(x) == [4, 1]) && all(size(P) == [4, 4]) ...
           && isreal(x) && isreal(P) && isfinite(sum(x) + sum(P(:)));
  catch
    good = false;
  end
end
