"""Command line: `orientation-lab` opens the window; subcommands run headless.

Headless commands (filter, evaluate, calibrate, calibrate-mag, tune, simulate, send, serve)
never import Qt; the window's module is imported only when the window opens (and app.ui.figures
only for --plots). Any bad argument or unusable file gives
a one-line error on stderr and exit status 2, no traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from app import __version__, paths
from app.cli import calibration, live, offline, phones
from app.cli.options import EXIT_USAGE, Parser, add_window, source_options
from app.engine.config import ConfigError
from app.engine.userfilter.octave import use_octave


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="orientation-lab",
                    description="Orientation Lab: a quaternion EKF beside the phone's own "
                                "estimate. Without a command, opens the window listening for "
                                "the phone.")
    parser.add_argument("--version", action="version", version=f"orientation-lab {__version__}")
    add_window(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    offline.add_commands(sub)
    calibration.add_commands(sub)
    live.add_commands(sub)
    phones.add_commands(sub)
    return parser


def open_window(args: argparse.Namespace) -> int:
    from app.ui.main import WindowOptions, run_gui   # Qt only for the window
    return run_gui(WindowOptions(source=source_options(args), settings=args.settings,
                                 screenshot=args.screenshot, exit_after=args.exit_after,
                                 size=args.window_size, filter=args.filter,
                                 forward=args.forward, record=args.record,
                                 record_max_mb=args.record_max_mb / 2**20,
                                 record_min_free_mb=args.record_min_free_mb / 2**20))


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    use_octave(getattr(args, "octave", None))
    try:
        paths.data_dir(create=False)
        command = getattr(args, "func", None) or open_window
        return int(command(args) or 0)
    except (ConfigError, paths.DataDirError) as error:
        print(f"orientation-lab: error: {error}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
