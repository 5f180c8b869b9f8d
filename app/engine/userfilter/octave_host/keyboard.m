function keyboard(varargin)
% KEYBOARD  No debugging prompt in a filter run by Orientation Lab: Octave's stdin carries the
% samples.
  error('OrientationLab:noKeyboard', ['keyboard(): a filter has no keyboard (Orientation ', ...
        'Lab feeds it samples); print values with disp or printf instead']);
end
