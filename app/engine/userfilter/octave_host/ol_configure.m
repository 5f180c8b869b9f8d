function ctx = ol_configure(ctx, wire)
% OL_CONFIGURE  The settings (Orientation Lab's, then the folder's filter_settings.m) and a
% fresh state. filter_settings is either s = filter_settings(s) (change the fields you want) or
% s = filter_settings() (a struct of the fields you set).
  s = ol_settings(wire);
  if ctx.has.filter_settings
    try
      if nargin('filter_settings') == 0
        mine = filter_settings();
        if ~isstruct(mine)
          error('OrientationLab:output', 'filter_settings() returned a %s, expected a struct', ...
                class(mine));
        end
        for name = fieldnames(mine)'
          s.(name{1}) = mine.(name{1});
        end
      else
        s = filter_settings(s);
      end
      s = ol_check_settings(s);
    catch err
      ctx.problem = ol_error_problem(ctx, err, 'filter_settings', NaN, 'exception');
      s = ol_settings(wire);
    end
  end
  ctx.s = s;
  ctx.state = ol_new_state(s);
end
