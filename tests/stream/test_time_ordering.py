"""TimeOrderer: per-tag clocks aligned, cross-tag reordering, drops counted, restarts."""

from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.stream.ordering import TimeOrderer
from app.stream.ordering_reference import ReferenceTimeOrderer
from app.stream.protocol import LineParser, Sample


def _s(t: int, tag: str) -> Sample:
    width = 4 if tag == "ORI" else 3
    return Sample(t, tag, (float(t),) + (0.0,) * (width - 1))


def _batched_stream(n: int, batch: int, offsets: dict[str, int] | None = None) -> list[Sample]:
    """Phone-like order: each tag written in batches of `batch` samples, 10 ms apart."""
    offsets = offsets or {}
    out = []
    for start in range(0, n, batch):
        for tag in ("ACC", "GYR", "MAG", "ORI"):
            out += [_s(1000 + 10 * k + offsets.get(tag, 0), tag)
                    for k in range(start, min(n, start + batch))]
    return out


def _run(orderer: TimeOrderer, samples: list[Sample]) -> list[Sample]:
    return orderer.push_many(samples) + orderer.flush()


def test_batches_are_put_in_time_order_with_tag_priority():
    orderer = TimeOrderer()
    out = _run(orderer, _batched_stream(300, 5))
    assert len(out) == 1200 and orderer.stats.out_of_order == 0
    keys = [(s.t_ms, ("GYR", "ACC", "MAG", "ORI").index(s.tag)) for s in out]
    assert keys == sorted(keys)


def test_constant_clock_offset_is_aligned_and_reported():
    orderer = TimeOrderer()
    out = _run(orderer, _batched_stream(200, 4, {"ACC": 131_072_000}))
    assert orderer.stats.out_of_order == 0 and len(out) == 800
    assert orderer.stats.clock_quirks == ["GYR clock -131072000 ms vs ACC (aligned)",
                                          "MAG clock -131072000 ms vs ACC (aligned)",
                                          "ORI clock -131072000 ms vs ACC (aligned)"]
    by_tag = {tag: [s.t_ms for s in out if s.tag == tag] for tag in ("ACC", "GYR")}
    assert by_tag["ACC"] == by_tag["GYR"]          # the same instants after alignment


def test_other_tags_bypass_untouched():
    orderer = TimeOrderer()
    wifi = Sample(1_585_038_883_072, "RSSWIFI", (), ("a", "b", "1", "2"))
    assert orderer.push(wifi) == [wifi]
    assert orderer.push(_s(1000, "ACC")) == []      # held: start of a segment


