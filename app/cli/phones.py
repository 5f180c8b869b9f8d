"""Any phone: `phyphox-experiment` (our experiment file and its QR code) and the phone
emulators of `send --as phyphox` / `send --as sensor-logger`.

Headless: no Qt. Bad arguments give one line and exit status 2.
"""

from __future__ import annotations

import argparse
import sys
import threading
from pathlib import Path

from app.engine import config
from app.engine.offline.outputs import check_output, open_output
from app.stream.emulator import PLATFORMS, PhyphoxPhone, SensorLoggerPhone, parse_push_url
from app.stream.phyphox_experiment import FILE_NAME, experiment_xml, qr_code

APPS = ("sensor-fusion", "phyphox", "sensor-logger")


# ---- phyphox-experiment -------------------------------------------------------------------------

def _write(path: str, write) -> None:
    check_output(path)
    with open_output(path, "wb") as stream:
        write(stream)


def cmd_phyphox_experiment(args: argparse.Namespace) -> int:
    kind = Path(args.qr).suffix.lower().lstrip(".") if args.qr else None
    if kind not in (None, "png", "svg"):
        raise config.ConfigError(f"--qr: a .png or .svg file, got {args.qr}")
    xml = experiment_xml().encode("utf-8")
    _write(args.output, lambda stream: stream.write(xml))
    print(f"phyphox experiment written to {args.output}; load it in phyphox with the + button "
          "(or scan the QR code in File > Connect a phone...)")
    if args.qr:
        code = qr_code()
        _write(args.qr, lambda stream: code.save(stream, kind=kind, scale=6, border=4))
        print(f"QR code written to {args.qr} (scan it with phyphox's + > Scan QR code)")
    return 0


# ---- send --as ----------------------------------------------------------------------------------

def add_send_options(parser: argparse.ArgumentParser) -> None:
    """The options of `send` that pick and set up the phone app it plays."""
    group = parser.add_argument_group("phone app (--as)")
    group.add_argument("--as", dest="as_app", choices=APPS, default="sensor-fusion",
                       help="the app to play: sensor-fusion (connect to HOST:PORT and send "
                            "lines, default), phyphox (serve the log through phyphox's remote "
                            "interface on HOST:PORT) or sensor-logger (push batches to --url)")
    group.add_argument("--url", help="sensor-logger: the push URL, e.g. http://127.0.0.1:8000/")
    group.add_argument("--period", type=_period, default=1.0, metavar="S",
                       help="sensor-logger: batch period in seconds (default 1)")
    group.add_argument("--platform", choices=PLATFORMS, default="android",
                       help="sensor-logger: android (totalacceleration with gravity) or ios "
                            "(accelerometer without gravity plus a gravity stream)")
    group.add_argument("--standardised", action="store_true",
                       help="sensor-logger --platform ios: Standardise Units & Frames on "
                            "(Android's signs and frames; off by default, as in the app)")
    group.add_argument("--device-id", metavar="ID",
                       help="sensor-logger: the deviceId to push with (default: a new one)")
    group.add_argument("--digits", type=int, default=0, metavar="N",
                       help="phyphox: round what is served to N significant digits, as the "
                            "phone does (about 8); 0 serves the log's values exactly (default)")
    group.add_argument("--start-ms", type=int, metavar="MS",
                       help="phyphox: the log's time (ms) at experiment time 0 (default: its "
                            "first sample, as on the phone; 0 serves the log's own times)")
    group.add_argument("--epoch-ms", type=int, metavar="MS",
                       help="sensor-logger: the phone clock's reading (UTC epoch ms) at the "
                            "log's first sample (default: now; its first sample's own time "
                            "pushes the log's times)")
    group.add_argument("--gone", type=_gone, metavar="AT:SECONDS",
                       help="phyphox, sensor-logger: the phone leaves the network when the "
                            "log reaches AT seconds, for SECONDS (phyphox refuses connections, "
                            "its measurement goes on; Sensor Logger's batches wait and go out "
                            "after)")
    group.add_argument("--started", action="store_true",
                       help="phyphox: the measurement runs from the start (default: it waits "
                            "for the PC to start it, as phyphox does until someone presses play)")


