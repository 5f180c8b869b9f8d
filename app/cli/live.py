"""The live commands: `send` (a phone emulator) and `serve` (the engine without a window).

Headless: they never import Qt. Bad arguments or unusable files give one line on stderr and
exit status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import itertools
import logging
import sys
import threading
import time

import ekf
from app.cli import options, phones
from app.engine import config
from app.engine.offline.filtering import EstimatesWriter
from app.engine.live.worker import on_finishing_signals
from app.engine.snapshot import Snapshot, lag_text
from app.engine.live.worker import Engine
from app.stream.emulator import PhoneEmulator
from app.stream.forwarder import LineForwarder
from app.stream.lines import LogError, line_blocks, read_lines
from app.stream.protocol import reasons_text
from app.stream.recorder import Recorder


# ---- send ---------------------------------------------------------------------------------------

def cmd_send(args: argparse.Namespace) -> int:
    path = config.resolve_log_path(args.log)
    if args.as_app != "sensor-fusion":
        try:
            lines = read_lines(path)
        except LogError as error:
            raise config.ConfigError(str(error)) from None
        return phones.send_as_app(args, lines)
    first_pass = line_blocks(path)          # the Sensor Fusion app's stream: block by block
    try:
        # a file that cannot be sent (missing, binary, empty) is one line before connecting
        passes = [itertools.chain([next(first_pass)], first_pass)]
    except LogError as error:
        raise config.ConfigError(str(error)) from None
    if args.gone:
        raise config.ConfigError("--gone: only with --as phyphox or --as sensor-logger")
    stop = threading.Event()
    try:
        with PhoneEmulator(args.host, args.port) as phone:
            sent = phone.stream_blocks(lambda: passes.pop() if passes else line_blocks(path),
                                       args.speed, args.loop, stop)
    except KeyboardInterrupt:
        return 130
    except LogError as error:           # the file broke off while it was being sent
        raise config.ConfigError(str(error)) from None
    except OSError as error:
        raise config.ConfigError(f"cannot send to {args.host}:{args.port}: "
                                 f"{error.strerror or error}") from None
    print(f"sent {sent} lines to {args.host}:{args.port}", file=sys.stderr)
    return 0


# ---- serve --------------------------------------------------------------------------------------

def health_line(snapshot: Snapshot) -> str:
    """One line of stream health (and the latest estimate) for the terminal."""
    health = snapshot.health
    rates = " ".join(f"{tag} {rate:.0f}Hz" for tag, rate in sorted(health.rates_hz.items()))
    peer = f" {health.peer}" if health.peer else ""
    parts = [f"{health.connection_state}{peer}", f"{health.lines_total} lines",
             f"{health.lines_per_s:.0f} lines/s", rates or "no samples"]
    if health.damaged:
        parts.append(f"{health.damaged} damaged ({reasons_text(health.damaged_reasons)})")
    counters = [(health.unknown, "unknown"), (health.too_long, "too long"),
                (health.out_of_order, "out of order"), (health.sessions, "new sessions")]
    parts += [f"{count} {name}" for count, name in counters if count]
    if health.waiting_peers:
        parts.append("waiting to stream: " + ", ".join(health.waiting_peers))
    if health.connections_closed:
        parts.append("connections closed: " + reasons_text(health.connections_closed))
    if health.clock_quirks:
        parts.append("clock: " + "; ".join(health.clock_quirks))
    if health.reorder_window_ms > 100:
        parts.append(lag_text(health))
    if health.recording and health.recording.startswith("recording stopped"):
        parts.append(health.recording)
    if snapshot.own_quat is not None and snapshot.t_ms is not None:
        q = snapshot.own_quat
        parts.append(f"t={snapshot.t_ms} q=({q[0]:.3f} {q[1]:.3f} {q[2]:.3f} {q[3]:.3f})")
    if health.forward is not None:
        parts.append(health.forward.summary())
    if snapshot.user is not None:
        parts.append(user_line(snapshot.user))
    return " | ".join(parts)


def user_line(user) -> str:
    """The user's filter in a few words: "yours my_filter.py running, 12 us/sample, 9 ms
    behind"."""
    text = f"yours {user.name} {user.state}"
    if user.time_per_sample_s == user.time_per_sample_s:
        text += f", {user.time_per_sample_s * 1e6:.0f} us/sample"
    if user.state == "running" and user.lag_s == user.lag_s:
        text += f", {user.lag_s * 1e3:.0f} ms behind"
    if user.slow:
        text += f", too slow: {user.used_fraction:.0%} of the samples used"
    if user.missing_steps:
        text += f", not written yet: {', '.join(s.split(' ')[0] for s in user.missing_steps)}"
    return text


