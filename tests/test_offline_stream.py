"""The offline commands read their log as a stream: estimates, scores and smoothed estimates do
not depend on the chunks the log is read in, and are those of the whole log in one piece."""

from __future__ import annotations

import gzip
from dataclasses import astuple

import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

import ekf
from ekf.simulate import simulate
from app.cli import main
from app.engine.offline.filtering import (evaluate_log, filter_log, filter_rows, reference_errors,
                                          run_offline, scan_log, session_row_starts)
from app.engine.processing.runner import Rows
from app.stream.demo import write_session
from app.stream.logfile import LogFile, read_log

HEALTH = [HealthCheck.function_scoped_fixture]


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """One session (damaged lines in it) and two (its clock restarts), and a truth file."""
    folder = tmp_path_factory.mktemp("stream")
    one, two, first, truth = (folder / n for n in ("one.txt", "two.txt", "first.txt",
                                                  "one.truth.txt"))
    write_session(simulate(duration_s=12.0, seed=4), one)
    lines = one.read_bytes().splitlines(keepends=True)
    lines[300:300] = [b"junk\n", b"\x00\x01\n", b"123\tACC\t1\n"]
    one.write_bytes(b"".join(lines))
    write_session(simulate(duration_s=6.0, seed=1, t0_ms=5_000_000), first)
    two.write_bytes(first.read_bytes() + one.read_bytes())
    truth.write_bytes(b"".join(line for line in lines if b"\tORI\t" in line))
    return {"one": one, "two": two, "truth": truth}


