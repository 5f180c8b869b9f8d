"""Every command-line option, defined once, and the argparse types that check them.

The window, `serve`, `send`, `filter` and `evaluate` share options (--host, --port, --settings,
--estimator, ...): each is added here by one function, with one help text and one check (the
checks are the engine's configuration functions, so the window's own controls apply the same
rules).
"""

from __future__ import annotations

import argparse
import math
import re
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
    """An argparse type from a config check (ConfigError -> argparse's one-line error, which
    names the option itself: a check's own "--option: " prefix is left out)."""
    def convert(text: str) -> Any:
        try:
            return check(text)
        except config.ConfigError as error:
            raise argparse.ArgumentTypeError(re.sub(r"^--[\w-]+: ", "", str(error))) from None
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


def finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise config.ConfigError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise config.ConfigError(f"expected a finite number, got {text}")
    return value


def seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise config.ConfigError(f"expected a whole number >= 0, got {text!r}") from None
    if value < 0:
        raise config.ConfigError(f"expected a whole number >= 0, got {text}")
    return value


def window_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise config.ConfigError(f"expected WIDTHxHEIGHT, e.g. 1280x720, got {text!r}") from None
    if not (320 <= width <= 10_000 and 240 <= height <= 10_000):
        raise config.ConfigError(f"window size out of range: {text}")
    return width, height


PORT = _checked(config.port_number)
WINDOW_SIZE = _checked(window_size)
FILTER_FILE = _checked(config.filter_file)
OCTAVE = _checked(config.octave_program)
FORWARD = _checked(config.forward_target)
SPEED = _checked(config.replay_speed)
NON_NEGATIVE = _checked(non_negative)
POSITIVE = _checked(positive)
FINITE = _checked(finite)
SEED = _checked(seed)
ALLOW = _checked(config.allowed_network)
LIMITS = _checked(config.sensor_limits)
MEGABYTES = _checked(config.megabytes)
SENSOR_LOGGER_FRAMES = _checked(config.sensor_logger_frames)


def add_listen(parser: argparse.ArgumentParser) -> None:
    """--host, --port: where the phone connects; --allow, --takeover-after: who may."""
    parser.add_argument("--host", default=config.DEFAULT_HOST,
                        help="address to listen on for the phone (default: all interfaces)")
    parser.add_argument("--port", type=PORT, default=config.DEFAULT_PORT,
                        help=f"TCP port for the phone (default {config.DEFAULT_PORT}; 0 = any)")
    parser.add_argument("--allow", type=ALLOW, action="append", metavar="ADDRESS[/PREFIX]",
                        help="only this address or network may connect (repeatable; default: "
                             "anyone); others are closed and counted")
    parser.add_argument("--takeover-after", type=NON_NEGATIVE, metavar="S",
                        default=config.DEFAULT_TAKEOVER_S,
                        help="a new connection waits while the phone streams; it takes over "
                             "once the stream has been silent S seconds (default "
                             f"{config.DEFAULT_TAKEOVER_S:g}) or has closed, or at once when "
                             "it streams at a phone's rate and the stream does not")


def add_phone_apps(parser: argparse.ArgumentParser) -> None:
    """--phyphox, --sensor-logger: the phone through phyphox or Sensor Logger instead."""
    parser.add_argument("--phyphox", metavar="URL",
                        help="poll phyphox's remote interface at the address it shows (e.g. "
                             "http://192.168.1.5:8080) instead of listening for the Sensor "
                             "Fusion app")
    parser.add_argument("--sensor-logger", metavar="[HOST:]PORT",
                        help="take Sensor Logger's HTTP Push on PORT (type http://THIS-PC:PORT/ "
                             "into Sensor Logger) instead of listening for the Sensor Fusion app")
    parser.add_argument("--sensor-logger-frames", type=SENSOR_LOGGER_FRAMES, default="auto",
                        metavar="auto|standardised|not-standardised",
                        help="Sensor Logger's Standardise Units & Frames setting (default auto: "
                             "told from its gravity and orientation)")


def add_limits(parser: argparse.ArgumentParser) -> None:
    """--limits: the physical bounds of a sample."""
    defaults = config.sensor_limits("").text()
    parser.add_argument("--limits", type=LIMITS, default=config.sensor_limits(""),
                        metavar="acc=A,gyr=G,mag=M,ori=T,floor=F",
                        help="physical bounds: |acc| <= A m/s^2, |gyr| <= G rad/s, |mag| <= M uT, "
                             "ORI norm within 1 +- T, |acc|, |mag| >= F (not a zero vector); a "
                             f"sample beyond them is a damaged line (default {defaults})")


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
    names = ", ".join(ekf.ESTIMATORS) + " or your own filter FILE.py"
    parser.add_argument("--estimator", default="ekf",
                        help=(f"estimator, or several separated by commas: {names}"
                              if several else f"estimator: {names}") + " (default ekf)")


def add_filter(parser: argparse.ArgumentParser) -> None:
    """--filter FILE.py: your own filter, run beside ours (YOURS)."""
    parser.add_argument("--filter", type=FILTER_FILE, metavar="FILE.py",
                        help="run your own filter (a Python file with class Filter; see "
                             "`orientation-lab new-filter`) beside ours as YOURS; it is "
                             "reloaded whenever you save it")