def _period(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.01 <= value <= 600:
        raise argparse.ArgumentTypeError(f"a batch period between 0.01 and 600 s, got {text}")
    return value


def _gone(text: str) -> tuple[float, float]:
    at, sep, seconds = str(text).partition(":")
    try:
        value = (float(at), float(seconds))
    except ValueError:
        value = (-1.0, -1.0)
    if not sep or not (value[0] >= 0 and value[1] > 0):
        raise argparse.ArgumentTypeError(f"expected AT:SECONDS, e.g. 300:5, got {text!r}")
    return value


def send_as_app(args: argparse.Namespace, lines: list[bytes]) -> int:
    """`send --as phyphox|sensor-logger`: play that app with the log's lines."""
    if args.as_app == "phyphox":
        return _serve_phyphox(args, lines)
    return _push_sensor_logger(args, lines)


def _serve_phyphox(args: argparse.Namespace, lines: list[bytes]) -> int:
    if args.loop:
        raise config.ConfigError("--loop: not with --as phyphox (phyphox's time never goes "
                                 "back; send the log again)")
    if args.digits < 0:
        raise config.ConfigError(f"--digits: 0 or more, got {args.digits}")
    phone = PhyphoxPhone(lines, args.host, args.port, speed=args.speed,
                         digits=args.digits or None, measuring=args.started,
                         start_ms=args.start_ms)
    try:
        phone.start()
    except OSError as error:
        raise config.ConfigError(f"cannot serve on {args.host}:{args.port}: "
                                 f"{error.strerror or error}") from None
    measuring = (f"; measuring since {phone.events[0]['systemTime']:.3f} (epoch s)"
                 if phone.events else "")
    print(f"phyphox (emulated) serving {len(lines)} lines on http://{args.host}:{phone.port}; "
          f"it stops once a client has fetched the whole log{measuring}", file=sys.stderr,
          flush=True)
    try:
        phone.serve_forever(gone=args.gone)
    except KeyboardInterrupt:
        return 130
    finally:
        phone.stop()
    print(f"served the log to its end ({phone.requests} requests, "
          f"{phone.overlapping_requests} overlapping another)", file=sys.stderr)
    return 0


def _push_sensor_logger(args: argparse.Namespace, lines: list[bytes]) -> int:
    if not args.url:
        raise config.ConfigError("--as sensor-logger needs --url (e.g. http://127.0.0.1:8000/)")
    try:
        parse_push_url(args.url)
    except ValueError as error:
        raise config.ConfigError(f"--url: {error}") from None
    first = next((int(line.split(b"\t", 1)[0]) for line in lines
                  if line.split(b"\t", 1)[0].isdigit()), 0)
    offset = None if args.epoch_ms is None else args.epoch_ms - first
    phone = SensorLoggerPhone(args.url, period_s=args.period, platform=args.platform,
                              standardised=args.standardised, device_id=args.device_id,
                              time_offset_ms=offset, gone=args.gone)
    stop = threading.Event()
    try:
        pushed = phone.stream_lines(lines, args.speed, args.loop, stop)
    except KeyboardInterrupt:
        return 130
    for message in phone.messages_shown:
        print(f"Sensor Logger would show: {message}", file=sys.stderr)
    statuses = ", ".join(f"{count} x {status}" for status, count in sorted(phone.statuses.items()))
    print(f"pushed {pushed} samples to {args.url} in {phone.message_id} batches "
          f"({statuses or 'none answered'}); the log's time + {phone.time_offset_ms} ms was the "
          "phone's clock (UTC epoch ms)", file=sys.stderr)
    if phone.message_id and not phone.statuses:
        raise config.ConfigError(f"cannot push to {args.url}: nothing answered")
    return 0


# ---- registration -------------------------------------------------------------------------------

def add_commands(sub) -> None:
    experiment = sub.add_parser(
        "phyphox-experiment", help="write Orientation Lab's phyphox experiment (and its QR code)",
        description="Write the phyphox experiment that streams the accelerometer, gyroscope, "
                    "magnetometer and the phone's orientation to Orientation Lab; load it in "
                    "phyphox by hand, or scan its QR code.")
    experiment.add_argument("-o", "--output", default=FILE_NAME, metavar="FILE.phyphox",
                            help=f"the experiment file (default {FILE_NAME})")
    experiment.add_argument("--qr", metavar="FILE.png|FILE.svg",
                            help="also write the QR code that loads it into phyphox")
    experiment.set_defaults(func=cmd_phyphox_experiment)
