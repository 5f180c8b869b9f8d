"""`orientation-lab send` (phone emulator) and `orientation-lab serve` (engine without a window).

Registered into the main parser by app/cli.py through :func:`add_subcommands`. Never imports Qt.
Each handler returns an exit code; bad arguments or unreadable files give one line on stderr and
exit status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

EXIT_USAGE = 2


def _error(message: str) -> int:
    print(f"orientation-lab: error: {message}", file=sys.stderr)
    return EXIT_USAGE


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port out of range 0-65535: {value}")
    return value


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text}")
    return value


def add_subcommands(subparsers) -> None:
    """Register `send` and `serve` on an argparse subparsers object."""
    send = subparsers.add_parser(
        "send", help="phone emulator: stream a log to a server like the Sensor Fusion app",
        description="Connect to HOST:PORT like the phone app and stream LOG with its original "
                    "timing.")
    send.add_argument("log", help="log file (.txt or .txt.gz) in the phone's format")
    send.add_argument("--host", default="127.0.0.1", help="server address (default 127.0.0.1)")
    send.add_argument("--port", type=_port, default=3400, help="server port (default 3400)")
    send.add_argument("--speed", type=_non_negative, default=1.0,
                      help="time scale: 1 = original timing, 2 = twice as fast, "
                           "0 = as fast as possible (default 1)")
    send.add_argument("--loop", action="store_true", help="start again at the end (Ctrl-C stops)")
    send.set_defaults(func=cmd_send)

    serve = subparsers.add_parser(
        "serve", help="receive the phone's stream without a window; print stream health",
        description="Listen for the phone, run the estimators and print stream health once a "
                    "second. Ctrl-C stops.")
    serve.add_argument("--host", default="0.0.0.0", help="listen address (default all interfaces)")
    serve.add_argument("--port", type=_port, default=3400, help="listen port (default 3400; 0 = any)")
    serve.add_argument("--record", metavar="DIR",
                       help="record the session into DIR (raw.txt + session.json)")
    serve.add_argument("--estimator", default="ekf", help="main estimator (default ekf)")
    serve.add_argument("--settings", metavar="FILE.json", help="filter settings (JSON)")
    serve.add_argument("--no-comparisons", action="store_true",
                       help="do not run the 7 sensor-combination comparison filters")
    serve.add_argument("--exit-after", type=_non_negative, metavar="S",
                       help="stop after S seconds")
    serve.add_argument("--exit-when-idle", type=_non_negative, metavar="S",
                       help="stop once a phone has connected and then nothing arrived for S s")
    serve.add_argument("--quiet", action="store_true", help="print only the final summary")
    serve.set_defaults(func=cmd_serve)


def cmd_send(args: argparse.Namespace) -> int:
    from app.io.emulator import PhoneEmulator, read_lines
    from app.io.logfile import LogError
    try:
        lines = read_lines(args.log)
    except LogError as error:
        return _error(str(error))
    stop = threading.Event()
    try:
        with PhoneEmulator(args.host, args.port) as phone:
            sent = phone.stream_lines(lines, args.speed, args.loop, stop)
    except KeyboardInterrupt:
        return 130
    except OSError as error:
        return _error(f"cannot send to {args.host}:{args.port}: {error.strerror or error}")
    print(f"sent {sent} lines to {args.host}:{args.port}", file=sys.stderr)
    return 0


def _health_line(snapshot) -> str:
    health = snapshot.health
    rates = " ".join(f"{tag} {rate:.0f}Hz" for tag, rate in sorted(health.rates_hz.items()))
    peer = f" {health.peer}" if health.peer else ""
    parts = [f"{health.connection_state}{peer}", f"{health.lines_total} lines",
             f"{health.lines_per_s:.0f} lines/s", rates or "no samples"]
    counters = [(health.damaged, "damaged"), (health.unknown, "unknown"),
                (health.too_long, "too long"), (health.out_of_order, "out of order")]
    parts += [f"{count} {name}" for count, name in counters if count]
    if health.clock_quirks:
        parts.append("clock: " + "; ".join(health.clock_quirks))
    if snapshot.own_quat is not None and snapshot.t_ms is not None:
        q = snapshot.own_quat
        parts.append(f"t={snapshot.t_ms} q=({q[0]:.3f} {q[1]:.3f} {q[2]:.3f} {q[3]:.3f})")
    return " | ".join(parts)


def cmd_serve(args: argparse.Namespace) -> int:
    import ekf

    from app.engine import Engine
    from app.io.recorder import Recorder
    from app.io.sources import TcpSource

    if args.estimator not in ekf.ESTIMATORS:
        return _error(f"--estimator: unknown {args.estimator!r}; choose from "
                      f"{', '.join(ekf.ESTIMATORS)}")
    settings = None
    if args.settings:
        try:
            settings = ekf.EKFSettings.load(args.settings)
        except (OSError, ValueError, TypeError) as error:
            return _error(f"bad settings file {args.settings}: {error}")
    source = TcpSource(args.host, args.port)
    recorder = None
    if args.record:
        try:
            recorder = Recorder(args.record, settings or ekf.PRESETS["default"],
                                info={"source": "tcp", "estimator": args.estimator})
        except OSError as error:
            return _error(str(error))
    engine = Engine(source, settings, args.estimator, comparisons=not args.no_comparisons,
                    recorder=recorder)
    try:
        engine.start()
    except OSError as error:
        if recorder is not None:
            recorder.close()
        return _error(f"cannot listen on {args.host}:{args.port}: {error.strerror or error}")

    stop = threading.Event()
    previous_handler = None
    if threading.current_thread() is threading.main_thread():
        previous_handler = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    addresses = ", ".join(source.info()["listen_addresses"] or [args.host])
    print(f"listening on port {source.port}; type one of these into the phone app: {addresses}",
          flush=True)
    snapshot = engine.snapshot_now()
    started = time.monotonic()
    last_print = started
    last_activity = started
    seen_lines = 0
    connected_once = False
    try:
        while not stop.is_set():
            stop.wait(0.1)
            snapshot = engine.poll() or snapshot   # poll: drains the plot buffer
            now = time.monotonic()
            health = snapshot.health
            if health.lines_total != seen_lines:
                last_activity = now
                seen_lines = health.lines_total
            if health.connection_state in ("connected", "disconnected") or seen_lines:
                connected_once = True
            if not args.quiet and now - last_print >= 1.0:
                print(_health_line(snapshot), flush=True)
                last_print = now
            if args.exit_after is not None and now - started >= args.exit_after:
                break
            waiting_since = engine.waiting_since
            if args.exit_when_idle is not None and connected_once and \
                    waiting_since is not None and \
                    now - max(last_activity, waiting_since) >= args.exit_when_idle:
                break
            if not engine.running:
                break
    except KeyboardInterrupt:
        pass
    finally:
        engine.stop()
        if previous_handler is not None:
            signal.signal(signal.SIGTERM, previous_handler)
    final = engine.snapshot_now()
    print("final: " + _health_line(final), flush=True)
    if engine.error:
        print(f"orientation-lab: {engine.error}", file=sys.stderr)
        return 1
    return 0