def test_backward_block_is_dropped_and_counted_deterministically():
    stream = [_s(1000 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
    jumped = [_s(2000 + 10 * k, tag) for k in range(3) for tag in ("GYR", "ACC")]
    late_block = [_s(1500 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
    tail = [_s(2030 + 10 * k, tag) for k in range(20) for tag in ("GYR", "ACC")]
    orderer = TimeOrderer()
    out = _run(orderer, stream + jumped + late_block + tail)
    assert orderer.stats.out_of_order == 100
    assert len(out) == 100 + 6 + 40
    times = [s.t_ms for s in out]
    assert times == sorted(times)


def test_lagging_tag_does_not_stall_release_and_its_old_samples_drop():
    orderer = TimeOrderer(window_ms=100)
    released = []
    for k in range(100):
        released += orderer.push(_s(1000 + 10 * k, "GYR"))
        released += orderer.push(_s(1000 + 10 * k, "ACC"))
        if k < 30:
            released += orderer.push(_s(1000 + 10 * k, "MAG"))   # MAG stops at 1290
    assert released and released[-1].t_ms >= 1980 - 10       # not stalled by MAG
    assert orderer.push(_s(1300, "MAG")) == [] and orderer.stats.out_of_order == 1


def test_forward_gap_restarts_time_base_and_keeps_times():
    orderer = TimeOrderer(gap_ms=2000)
    first = [_s(1000 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
    second = [_s(60_000 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
    out = _run(orderer, first + second)
    assert len(out) == 200 and orderer.stats.restarts == 1
    assert orderer.stats.restart_times_ms == [60_000]
    assert [s.t_ms for s in out] == sorted(s.t_ms for s in out)


def test_backward_clock_after_restart_is_a_new_session_on_its_own_times():
    """Another connection (or an earlier stranger's fake clock) never shifts the next stream's
    time axis: a segment starting before the last released time starts a new session."""
    for cls in (ReferenceTimeOrderer, TimeOrderer):
        orderer = cls()
        first = [_s(10**18 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
        out = orderer.push_many(first)
        out += orderer.restart()
        second = [_s(1000 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
        out += _run(orderer, second)
        assert len(out) == 200 and orderer.stats.out_of_order == 0
        assert [s.t_ms for s in out[100:]] == [s.t_ms for s in sorted(second, key=_key)]
        assert orderer.stats.sessions == 1 and orderer.stats.session_starts == [100]
    arrays = TimeOrderer()
    arrays.push_arrays(*_arrays(first))
    arrays.restart_arrays()
    released = arrays.push_arrays(*_arrays(second))
    released_all = arrays.flush_arrays()
    assert released.session_starts.tolist() == [0] and len(released) + len(released_all) == 100


def test_a_continuing_clock_keeps_the_session_and_a_loop_shifts_after_last_release():
    orderer = TimeOrderer(restart_gap_ms=1500)
    first = [_s(500_000 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
    out = orderer.push_many(first)
    out += orderer.restart(continue_time=True)           # a replay that loops
    second = [_s(1000 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
    out += _run(orderer, second)
    assert len(out) == 200 and orderer.stats.out_of_order == 0
    assert out[100].t_ms == 500_490 + 1500             # dt > 1 s: the filter restarts its dt
    assert [s.t_ms for s in out] == sorted(s.t_ms for s in out)
    assert orderer.stats.sessions == 0
    later = TimeOrderer()
    later.push_many(first)
    later.restart()                                       # the phone reconnecting later
    out = later.push_many([_s(600_000 + 10 * k, "GYR") for k in range(50)]) + later.flush()
    assert later.stats.sessions == 0 and out[0].t_ms == 600_000


def _key(sample: Sample):
    return (sample.t_ms, ("GYR", "ACC", "MAG", "ORI").index(sample.tag))


def _arrays(samples: list[Sample]):
    from app.stream.fastparse import samples_to_arrays
    arrays = samples_to_arrays(samples)
    return arrays.t_ms, arrays.tag, arrays.values


def test_buffer_is_bounded():
    orderer = TimeOrderer(max_pending=50)
    # GYR runs 40 ms behind ACC forever: within the window, so its release holds ACC back.
    for k in range(1000):
        orderer.push(_s(1000 + 10 * k, "ACC"))
        orderer.push(_s(960 + 10 * k, "GYR"))
        assert orderer.pending <= 51


def test_real_logs_ordered_and_counted(realphone_dir):
    # The standstill log's 0.9 s block is written 0.92 s after its time: beyond the largest
    # window (0.5 s), so its 420 samples are dropped as before the window adapted (187 ACC,
    # 187 GYR, 46 MAG). The lags the real logs show are at most ~20 ms (MAG written in pairs),
    # so their window stays 100 ms and no other count changes. (A 0.9 s gap in the data is not
    # a lag: lags are learned from how far behind the newest time a sample arrives.)
    expected_out_of_order = {"sensorLog_20221024T182616_standstill.txt": 420}
    for path in sorted(realphone_dir.glob("*.txt")):
        parser = LineParser()
        orderer = TimeOrderer()
        out = [s for s in _run(orderer, parser.feed(path.read_bytes()) + parser.finish())
               if s.tag in ("GYR", "ACC", "MAG", "ORI")]
        assert orderer.stats.out_of_order == expected_out_of_order.get(path.name, 0), path.name
        times = [s.t_ms for s in out]
        assert times == sorted(times)
        assert orderer.stats.sessions == 0 and max(orderer.stats.lags_ms.values(), default=0) < 50


def _arriving(tags: dict[str, int], seconds: float = 6.0, clock: dict[str, int] | None = None,
              rate_ms: int = 10) -> list[Sample]:
    """GYR/ACC/MAG/ORI every rate_ms from t=1000; each tag's lines written `tags[tag]` ms after
    their time (the others at once); `clock[tag]` added to a tag's time stamps (another clock,
    written at the true time)."""
    clock = clock or {}
    events = []
    for k in range(int(seconds * 1000 / rate_ms)):
        t = 1000 + rate_ms * k
        for order, tag in enumerate(("GYR", "ACC", "MAG", "ORI")):
            events.append((t + tags.get(tag, 0), order, _s(t + clock.get(tag, 0), tag)))
    return [sample for *_, sample in sorted(events, key=lambda e: (e[0], e[1]))]


@pytest.mark.parametrize("cls", [ReferenceTimeOrderer, TimeOrderer])
@pytest.mark.parametrize("lag", [73, 80, 95, 150, 240])
def test_a_tag_arriving_late_is_waited_for_not_dropped(cls, lag):
    """Was: a tag arriving >= 95 ms behind the others was dropped entirely. Its lag is learned
    and the window grows to hold it (bounded by 0.5 s); its own time stamps are kept."""
    stream = _arriving({"MAG": lag})
    orderer = cls()
    out = _run(orderer, stream)
    assert orderer.stats.out_of_order == 0 and len(out) == len(stream)
    assert [s.t_ms for s in out] == sorted(s.t_ms for s in out)
    learned = orderer.stats.lags_ms["MAG"]
    assert lag - 10 <= learned <= lag + 10              # in steps of the 10 ms sample period
    assert orderer.stats.window_ms == max(100, min(500, learned + learned // 4 + 10))
    assert orderer.stats.offsets_ms.get("MAG", 0) == 0 and not orderer.stats.clock_quirks


@pytest.mark.parametrize("cls", [ReferenceTimeOrderer, TimeOrderer])
@pytest.mark.parametrize("offset", [150, -150, 300, -400, 2000, -2000, 9000, -9000,
                                    131_072_000])
def test_a_constant_clock_offset_of_any_size_loses_nothing(cls, offset):
    """Was: offsets from 150 ms to 9 s (under the 10 s alignment threshold) dropped every
    other tag. Beyond 250 ms the tag's clock is aligned exactly (a whole number of seconds is
    snapped to); up to 250 ms it is indistinguishable from a tag arriving late: waited for."""
    stream = _arriving({}, clock={"GYR": offset})
    orderer = cls()
    out = _run(orderer, stream)
    assert orderer.stats.out_of_order == 0 and len(out) == len(stream)
    assert [s.t_ms for s in out] == sorted(s.t_ms for s in out)
    by_tag = {tag: [s.t_ms for s in out if s.tag == tag] for tag in ("GYR", "ACC")}
    if abs(offset) > 250:
        assert orderer.stats.clock_quirks
        assert by_tag["GYR"] == by_tag["ACC"]          # the same instants after alignment
    else:
        assert orderer.stats.window_ms >= abs(offset)


@pytest.mark.parametrize("cls", [ReferenceTimeOrderer, TimeOrderer])
def test_a_block_arriving_after_the_window_is_dropped_never_a_new_segment(cls):
    """Was: a 0.9 s block arriving 2.9 s late (beyond gap_ms) was played as a new segment
    (OWN vs PHONE 179 deg for 1.5 s). Now it is dropped and counted."""
    stream = _arriving({}, seconds=10.0)
    block = [s for s in stream if 3000 <= s.t_ms < 3900]
    rest = [s for s in stream if not 3000 <= s.t_ms < 3900]
    at = next(i for i, s in enumerate(rest) if s.t_ms >= 6800)      # 2.9 s after its end
    orderer = cls()
    out = _run(orderer, rest[:at] + block + rest[at:])
    assert orderer.stats.out_of_order == len(block) == 360
    assert orderer.stats.restarts == 0 and orderer.stats.sessions == 0
    assert [s.t_ms for s in out] == sorted(s.t_ms for s in out)
    assert len(out) == len(rest)


def test_a_clock_that_really_goes_back_starts_a_new_session_after_gap_ms():
    """A reboot within the late horizon looks like a late block at first; once its samples go
    on for more than gap_ms of their own time, they are a new clock: a new session."""
    first = _arriving({}, seconds=8.0)
    again = [s._replace(t_ms=s.t_ms + 2000) for s in _arriving({}, seconds=5.0)]   # 3000..
    for cls in (ReferenceTimeOrderer, TimeOrderer):
        orderer = cls()
        out = _run(orderer, first + again)
        assert orderer.stats.sessions == 1 and orderer.stats.restarts == 1
        dropped = orderer.stats.out_of_order
        assert 0 < dropped <= 4 * 202                   # about gap_ms of the new clock
        assert len(out) + dropped == len(first) + len(again)


YEAR_MS = 365 * 24 * 3600 * 1000


def _with_outliers(kind: str) -> tuple[list[Sample], list[Sample]]:
    """A 4-tag stream with bad time stamps inserted in its middle (and those samples)."""
    stream = _arriving({"MAG": 40}, seconds=8.0)
    at = len(stream) // 2
    t = stream[at].t_ms
    bad = {"zero": [_s(0, "GYR")],
           "year": [_s(t + YEAR_MS, "ACC")],
           "year-burst": [_s(t + YEAR_MS + 10 * k, "ACC") for k in range(5)],
           "ahead": [_s(t + 5000, "MAG")],
           "behind": [_s(t - 30_000, "ORI")],
           "two-tags-apart": [_s(0, "GYR"), _s(t + YEAR_MS, "ACC")]}[kind]
    return stream[:at] + bad + stream[at:], bad


@pytest.mark.parametrize("cls", [ReferenceTimeOrderer, TimeOrderer])
@pytest.mark.parametrize("kind", ["zero", "year", "year-burst", "ahead", "behind",
                                  "two-tags-apart"])
def test_a_bad_time_stamp_is_dropped_never_a_clock_quirk_or_new_session(cls, kind):
    """Was: one sample at t = 0 (or a burst a year ahead) started two new sessions and was
    reported as clock quirks ("GYR clock -31536000000 ms vs ACC"): the tag's clock went on
    where it was, so the samples are dropped and counted, and nothing else changes."""
    stream, bad = _with_outliers(kind)
    clean = [s for s in stream if s not in bad]
    orderer = cls()
    out = _run(orderer, stream)
    assert out == _run(cls(), clean)
    assert orderer.stats.out_of_order == len(bad)
    assert orderer.stats.clock_quirks == [] and orderer.stats.sessions == 0
    assert orderer.stats.restarts == 0


@pytest.mark.parametrize("cls", [ReferenceTimeOrderer, TimeOrderer])
def test_a_bad_time_stamp_at_the_end_is_dropped(cls):
    stream = _arriving({}, seconds=3.0)
    orderer = cls()
    out = _run(orderer, stream + [_s(0, "GYR")])
    assert out == _run(cls(), stream) and orderer.stats.out_of_order == 1
    assert orderer.pending == 0 and orderer.stats.sessions == 0


@pytest.mark.parametrize("cls", [ReferenceTimeOrderer, TimeOrderer])
def test_one_tag_moving_to_another_clock_is_followed_after_gap_ms(cls):
    """A tag whose samples stay on a new clock for more than gap_ms (the others going on on
    the old one) really changed clock: a new segment aligns it, nothing is lost."""
    stream = [s if s.tag != "MAG" or s.t_ms < 4000 else s._replace(t_ms=s.t_ms + 7000)
              for s in _arriving({}, seconds=8.0)]
    orderer = cls()
    out = _run(orderer, stream)
    assert orderer.stats.restarts == 1 and orderer.stats.out_of_order == 0
    assert len(out) == len(stream)
    assert any("7000 ms" in quirk for quirk in orderer.stats.clock_quirks)


def test_a_checkpoint_taken_while_a_jump_is_held_continues_the_same():
    stream, _ = _with_outliers("year-burst")
    at = next(k for k, s in enumerate(stream) if s.t_ms > YEAR_MS) + 2     # inside the burst
    whole = TimeOrderer()
    expected = whole.push_arrays(*_arrays(stream))
    first = TimeOrderer()
    released = first.push_arrays(*_arrays(stream[:at]))
    assert first.pending > first.snapshot()["keys"].shape[0]           # the burst is held
    second = TimeOrderer()
    second.restore(first.snapshot())
    rest = second.push_arrays(*_arrays(stream[at:]))
    assert np.concatenate([released.t_ms, rest.t_ms]).tolist() == expected.t_ms.tolist()
    assert second.stats.out_of_order == whole.stats.out_of_order == 5


def test_filter_with_one_bad_time_stamp_gives_the_logs_estimates(realphone_dir, tmp_path,
                                                                  capsys):
    from app import cli
    log = realphone_dir / "tsrt14_lab2_rotation.txt"
    lines = log.read_text().splitlines(keepends=True)
    at = next(k for k in range(len(lines) // 2, len(lines)) if "\tGYR\t" in lines[k])
    bad = tmp_path / "bad.txt"
    bad.write_text("".join(lines[:at] + ["0\tGYR\t0.01\t0.02\t0.03\n"] + lines[at:]))
    assert cli.main(["filter", str(log), "-o", str(tmp_path / "good.csv")]) == 0
    capsys.readouterr()
    assert cli.main(["filter", str(bad), "-o", str(tmp_path / "bad.csv")]) == 0
    summary = capsys.readouterr().err.splitlines()[0]
    assert "1 out of order" in summary
    assert "quirk" not in summary and "session" not in summary and "restart" not in summary
    assert (tmp_path / "bad.csv").read_bytes() == (tmp_path / "good.csv").read_bytes()


@settings(max_examples=60, deadline=None)
@given(st.integers(min_value=1, max_value=30), st.integers(min_value=0, max_value=2**31))
def test_output_is_time_sorted_and_accounts_for_every_sample(batch, seed):
    rng = random.Random(seed)
    stream = _batched_stream(120, batch)
    # a little extra disorder: swap a few neighbours
    for _ in range(10):
        i = rng.randrange(len(stream) - 1)
        stream[i], stream[i + 1] = stream[i + 1], stream[i]
    orderer = TimeOrderer()
    out = _run(orderer, stream)
    assert len(out) + orderer.stats.out_of_order == len(stream)
    assert [s.t_ms for s in out] == sorted(s.t_ms for s in out)
    assert _run(TimeOrderer(), stream) == out


def _phone_like_stream(rng: random.Random, n: int) -> list[Sample]:
    """Per-tag increasing clocks with batching, jitter, drops back, pauses and other clocks;
    sometimes one tag written late (lags the window learns) or blocks written late."""
    tags = ("GYR", "ACC", "MAG", "ORI")
    clocks = {tag: 1000 + rng.randrange(0, 30) for tag in tags}
    if rng.random() < 0.3:
        clocks["ACC"] += 131_072_000
    if rng.random() < 0.2:
        clocks["MAG"] += rng.choice([-180, 120, 400, -3000, 9000])
    late_tag = rng.choice(tags) if rng.random() < 0.4 else None
    late_by = rng.randrange(20, 600)
    out: list[tuple[int, int, Sample]] = []
    arrival = 0
    while len(out) < n:
        tag = rng.choice(tags)
        for _ in range(rng.randrange(1, 8)):
            step = rng.choice([0, 2, 5, 10, 10, 10, 15])
            if rng.random() < 0.01:
                # reboot, late block, glitch, pause, a clock beyond the late horizon
                step = rng.choice([-3000, -50, 2500, 60_000, -20_000, 700_000])
            clocks[tag] += step
            arrival += 1
            delay = late_by // 10 if tag == late_tag else 0        # arrival in ~10 ms steps
            out.append((arrival + delay, len(out), _s(clocks[tag], tag)))
            if rng.random() < 0.01:
                # a bad time stamp or a short burst of them; the clock goes on where it was
                wild = rng.choice([-clocks[tag], 5000, -30_000, YEAR_MS])
                for k in range(rng.choice([1, 1, 3])):
                    out.append((arrival + delay, len(out), _s(clocks[tag] + wild + k, tag)))
    return [sample for *_, sample in sorted(out)]


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 10**6), n=st.integers(1, 600), cut=st.integers(1, 200),
       max_pending=st.sampled_from([20_000, 7]), restart_at=st.integers(-1, 600),
       continue_time=st.booleans(),
       params=st.sampled_from([{}, {"late_horizon_ms": 2500, "session_gap_ms": 50_000},
                               {"max_window_ms": 200, "align_threshold_ms": 100}]))
def test_compiled_orderer_equals_the_reference(seed, n, cut, max_pending, restart_at,
                                               continue_time, params):
    stream = _phone_like_stream(random.Random(seed), n)
    results = []
    for cls in (ReferenceTimeOrderer, TimeOrderer):
        orderer = cls(max_pending=max_pending, **params)
        out = []
        for start in range(0, len(stream), cut):
            if start <= restart_at < start + cut:
                out += orderer.restart(continue_time)
            out += orderer.push_many(stream[start:start + cut])
        out += orderer.flush()
        results.append((out, orderer.stats, orderer.pending, orderer.last_released_ms))
    assert results[0] == results[1]


def test_array_face_equals_sample_face():
    from app.stream.fastparse import samples_to_arrays
    stream = _phone_like_stream(random.Random(5), 2000)
    samples = TimeOrderer().push_many(stream)
    arrays = samples_to_arrays(stream)
    orderer = TimeOrderer()
    released = orderer.push_arrays(arrays.t_ms, arrays.tag, arrays.values)
    assert released.t_ms.tolist() == [s.t_ms for s in samples]
    assert released.tag.tolist() == [("GYR", "ACC", "MAG", "ORI").index(s.tag) for s in samples]
    assert released.values[:, 0].tolist() == [s.values[0] for s in samples]
    # every sample that entered the buffer before the oldest one still held is out
    oldest = orderer.oldest_pending_sequence
    assert orderer.pending > 0 and set(range(1, oldest)) <= set(released.seq.tolist())
    assert oldest not in set(released.seq.tolist())


def _steps(functions) -> list[str]:
    return [name.lstrip("_") for name, value in functions
            if callable(value) and not name.startswith("__")]


def test_the_compiled_orderer_and_its_specification_are_twins_with_the_same_steps():
    """Every private method of the reference (a step of the algorithm) is a compiled kernel of
    app.stream.ordering without the underscore, or, where the compiled twin runs that step in
    Python, a TimeOrderer method of the same name; in the same order on both sides."""
    import app.stream.ordering as ordering
    from numba.core.dispatcher import Dispatcher

    reference = _steps((name, value) for name, value in vars(ReferenceTimeOrderer).items()
                       if name.startswith("_"))
    kernels = [name for name, value in vars(ordering).items()
               if isinstance(value, Dispatcher) and value.py_func.__module__ == ordering.__name__
               and not name.startswith("_") and name != "effective_window"]
    in_python = [name for name in _steps((name, value) for name, value
                                         in vars(TimeOrderer).items() if name.startswith("_"))
                 if name in reference]
    assert [name for name in reference if name not in in_python] == kernels
    assert in_python == [name for name in reference if name in in_python]
    assert set(in_python) == {"update_stats", "start_segment_clock", "learn_offset"}
    public = {name for name in vars(ReferenceTimeOrderer) if not name.startswith("_")}
    assert public <= set(vars(TimeOrderer))
