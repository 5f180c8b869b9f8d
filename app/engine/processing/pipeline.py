"""Bytes -> estimates: the engine's processing, one object the live engine, a replay's session
index and the exports share (so all three give the same estimates, bit for bit).

:class:`Pipeline` holds the compiled parser, the time orderer and the estimator runner, the
session's time origin (the plots count seconds from it) and the changes of the configuration
over time that the current pass applies (:mod:`app.engine.processing.configuration`): sensor
switches, estimator, settings and comparisons changes, resets and alignments at their sample
positions (``fed``: samples fed to the estimators since the pass started), applied at exactly those
positions. Its whole state is one :class:`Checkpoint <app.engine.processing.checkpoints.Checkpoint>`
(:meth:`checkpoint`, :meth:`restore`).

The owner hands it its callbacks when it makes it: ``on_cut(rows, piece)`` gets the output of
a session that ended (a clock that does not continue: the estimators start afresh, the time
origin is set again), ``on_event(kind, **data)`` a "session" event for the recording's
timeline, ``on_parsed(parsed)`` every parsed piece, ``on_ordered(t_ms, tag, values)`` every
ordered sample fed to the estimators, ``on_applied(change, data)`` every change applied.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

import ekf
from app.engine.processing.checkpoints import Checkpoint, pack_runner, unpack_runner
from app.engine.processing.configuration import Change, Config, Setup, apply_change, changes_due
from app.engine.processing.runner import SENSORS, EstimatorRunner, Rows
from app.engine.snapshot import PlotChunk
from app.stream import fastparse
from app.stream.fastparse import ParsedArrays
from app.stream.ordering import OrderedArrays, TimeOrderer
from app.stream.protocol import DEFAULT_LIMITS, Limits


class Pipeline:
    """Parser -> orderer -> runner (see the module docstring)."""

    def __init__(self, runner: EstimatorRunner, limits: Limits = DEFAULT_LIMITS,
                 orderer_options: dict[str, Any] | None = None,
                 on_cut: Callable[[Rows, PlotChunk], None] | None = None,
                 on_event: Callable[..., None] | None = None,
                 on_parsed: Callable[[ParsedArrays], None] | None = None,
                 on_ordered: Callable[[np.ndarray, np.ndarray, np.ndarray], None] | None = None,
                 on_applied: Callable[[Change, dict[str, Any]], None] | None = None) -> None:
        self.runner = runner
        self.limits = limits
        self.orderer_options = dict(orderer_options or {})
        self.parser = fastparse.FastLineParser(limits=limits)
        self.orderer = TimeOrderer(**self.orderer_options)
        self.on_cut = on_cut or (lambda rows, piece: None)
        self.on_event = on_event or (lambda kind, **data: None)
        self.on_parsed = on_parsed
        self.on_ordered = on_ordered
        self.on_applied = on_applied
        self.t0_ms: int | None = None        # the session's start: plots count time from it
        self.piece_first_ms: int | None = None   # the earliest time in the latest output piece
        self.fed = 0                         # samples fed to the estimators in this pass
        self.fed_total = 0                   # ... ever (never restored)
        self.timeline: tuple[Change, ...] = ()   # the changes this pass applies, in order
        self.timeline_next = 0               # ... the next one not applied yet
        self.order_retired = 0               # out-of-order counts of restored orderer states

    # -- sinks -------------------------------------------------------------------------------

    def set_raw_sinks(self, line_sink=None, block_sink=None) -> None:
        """Where every line that parses goes, verbatim (a recording's raw.txt); None: nowhere."""
        self.parser.raw_sink = line_sink
        self.parser.raw_block_sink = block_sink

    # -- samples -----------------------------------------------------------------------------

    def feed_bytes(self, data: bytes) -> None:
        """Received bytes (any chunking) -> parser, orderer, estimators."""
        self.parsed(self.parser.feed_arrays(data))

    def parsed(self, parsed: ParsedArrays) -> None:
        if self.on_parsed is not None:
            self.on_parsed(parsed)
        if len(parsed.t_ms):
            self.feed_ordered(self.orderer.push_arrays(parsed.t_ms, parsed.tag, parsed.values))

    def feed_ordered(self, ordered: OrderedArrays) -> None:
        if not len(ordered.session_starts):
            if len(ordered):
                self._feed_runner(ordered.t_ms, ordered.tag, ordered.values)
            return
        # A clock that does not continue the previous stream's: nothing carries over (the
        # session may start while its first samples are still held: nothing released yet), and
        # the plots count time from the new session's start.
        for new, piece in ordered.pieces():
            if new:
                self.on_event("session", reason="the clock does not continue")
                self.runner.finish()
                self.cut()
                self.runner.new_session()
            self._feed_runner(ordered.t_ms[piece], ordered.tag[piece], ordered.values[piece])

    def feed_samples(self, t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray) -> None:
        """Ordered filter-tag samples straight to the estimators (no parser, no orderer), the
        pass's changes applied at their positions (a re-run of ordered samples)."""
        self._feed_runner(t_ms, tag, values)

    def _feed_runner(self, t_ms: np.ndarray, tag: np.ndarray, values: np.ndarray) -> None:
        """Samples to the estimators, the pass's changes applied between them at their sample
        positions."""
        if self.on_ordered is not None:
            self.on_ordered(t_ms, tag, values)
        changes = self.timeline
        start = 0
        count = len(t_ms)
        while self.timeline_next < len(changes):
            position = changes[self.timeline_next].sample - self.fed
            if position > count - start:
                break
            if position > 0:
                self.runner.feed_arrays(t_ms[start:start + position], tag[start:start + position],
                                        values[start:start + position])
                self.fed += position
                self.fed_total += position
                start += position
            self.apply_change(changes[self.timeline_next])
            self.timeline_next += 1
        if start < count:
            self.runner.feed_arrays(t_ms[start:], tag[start:], values[start:])
            self.fed += count - start
            self.fed_total += count - start

    def apply_change(self, change: Change) -> None:
        """One change applied to the estimators now (and handed to on_applied)."""
        data = apply_change(self.runner, change)
        if self.on_applied is not None:
            self.on_applied(change, data)

    def use_timeline(self, changes: tuple[Change, ...]) -> None:
        """Go on with these changes (a configuration's, in sample order): those before the
        current position count as applied, and those at it that were; the others at or before
        it apply now."""
        self.timeline_next = changes_due(tuple(changes), self.timeline[:self.timeline_next],
                                         self.fed)
        self.timeline = tuple(changes)
        self.apply_due()

    def apply_due(self) -> None:
        """Apply the changes due at the current position (a pass's start, a new change)."""
        changes = self.timeline
        while self.timeline_next < len(changes) and \
                changes[self.timeline_next].sample <= self.fed:
            self.apply_change(changes[self.timeline_next])
            self.timeline_next += 1

    def begin(self, checkpoint: Checkpoint, changes: tuple[Change, ...]) -> None:
        """Go on from a checkpoint of a pass that applies `changes`."""
        self.restore(checkpoint)
        self.continue_with(changes)

    def continue_with(self, changes: tuple[Change, ...]) -> None:
        """After :meth:`restore`: the pass applies `changes` (the checkpoint's, which says how
        many of them are applied); those due apply now."""
        self.timeline = tuple(changes)
        self.apply_due()

    def end_of_stream(self, partial_line_damaged: bool) -> None:
        """The current stream ended: a partial line is dropped (a line cut by a disconnect is
        damaged), pending samples are released, the last row is committed."""
        parser = self.parser
        if partial_line_damaged:
            parser.cut_off()
        else:
            self.parsed(parser.finish_arrays())
        self.feed_ordered(self.orderer.flush_arrays())
        self.runner.finish()

    def restart(self, continue_time: bool = False) -> None:
        """A new connection: the orderer learns the clocks again."""
        self.feed_ordered(self.orderer.restart_arrays(continue_time=continue_time))

    # -- output ------------------------------------------------------------------------------

    def cut(self) -> None:
        """A session ends here: its output goes to on_cut with its time origin, and the next
        samples set a new one."""
        rows, piece = self.take_output()
        self.on_cut(rows, piece)
        self.t0_ms = None

    def flush_output(self) -> None:
        """The output so far to on_cut now, in the session's time (a seek's re-sync)."""
        self.on_cut(*self.take_output())

    def count_damaged(self, reason: str, example: str) -> None:
        """A damaged line the parser did not see (a replay's torn last line)."""
        self.parser.count_damaged(reason, example)

    def take_output(self) -> tuple[Rows, PlotChunk]:
        """The rows committed since the last call and the plot samples as a PlotChunk in
        seconds since the session's start."""
        runner = self.runner
        rows = runner.take_rows()
        return rows, self.plot_piece(rows, runner.take_plot_samples())

    def plot_piece(self, rows: Rows, plot: dict[str, np.ndarray]) -> PlotChunk:
        runner = self.runner
        ori_t, ori_q = runner.take_phone_samples()
        errors = runner.take_errors()
        rows = rows.select(rows.has_sample)         # OWN at our own estimate times
        firsts = [int(t[0]) for t in (rows.t_ms, plot["t_acc"], plot["t_gyr"],
                                      plot["t_mag"], ori_t) if len(t)]
        self.piece_first_ms = min(firsts) if firsts else None
        if self.t0_ms is None:
            self.t0_ms = self.piece_first_ms
        t0 = self.t0_ms or 0
        count = len(rows)
        if count or len(ori_q):
            # one call for both series (the per-call overhead dominates at live chunk sizes)
            euler = np.degrees(ekf.quaternion.to_euler(np.concatenate([rows.quat, ori_q])))
        else:
            euler = np.empty((0, 3))

        def seconds(t_ms: np.ndarray) -> np.ndarray:
            return (np.asarray(t_ms, np.float64) - t0) / 1000.0

        innovations = runner.take_innovations()
        if "t_innovation" in innovations:
            innovations["t_innovation"] = seconds(np.asarray(innovations["t_innovation"]) * 1000.0)
        return PlotChunk(
            **self._user_plot(seconds), **innovations,
            t_acc=seconds(plot["t_acc"]), acc=plot["acc"], acc_rejected=plot["acc_rejected"],
            t_gyr=seconds(plot["t_gyr"]), gyr=plot["gyr"],
            t_mag=seconds(plot["t_mag"]), mag=plot["mag"], mag_rejected=plot["mag_rejected"],
            t_est=seconds(rows.t_ms), own_euler_deg=euler[:count],
            t_ori=seconds(ori_t), phone_euler_deg=euler[count:],
            t_err=seconds(errors.t_ms), error_deg=errors.error_deg)

    def _user_plot(self, seconds) -> dict[str, np.ndarray]:
        """YOURS for the plots, as its rows came back from your filter's process: its Euler
        angles (wrapped, at our estimate times, NaN where it has none) and its errors against
        PHONE at PHONE's times."""
        errors = self.runner.take_user_errors()
        out = {"t_user_err": seconds(errors.t_ms), "user_error_deg": errors.error_deg}
        t_ms, quat = self.runner.take_user_rows()
        if not len(t_ms):
            return out
        euler = np.full((len(t_ms), 3), np.nan)
        finite = np.isfinite(quat).all(axis=1)
        if finite.any():
            euler[finite] = np.degrees(ekf.quaternion.to_euler(quat[finite]))
        return {**out, "t_user": seconds(t_ms), "user_euler_deg": euler}

    # -- state -------------------------------------------------------------------------------

    def checkpoint(self, line: int) -> Checkpoint:
        """The whole state now, as after lines 0..line-1 of a replay."""
        return Checkpoint(line, pack_runner(self.runner.snapshot()), self.orderer.snapshot(),
                          self.parser.line_state(), self.t0_ms, self.fed, self.timeline_next,
                          self.runner.latest_t_ms)

    def restore(self, checkpoint: Checkpoint) -> None:
        """Go on from a checkpoint (the outputs not yet taken are dropped)."""
        self.runner.restore(unpack_runner(checkpoint.runner))
        self.order_retired += self.orderer.stats.out_of_order
        self.orderer.restore(checkpoint.orderer)
        self.order_retired -= self.orderer.stats.out_of_order
        self.parser.restore_line_state(checkpoint.parser)
        self.t0_ms = checkpoint.t0_ms
        self.fed = checkpoint.fed
        self.timeline_next = checkpoint.timeline_next

    def initial_checkpoint(self, setup: Setup) -> Checkpoint:
        """The state a replay pass of `setup` starts from, at line 0 (made with fresh objects
        of the same options; this pipeline is not changed)."""
        start = setup.start_state
        if start is not None:
            return Checkpoint(0, pack_runner(_started(start["runner"], setup.start)),
                              start["orderer"],
                              (b"", False, bool(start.get("ori4_seen", False))), None, 0, 0,
                              None)
        runner = EstimatorRunner(setup.estimator, setup.settings, setup.sensors or SENSORS,
                                 comparisons=False,
                                 comparison_estimator=setup.comparison_estimator)
        for sensor in SENSORS:
            runner.set_sensor_enabled(sensor, sensor in setup.sensors)
        runner.set_comparisons_enabled(setup.comparisons)
        orderer = TimeOrderer(**self.orderer_options)
        return Checkpoint(0, pack_runner(runner.snapshot()), orderer.snapshot(),
                          (b"", False, False), None, 0, 0, None)

    def start_state(self) -> dict[str, Any]:
        """What session.json's start_state keeps of a recording that starts now."""
        return {"runner": self.runner.snapshot(), "orderer": self.orderer.snapshot(),
                "ori4_seen": self.parser.line_state()[2]}


def _started(snapshot: dict[str, Any], config: Config) -> dict[str, Any]:
    """A recording's start state (a runner snapshot) with `config` where it differs (your
    overrides of a recording that started mid-stream: its state, your values)."""
    runner = EstimatorRunner(collect_plot=False)
    runner.restore(snapshot)
    changes = Config.of(runner).changes_to(config, 0)
    if not changes:
        return snapshot
    for change in changes:
        apply_change(runner, change)
    return runner.snapshot()


def check_start_state(start: Any) -> None:
    """ValueError (one line) when a session's start_state is not an engine state a pipeline can
    continue from (it is restored once into a scratch pipeline)."""
    if start is None:
        return
    pipeline = Pipeline(EstimatorRunner(collect_plot=False))
    try:
        pipeline.restore(pipeline.initial_checkpoint(Setup(start_state=start)))
    except Exception:   # noqa: BLE001 (any failure means the same: not a state we wrote)
        raise ValueError("start_state is not an engine state this program recorded") from None