def add_octave(parser: argparse.ArgumentParser) -> None:
    """--octave PATH: the GNU Octave a MATLAB filter runs in."""
    parser.add_argument("--octave", type=OCTAVE, metavar="PATH",
                        help="GNU Octave's octave-cli (or its folder) to run a MATLAB filter in "
                             "(a folder of .m files as --filter or --estimator; default: "
                             "octave-cli found on PATH)")


def add_forward(parser: argparse.ArgumentParser) -> None:
    """--forward HOST:PORT: a copy of the phone's lines for another receiver."""
    parser.add_argument("--forward", type=FORWARD, metavar="HOST:PORT",
                        help="also send every line received from the phone, verbatim, to the "
                             "TCP server at HOST:PORT (e.g. the MATLAB kit's "
                             "StreamSensorDataReader); a slow or absent receiver never slows "
                             "the phone (lines that do not fit are dropped and counted)")


def add_traceback(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--traceback", action="store_true",
                        help="when your filter (FILE.py) fails, print its whole traceback")


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
                        help="record from the start into DIR (raw.txt, session.json, "
                             "estimates.csv); a folder holding a session already: DIR-2, ... "
                             "(the window: Ctrl+Shift+R starts and stops recording at any time)")
    parser.add_argument("--record-max-mb", type=MEGABYTES, default=config.megabytes(2048),
                        metavar="MB", help="stop recording when raw.txt reaches MB (default "
                                           "2048; 0 = no limit)")
    parser.add_argument("--record-min-free-mb", type=MEGABYTES, default=config.megabytes(256),
                        metavar="MB", help="stop recording when less than MB are free on the "
                                           "disk (default 256; 0 = no limit)")


def add_window(parser: argparse.ArgumentParser) -> None:
    """The window's options (no command): source, settings, screenshot."""
    group = parser.add_argument_group("window")
    add_listen(group)
    add_phone_apps(group)
    group.add_argument("--demo", action="store_true",
                       help="play the built-in demo session (still listening for the phone)")
    group.add_argument("--replay", metavar="PATH",
                       help="play a recorded session (its folder, raw.txt or session.json) or a "
                            "log saved on the phone")
    add_speed_loop(group)
    add_record(group)
    add_settings(group)
    add_limits(group)
    add_filter(group)
    add_octave(group)
    add_forward(group)
    group.add_argument("--screenshot", metavar="PNG",
                       help="save the window to PNG after --exit-after seconds, then quit")
    group.add_argument("--window-size", type=WINDOW_SIZE, metavar="WxH",
                       help="open the window at this size, e.g. 1280x720 (default: fitted to "
                            "the screen, or as it was last closed)")
    group.add_argument("--exit-after", type=NON_NEGATIVE, metavar="S",
                       help="quit after S seconds")


def source_options(args: argparse.Namespace) -> config.SourceOptions:
    """The source the window's (or serve's) options describe."""
    return config.SourceOptions(host=args.host, port=args.port,
                                demo=bool(getattr(args, "demo", False)),
                                replay=getattr(args, "replay", None),
                                speed=getattr(args, "speed", 1.0),
                                loop=bool(getattr(args, "loop", False)),
                                allow=tuple(getattr(args, "allow", None) or ()),
                                takeover_after_s=getattr(args, "takeover_after",
                                                         config.DEFAULT_TAKEOVER_S),
                                limits=getattr(args, "limits", None)
                                or config.sensor_limits(""),
                                phyphox=getattr(args, "phyphox", None),
                                sensor_logger=getattr(args, "sensor_logger", None),
                                sensor_logger_frames=getattr(args, "sensor_logger_frames",
                                                             "auto"))


def add_intervals(parser: argparse.ArgumentParser, flag: str = "--intervals",
                  help_text: str | None = None) -> None:
    parser.add_argument(flag, metavar="FILE.json",
                        help=help_text or "JSON with score_intervals_ms (default: LOG's sibling "
                                          ".json if present)")


def add_skip(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--skip", type=NON_NEGATIVE, default=0.0, metavar="S",
                        help="ignore the first S seconds (convergence), default 0")


def add_output(parser: argparse.ArgumentParser, what: str = "settings for the other commands",
               required: bool = False) -> None:
    parser.add_argument("-o", "--output", metavar="SETTINGS.json", required=required,
                        help=f"write {what} (JSON; --settings accepts it)")


def add_plots(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--plots", metavar="DIR",
                        help="also write the figures as PNG files into DIR (needs Qt: "
                             "PySide6 and pyqtgraph, drawn offscreen)")


def add_profile(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", metavar="NAME",
                        help="also keep the result in the named per-phone profile (the user's "
                             "data folder's profiles/; an existing profile is updated)")


def time_range(text: str) -> tuple[float, float]:
    """"A:B" seconds from the log's start -> (A, B), A < B; either may be empty (start, end)."""
    start, sep, end = str(text).partition(":")
    try:
        lo = float(start) if start.strip() else 0.0
        hi = float(end) if end.strip() else float("inf")
    except ValueError:
        raise config.ConfigError(f"not a time range START:END in seconds: {text!r}") from None
    if not sep or not 0 <= lo < hi:
        raise config.ConfigError(f"not a time range START:END in seconds: {text!r}")
    return lo, hi


TIME_RANGE = _checked(time_range)


def add_range(parser: argparse.ArgumentParser, flag: str, what: str) -> None:
    parser.add_argument(flag, type=TIME_RANGE, metavar="START:END",
                        help=f"{what}: seconds from the log's start (either end may be empty)")