def _recording(args: argparse.Namespace, settings: ekf.EKFSettings | None,
               estimator: str, source_kind: str = "tcp") \
        -> tuple[Recorder | None, EstimatesWriter | None]:
    """The recorder and estimates file of a session folder (None, None without --record). A
    folder that holds a session already is left alone: the recording goes to DIR-2, ...; a
    recording refused at its start leaves no folder behind."""
    if not args.record:
        return None, None
    try:
        recorder = Recorder(args.record, settings or ekf.PRESETS["default"],
                            info={"source": source_kind, "estimator": estimator},
                            max_bytes=args.record_max_mb,
                            min_free_bytes=args.record_min_free_mb)
    except OSError as error:
        raise config.ConfigError(str(error)) from None
    folder = recorder.directory
    note = config.recording_note(args.record, folder)
    if note:
        print(f"orientation-lab: {note}", file=sys.stderr, flush=True)
    try:
        writer = EstimatesWriter(folder / "estimates.csv")
    except OSError as error:
        recorder.discard()
        raise config.ConfigError(f"cannot write {folder / 'estimates.csv'}: "
                                 f"{error.strerror or error}") from None
    return recorder, writer


def _start_engine(args: argparse.Namespace) -> Engine:
    names = config.estimator_names(args.estimator)
    if len(names) != 1:
        raise config.ConfigError("serve: give exactly one --estimator")
    settings = config.load_settings(args.settings)
    source = config.make_source(options.source_options(args))
    try:
        source.start()               # the port first: a port in use makes no session folder
        recorder, writer = _recording(args, settings, names[0], source.kind)
    except OSError as error:
        source.stop()
        where = args.sensor_logger or f"{args.host}:{args.port}"
        raise config.ConfigError(f"cannot listen on {where}: "
                                 f"{error.strerror or error}") from None
    except BaseException:
        source.stop()
        raise
    forwarder = LineForwarder(*args.forward) if args.forward else None
    engine = Engine(source, settings, names[0], comparisons=not args.no_comparisons,
                    recorder=recorder, estimates=writer, limits=args.limits,
                    user_filter=args.filter, forwarder=forwarder)
    engine.start()                   # the source listens already
    return engine


