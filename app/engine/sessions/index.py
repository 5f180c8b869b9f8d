"""A replay's index: checkpoints every second of data and the whole session's plot data, built
once in a background thread when a replay opens (and again when its set-up changes).

The index runs the replay's lines through its own :class:`~app.engine.processing.pipeline.Pipeline`,
the engine's processing, with the same set-up, as fast as the compiled kernels go, one second of
lines (by the replay's own timing) at a time, and after each second keeps

* a :class:`~app.engine.processing.checkpoints.Checkpoint`: a seek restores the latest one at or
before
  its target and replays at most one second;
* the plot samples of that second (:class:`SessionPlot`): the window can scroll and zoom over
  the whole session, not only the last minutes its rolling buffers hold.

Because it is the same processing on the same lines, a checkpoint's state is exactly the live
engine's state at that line and the plotted curves are exactly what the engine computes.

Memory, per hour at 100 Hz (ACC, GYR, ORI 100 Hz, MAG 50 Hz): the plot data about 50 MB (times
float64, values float32 in the plots' own column layout, so the window draws them without a
copy), the checkpoints about 30 MB with the 7 comparison filters (8 estimators x ~1 KB x 3,600).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.engine.processing.checkpoints import Checkpoint, CheckpointStore
from app.engine.processing.configuration import Setup
from app.engine.processing.pipeline import Pipeline
from app.engine.processing.runner import EstimatorRunner
from app.engine.snapshot import PlotChunk

CHECKPOINT_INTERVAL_S = 1.0
# plot streams in the plots' column layout: name -> (time field, value columns)
PLOT_STREAMS = ("acc", "gyr", "mag", "own", "phone", "error")


def plot_columns(piece: PlotChunk) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """A PlotChunk as the plots store it: per stream (t (n,) float64 s, values (n, c) float32);
    acc and mag: x, y, z, norm, rejected (0/1); gyr: x, y, z, norm; own, phone: yaw, pitch, roll
    [deg]; error: total, heading, inclination [deg]."""
    out = {}
    for name, t, values, rejected in (("acc", piece.t_acc, piece.acc, piece.acc_rejected),
                                      ("gyr", piece.t_gyr, piece.gyr, None),
                                      ("mag", piece.t_mag, piece.mag, piece.mag_rejected)):
        values = np.asarray(values, float).reshape(len(t), 3)
        columns = [values, np.linalg.norm(values, axis=1, keepdims=True)]
        if rejected is not None:
            flags = np.asarray(rejected, float).reshape(-1, 1)
            columns.append(flags if len(flags) == len(t) else np.zeros((len(t), 1)))
        out[name] = (np.asarray(t, np.float64), np.hstack(columns).astype(np.float32))
    for name, t, values in (("own", piece.t_est, piece.own_euler_deg),
                            ("phone", piece.t_ori, piece.phone_euler_deg),
                            ("error", piece.t_err, piece.error_deg)):
        out[name] = (np.asarray(t, np.float64),
                     np.asarray(values, float).reshape(len(t), 3).astype(np.float32))
    return out


class _Growing:
    """Rows appended to arrays that double when full: no list of pieces to join at the end
    (an hour is 3,600 pieces per stream; the doubled arrays' unused tail is never touched, so
    it costs address space, not memory)."""

    def __init__(self, width: int) -> None:
        self.t = np.empty(1 << 14)
        self.values = np.empty((1 << 14, width), np.float32)
        self.size = 0

    def add(self, t: np.ndarray, values: np.ndarray) -> None:
        end = self.size + len(t)
        if end > len(self.t):
            capacity = max(end, 2 * len(self.t))
            grown_t = np.empty(capacity)
            grown_values = np.empty((capacity, self.values.shape[1]), np.float32)
            grown_t[:self.size] = self.t[:self.size]
            grown_values[:self.size] = self.values[:self.size]
            self.t, self.values = grown_t, grown_values
        self.t[self.size:end] = t
        self.values[self.size:end] = values
        self.size = end


STREAM_WIDTHS = {"acc": 5, "gyr": 4, "mag": 5, "own": 3, "phone": 3, "error": 3}


@dataclass
class SessionPlot:
    """The whole session's plot samples (see :func:`plot_columns`), in seconds since its start.
    ``streams`` is filled when complete; ``valid`` is False when the replay holds several
    sessions whose times start again (then the plots keep their rolling buffers)."""

    streams: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    valid: bool = True
    _growing: dict[str, _Growing] = field(
        default_factory=lambda: {s: _Growing(w) for s, w in STREAM_WIDTHS.items()})

    def add(self, piece: PlotChunk) -> None:
        for name, (t, values) in plot_columns(piece).items():
            if not len(t):
                continue
            growing = self._growing[name]
            if (growing.size and t[0] < growing.t[growing.size - 1] - 1e-9) \
                    or np.any(np.diff(t) < 0):
                self.valid = False
            growing.add(t, values)

    def finish(self) -> None:
        for name, growing in self._growing.items():
            self.streams[name] = (growing.t[:growing.size], growing.values[:growing.size])
        self._growing = {}

    @property
    def end_s(self) -> float:
        ends = [float(t[-1]) for t, _ in self.streams.values() if len(t)]
        return max(ends) if ends else 0.0

    def nbytes(self) -> int:
        return sum(t.nbytes + v.nbytes for t, v in self.streams.values())


def checkpoint_lines(pace: np.ndarray, interval_s: float = CHECKPOINT_INTERVAL_S) -> np.ndarray:
    """The lines at which checkpoints are taken: 0, then the first line due at or after each
    whole interval, then the end."""
    duration = float(pace[-1]) if len(pace) else 0.0
    marks = np.arange(interval_s, duration + interval_s, interval_s)
    lines = np.searchsorted(pace, marks, side="left")
    return np.unique(np.concatenate(([0], lines, [len(pace)]))).astype(np.int64)


class SessionIndex:
    """Build the index of `source` (a LineReplaySource) for `setup` in a background thread.

    options: the engine's pipeline options (limits, orderer_options). Read :attr:`store`
    (checkpoints so far), :attr:`plot`, :attr:`complete`, :attr:`progress` (0..1),
    :attr:`error` (one line), :attr:`elapsed_s`."""

    def __init__(self, source: Any, setup: Setup, options: dict[str, Any] | None = None,
                 interval_s: float = CHECKPOINT_INTERVAL_S) -> None:
        self.source = source
        self.setup = setup
        self.options = dict(options or {})
        self.interval_s = interval_s
        self.store = CheckpointStore()
        self.plot = SessionPlot()
        self.complete = False
        self.error: str | None = None
        self.progress = 0.0
        self.elapsed_s = 0.0
        self.end_t_ms: int | None = None
        self._cancel = threading.Event()
        self._thread: threading.Thread | None = None
        self._started = time.perf_counter()

    def start(self) -> SessionIndex:
        self._thread = threading.Thread(target=self._run, name="session-index", daemon=True)
        self._thread.start()
        return self

    def cancel(self) -> None:
        self._cancel.set()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def wait(self, timeout: float | None = None) -> bool:
        if self._thread is not None:
            self._thread.join(timeout)
        return self.complete

    def _run(self) -> None:
        try:
            self.build()
        except Exception as error:   # noqa: BLE001 (reported; seeks fall back to replaying)
            self.error = f"{type(error).__name__}: {error}"
        self.elapsed_s = time.perf_counter() - self._started

    def build(self) -> None:
        """Run the whole replay through a pipeline of the set-up (in this thread)."""
        self._started = time.perf_counter()
        setup = self.setup
        runner = EstimatorRunner(setup.estimator, setup.settings, comparisons=False,
                                 collect_plot=True)
        pipeline = Pipeline(runner, on_cut=lambda rows, piece: self.plot.add(piece),
                            **self.options)
        pipeline.begin(pipeline.initial_checkpoint(setup), setup.timeline)
        lines = checkpoint_lines(self.source.pace, self.interval_s)
        total = max(int(lines[-1]), 1)
        self.store.add(pipeline.checkpoint(0))
        for first, last in zip(lines[:-1].tolist(), lines[1:].tolist()):
            if self._cancel.is_set():
                return
            pipeline.feed_bytes(self.source.lines_between(first, last))
            self.plot.add(pipeline.take_output()[1])
            if last < total:
                self.store.add(pipeline.checkpoint(last))
            self.progress = last / total
        pipeline.end_of_stream(partial_line_damaged=False)
        self.plot.add(pipeline.take_output()[1])
        self.end_t_ms = runner.latest_t_ms
        self.plot.finish()
        self.elapsed_s = time.perf_counter() - self._started
        self.complete = True

    def checkpoint_before(self, line: int) -> Checkpoint | None:
        return self.store.before(line)
