"""Every command-line option, defined once, and the argparse types that check them.

The window, `serve`, `send`, `filter` and `evaluate` share options (--host, --port, --settings,
--estimator, ...): each is added here by one function, with one help text and one check (the
checks are the engine's configuration functions, so the window's own controls apply the same
rules).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import ekf
from app.engine import config

EXIT_USAGE = 2


class Parser(argparse.ArgumentParser):
    """argparse with errors as one line on stderr and exit status 2 (no usage dump)."""

    def error(self, message: str) -> None:  # noqa: D102
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def _checked(check: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type from a config check (ConfigError -> argparse's one-line error)."""
    def convert(text: str) -> Any:
        try:
            return check(text)
        except config.ConfigError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    convert.__name__ = check.__name__
    return convert


def non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise config.ConfigError(f"not a number: {text!r}") from None
    if not value >= 0 or value == float("inf"):
        raise config.ConfigError(f"expected a number >= 0, got {text}")
    return value


def positive(text: str) -> float:
    value = non_negative(text)
    if value == 0:
        raise config.ConfigError(f"expected a number > 0, got {text}")
    return value


PORT = _checked(config.port_number)
SPEED = _checked(config.replay_speed)
NON_NEGATIVE = _checked(non_negative)
POSITIVE = _checked(positive)


def add_listen(parser: argparse.ArgumentParser) -> None:
    """--host, --port: where the phone connects."""
    parser.add_argument("--host", default=config.DEFAULT_HOST,
                        help="address to listen on for the phone (default: all interfaces)")
    parser.add_argument("--port", type=PORT, default=config.DEFAULT_PORT,
                        help=f"TCP port for the phone (default {config.DEFAULT_PORT}; 0 = any)")


def add_connect(parser: argparse.ArgumentParser) -> None:
    """--host, --port: the server to connect to (the emulator's side)."""
    parser.add_argument("--host", default="127.0.0.1", help="server address (default 127.0.0.1)")
    parser.add_argument("--port", type=PORT, default=config.DEFAULT_PORT,
                        help=f"server port (default {config.DEFAULT_PORT})")


def add_speed_loop(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--speed", type=SPEED, default=1.0,
                        help="time scale: 1 = original timing, 2 = twice as fast, "
                             "0 = as fast as possible (default 1)")
    parser.add_argument("--loop", action="store_true", help="start again at the end")


def add_settings(parser: argparse.ArgumentParser, help_text: str | None = None) -> None:
    presets = ", ".join(ekf.PRESETS)
    parser.add_argument("--settings", metavar="FILE.json|PRESET",
                        help=help_text or f"filter settings: a JSON file (e.g. from `calibrate` "
                                          f"or a session.json) or a preset ({presets})")


def add_estimator(parser: argparse.ArgumentParser, several: bool = False) -> None:
    names = ", ".join(ekf.ESTIMATORS)
    parser.add_argument("--estimator", default="ekf",
                        help=(f"estimator, or several separated by commas: {names}"
                              if several else f"estimator: {names}") + " (default ekf)")


def add_sensors(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sensors", default="gyr,acc,mag",
                        help="sensors the filter uses, a comma-separated subset of gyr,acc,mag "
                             "(default all)")


def add_smooth(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--smooth", action="store_true",
                        help="offline smoother: the EKF forward, then a backward "
                             "Rauch-Tung-Striebel pass (EKF only; every estimate uses the whole "
                             "recording)")


def add_truth(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--truth", metavar="FILE",
                        help="ORI-only log holding the ground truth (default: LOG's sibling "
                             "NAME.truth.txt if present, else LOG's own ORI); the phone's own "
                             "ORI is then scored as a row of its own")


def add_record(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--record", metavar="DIR",
                        help="record the session into DIR (raw.txt, session.json, "
                             "estimates.csv)")


def add_window(parser: argparse.ArgumentParser) -> None:
    """The window's options (no command): source, settings, screenshot."""
    group = parser.add_argument_group("window")
    add_listen(group)
    group.add_argument("--demo", action="store_true",
                       help="play the built-in demo session (still listening for the phone)")
    group.add_argument("--replay", metavar="LOG",
                       help="play a phone log, a recorded session folder or its session.json")
    add_speed_loop(group)
    add_settings(group)
    group.add_argument("--screenshot", metavar="PNG",
                       help="save the window to PNG after --exit-after seconds, then quit")
    group.add_argument("--exit-after", type=NON_NEGATIVE, metavar="S",
                       help="quit after S seconds")


def source_options(args: argparse.Namespace) -> config.SourceOptions:
    """The source the window's (or serve's) options describe."""
    return config.SourceOptions(host=args.host, port=args.port,
                                demo=bool(getattr(args, "demo", False)),
                                replay=getattr(args, "replay", None),
                                speed=getattr(args, "speed", 1.0),
                                loop=bool(getattr(args, "loop", False)))