class _Watch:
    """When serve should stop: --exit-after, --exit-when-idle, a fatal engine failure."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.started = self.last_activity = time.monotonic()
        self.seen_lines = 0
        self.streamed_once = False
        self.failures_shown = 0
        self.recording_shown = False
        self.user_said = ""
        self.user_printed = (0, 0)         # (generation, lines) of what your filter printed

    def _user_news(self, snapshot: Snapshot) -> None:
        """The user's filter's problems and reloads, each once, and what it printed, on
        stderr."""
        user = snapshot.user
        if user is None:
            return
        generation, shown = self.user_printed
        if user.generation != generation:
            shown = 0
        new = user.printed_total - shown
        if new > len(user.printed):
            print(f"orientation-lab: your filter printed {new - len(user.printed)} lines more",
                  file=sys.stderr)
        for line in user.printed[len(user.printed) - min(new, len(user.printed)):]:
            print(f"{user.name}: {line}", file=sys.stderr, flush=True)
        self.user_printed = (user.generation, user.printed_total)
        news = user.problem.message if user.problem is not None else user.message
        if news and news != self.user_said:
            self.user_said = news
            paused = " (paused until you save the file)" if user.problem is not None else ""
            print(f"orientation-lab: your filter: {news}{paused}", file=sys.stderr, flush=True)

    def done(self, engine: Engine, snapshot: Snapshot) -> bool:
        now = time.monotonic()
        health = snapshot.health
        if health.lines_total != self.seen_lines:
            self.last_activity = now
            self.seen_lines = health.lines_total
        if self.seen_lines:
            # a phone has streamed: a connection that sends nothing (a port probe, a stranger
            # that leaves) does not start the idle timer
            self.streamed_once = True
        for failure in snapshot.failures:
            if failure.number > self.failures_shown:
                self.failures_shown = failure.number
                then = "the engine stopped" if failure.fatal else "going on"
                print(f"orientation-lab: engine error ({then}): {failure.message}",
                      file=sys.stderr, flush=True)
        recording = health.recording or ""
        if recording.startswith("recording stopped") and not self.recording_shown:
            self.recording_shown = True
            print(f"orientation-lab: {recording} (the stream and the estimates go on)",
                  file=sys.stderr, flush=True)
        self._user_news(snapshot)
        if self.args.exit_after is not None and now - self.started >= self.args.exit_after:
            return True
        idle = self.args.exit_when_idle
        waiting_since = engine.waiting_since
        if (idle is not None and self.streamed_once and waiting_since is not None
                and now - max(self.last_activity, waiting_since) >= idle):
            return True
        return not engine.running


def cmd_serve(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    stop = threading.Event()
    # SIGTERM and SIGHUP (the terminal closed) finish the recording as Ctrl-C does
    restore_signals = on_finishing_signals(stop.set)
    try:
        engine = _start_engine(args)
    except BaseException:
        restore_signals()
        raise
    print(engine.source.connect_hint(), flush=True)
    snapshot = engine.snapshot_now()
    watch = _Watch(args)
    last_print = time.monotonic()
    try:
        while not stop.is_set():
            stop.wait(0.1)
            snapshot = engine.poll() or snapshot   # poll: drains the plot buffer
            if not args.quiet and time.monotonic() - last_print >= 1.0:
                print(health_line(snapshot), flush=True)
                last_print = time.monotonic()
            if watch.done(engine, snapshot):
                break
    except KeyboardInterrupt:
        pass
    finally:
        engine.stop()
        restore_signals()
    final = engine.snapshot_now()
    watch.done(engine, final)
    print("final: " + health_line(final), flush=True)
    return 1 if engine.stopped_by_failure else 0


# ---- registration -------------------------------------------------------------------------------

def add_commands(sub) -> None:
    send = sub.add_parser(
        "send", help="phone emulator: stream a log like the Sensor Fusion app, phyphox or "
                     "Sensor Logger",
        description="Connect to HOST:PORT like the Sensor Fusion app and stream LOG with its "
                    "original timing; --as phyphox serves it through phyphox's remote "
                    "interface on HOST:PORT, --as sensor-logger pushes it to --url.")
    send.add_argument("log", help="log file (.txt or .txt.gz) in the phone's format, or a "
                                  "recorded session folder")
    options.add_connect(send)
    options.add_speed_loop(send)
    phones.add_send_options(send)
    send.set_defaults(func=cmd_send)

    serve = sub.add_parser(
        "serve", help="receive the phone's stream without a window; print stream health",
        description="Listen for the phone, run the estimators and print stream health once a "
                    "second. Ctrl-C stops.")
    options.add_listen(serve)
    options.add_phone_apps(serve)
    options.add_record(serve)
    options.add_estimator(serve)
    options.add_settings(serve)
    options.add_limits(serve)
    options.add_filter(serve)
    options.add_octave(serve)
    options.add_forward(serve)
    serve.add_argument("--no-comparisons", action="store_true",
                       help="do not run the 7 sensor-combination comparison filters")
    serve.add_argument("--exit-after", type=options.NON_NEGATIVE, metavar="S",
                       help="stop after S seconds")
    serve.add_argument("--exit-when-idle", type=options.NON_NEGATIVE, metavar="S",
                       help="stop once a phone has sent lines and then nothing arrived for S s "
                            "(a connection that sends nothing does not count)")
    serve.add_argument("--quiet", action="store_true", help="print only the final summary")
    serve.set_defaults(func=cmd_serve)
