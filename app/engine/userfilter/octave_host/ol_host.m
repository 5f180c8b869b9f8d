% OL_HOST  Orientation Lab's host for a filter written in MATLAB, run by GNU Octave:
%
%   octave-cli --no-gui --norc --quiet --no-window-system ol_host.m CODE_DIR FOLDER
%
% CODE_DIR holds the copy of the filter's folder that runs (the bytes Orientation Lab hashed);
% FOLDER is the folder the user chose (named in messages). Requests arrive on stdin and replies
% leave on stdout as frames (app/engine/userfilter/protocol.py); anything the filter prints goes
% to stdout between frames, warnings and Octave's own messages to stderr.
1;
if exist('jsondecode', 'builtin') ~= 5
  fprintf(stderr, 'OrientationLab:octaveTooOld GNU Octave %s is too old: Orientation Lab needs Octave 7 or newer\n', OCTAVE_VERSION);
  exit(3);
end
args = argv();
if numel(args) < 2
  fprintf(stderr, 'usage: ol_host.m CODE_DIR FOLDER\n');
  exit(2);
end
more off;
page_screen_output(false);
crash_dumps_octave_core(false);       % never an octave-workspace file left in the folder
sighup_dumps_octave_core(false);
sigterm_dumps_octave_core(false);
page_output_immediately(true);
warning('off', 'Octave:shadowed-function');     % input.m, keyboard.m: no keyboard here
addpath(fileparts(mfilename('fullpath')));
ol_serve(args{end - 1}, args{end});
exit(0);