def _same_rows(a: Rows, b: Rows) -> None:
    for name in ("t_ms", "quat", "acc_rejected", "mag_rejected", "at_rest"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


@given(chunk_bytes=st.integers(4096, 200_000), which=st.sampled_from(["one", "two"]))
@hsettings(max_examples=8, deadline=None, suppress_health_check=HEALTH)
def test_the_estimates_do_not_depend_on_the_chunks_the_log_is_read_in(logs, chunk_bytes,
                                                                        which):
    whole = read_log(logs[which])
    expected = filter_log(whole)
    streamed = Rows.concatenate(list(filter_rows(LogFile(logs[which],
                                                         chunk_bytes=chunk_bytes))))
    _same_rows(streamed, expected)
    one_piece = run_offline(_one_chunk(whole))
    _same_rows(streamed, one_piece.select(one_piece.has_sample))


@given(chunk_bytes=st.integers(4096, 200_000), which=st.sampled_from(["one", "two"]),
       skip_s=st.sampled_from([0.0, 1.5]), intervals=st.sampled_from([None, "some"]),
       with_truth=st.booleans())
@hsettings(max_examples=8, deadline=None, suppress_health_check=HEALTH)
def test_evaluate_scores_as_it_goes_what_the_whole_run_scores(logs, chunk_bytes, which, skip_s,
                                                              intervals, with_truth):
    """The error angles of each scored ORI sample are kept, never the run: the figures are
    reference_errors' over the whole run (the Tune panel's), bit for bit."""
    whole = read_log(logs[which])
    if intervals == "some":                       # (in the session of one.txt)
        start = int(read_log(logs["one"]).t_ms[0])
        intervals = [[start + 2000, start + 5000], [start + 7000, start + 30_000]]
    truth = read_log(logs["truth"]) if with_truth else None
    scan = scan_log(whole, ori=True)
    reference = None
    if truth is not None:
        found = scan_log(truth, ori=True)
        reference = (found.ori_t_ms.astype(np.float64), found.ori_quat)
    rows = run_offline(_one_chunk(whole))
    expected = reference_errors(rows, scan.ori_t_ms, intervals, skip_s,
                                session_row_starts(whole.t_ms, whole.session_starts),
                                reference).summary
    streamed = evaluate_log(LogFile(logs[which], chunk_bytes=chunk_bytes), intervals_ms=intervals,
                            skip_s=skip_s, truth=truth)
    assert astuple(streamed) == astuple(expected)
    assert streamed.samples > 100


@given(chunk_bytes=st.integers(4096, 200_000))
@hsettings(max_examples=6, deadline=None, suppress_health_check=HEALTH)
def test_the_smoothed_estimates_do_not_depend_on_the_chunks(logs, chunk_bytes):
    whole = read_log(logs["one"])
    t_ms, gyr, acc, mag = _sensor_rows_of(whole)
    expected = ekf.smooth_batch(t_ms / 1000.0, gyr, acc, mag, ekf.PRESETS["default"]).quat
    streamed = Rows.concatenate(list(filter_rows(LogFile(logs["one"], chunk_bytes=chunk_bytes),
                                                 smooth=True)))
    assert np.array_equal(streamed.t_ms, t_ms)
    assert np.array_equal(streamed.quat, expected)
    assert evaluate_log(LogFile(logs["one"], chunk_bytes=chunk_bytes), smooth=True) == \
        evaluate_log(whole, smooth=True)


def test_smoothing_refuses_a_log_whose_clock_restarts(logs):
    with pytest.raises(ValueError, match="one session"):
        filter_log(read_log(logs["two"]), smooth=True)


def test_filter_and_evaluate_on_the_command_line_read_a_gzip_log_as_a_stream(logs, tmp_path,
                                                                                capsys):
    packed = tmp_path / "one.txt.gz"
    packed.write_bytes(gzip.compress(logs["one"].read_bytes()))
    out = tmp_path / "est.csv"
    assert main(["filter", str(packed), "-o", str(out)]) == 0
    plain = tmp_path / "plain.csv"
    assert main(["filter", str(logs["one"]), "-o", str(plain)]) == 0
    assert out.read_bytes() == plain.read_bytes()
    capsys.readouterr()
    assert main(["filter", str(logs["one"])]) == 0          # stdout: the same CSV
    assert capsys.readouterr().out.encode() == plain.read_bytes()


def test_a_gzip_log_that_breaks_off_is_one_line_and_nothing_written(logs, tmp_path, capsys):
    data = gzip.compress(logs["one"].read_bytes())
    broken = tmp_path / "broken.txt.gz"
    broken.write_bytes(data[:len(data) // 2])
    out = tmp_path / "est.csv"
    for argv in (["filter", str(broken), "-o", str(out)], ["filter", str(broken)],
                 ["evaluate", str(broken)]):
        assert main(argv) == 2
        captured = capsys.readouterr()
        assert "damaged or incomplete gzip" in captured.err
        assert len(captured.err.strip().splitlines()) == 1 and "Traceback" not in captured.err
        assert not captured.out.startswith("t_ms")
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == ["broken.txt.gz"]


@given(size=st.integers(1, 5000), which=st.sampled_from(["one", "two"]),
       positions=st.lists(st.integers(0, 4000), min_size=4, max_size=4))
@hsettings(max_examples=8, deadline=None, suppress_health_check=HEALTH)
def test_a_configuration_over_time_runs_the_same_in_any_chunks(logs, size, which, positions):
    """Tune's re-run of a Setup (run_log with setup): the changes apply at their sample
    positions whatever the chunks, as one pipeline pass over each whole session gives."""
    from app.engine.processing.configuration import Change, Setup
    from app.engine.processing.pipeline import Pipeline
    from app.engine.processing.runner import EstimatorRunner
    log = read_log(logs[which])
    a, b, c, d = sorted(positions)
    setup = Setup(comparisons=False, timeline=(
        Change.of("gyr", False, a), Change.of("gyr", True, b),
        Change.of("estimator", "course", c), Change(d, "reset")))
    runner = EstimatorRunner(collect_plot=False)
    pipeline = Pipeline(runner)
    pipeline.begin(pipeline.initial_checkpoint(setup), setup.timeline)
    previous = 0
    for start in list(log.session_starts) + [len(log)]:
        pipeline.feed_samples(log.t_ms[previous:start], log.tag[previous:start],
                              log.values[previous:start])
        if start < len(log):
            runner.new_session()
        previous = start
    runner.finish()
    expected = runner.take_rows()
    _same_rows(run_offline(_chunked(log, size), setup=setup), expected)


def _chunked(log, size):
    """The log in chunks of `size` samples."""

    class Chunked:
        path = log.path

        @staticmethod
        def chunks():
            return log.chunks(size=size)

    return Chunked()


def _one_chunk(log):
    """The whole log as one chunk."""

    class Whole:
        path = log.path

        @staticmethod
        def chunks():
            return log.chunks(size=max(1, len(log)))

    return Whole()


def _sensor_rows_of(log):
    a = log.to_arrays()
    has = ~(np.isnan(a.gyr).all(1) & np.isnan(a.acc).all(1) & np.isnan(a.mag).all(1))
    return a.t_ms[has], a.gyr[has], a.acc[has], a.mag[has]
