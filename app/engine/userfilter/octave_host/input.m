function varargout = input(varargin)
% INPUT  In a filter run by Orientation Lab there is no keyboard: Octave's stdin carries the
% samples. Give values in filter_settings.m instead.
  error('OrientationLab:noKeyboard', ['input(): a filter has no keyboard (Orientation Lab ', ...
        'feeds it samples); give values in filter_settings.m']);
end
