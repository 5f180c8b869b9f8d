"""TimeOrderer: per-tag clocks aligned, cross-tag reordering, drops counted, restarts."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from app.stream.ordering import TimeOrderer
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


def test_backward_clock_after_restart_is_shifted_after_last_release():
    orderer = TimeOrderer(restart_gap_ms=1500)
    first = [_s(500_000 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
    out = orderer.push_many(first)
    out += orderer.restart()
    second = [_s(1000 + 10 * k, tag) for k in range(50) for tag in ("GYR", "ACC")]
    out += _run(orderer, second)
    assert len(out) == 200 and orderer.stats.out_of_order == 0
    assert out[100].t_ms == 500_490 + 1500             # dt > 1 s: the filter restarts its dt
    assert [s.t_ms for s in out] == sorted(s.t_ms for s in out)


def test_buffer_is_bounded():
    orderer = TimeOrderer(max_pending=50)
    # GYR runs 40 ms behind ACC forever: within the window, so its release holds ACC back.
    for k in range(1000):
        orderer.push(_s(1000 + 10 * k, "ACC"))
        orderer.push(_s(960 + 10 * k, "GYR"))
        assert orderer.pending <= 51


def test_real_logs_ordered_and_counted(realphone_dir):
    expected_out_of_order = {"sensorLog_20221024T182616_standstill.txt": 420}
    for path in sorted(realphone_dir.glob("*.txt")):
        parser = LineParser()
        orderer = TimeOrderer()
        out = [s for s in _run(orderer, parser.feed(path.read_bytes()) + parser.finish())
               if s.tag in ("GYR", "ACC", "MAG", "ORI")]
        assert orderer.stats.out_of_order == expected_out_of_order.get(path.name, 0), path.name
        times = [s.t_ms for s in out]
        assert times == sorted(times)


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
    """Per-tag increasing clocks with batching, jitter, drops back, pauses and other clocks."""
    tags = ("GYR", "ACC", "MAG", "ORI")
    clocks = {tag: 1000 + rng.randrange(0, 30) for tag in tags}
    if rng.random() < 0.3:
        clocks["ACC"] += 131_072_000
    out = []
    while len(out) < n:
        tag = rng.choice(tags)
        for _ in range(rng.randrange(1, 8)):
            step = rng.choice([0, 2, 5, 10, 10, 10, 15])
            if rng.random() < 0.01:
                step = rng.choice([-3000, -50, 2500, 60_000])      # reboot, glitch, pause
            clocks[tag] += step
            out.append(_s(clocks[tag], tag))
    return out


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10**6), n=st.integers(1, 600), cut=st.integers(1, 200),
       max_pending=st.sampled_from([20_000, 7]), restart_at=st.integers(-1, 600))
def test_compiled_orderer_equals_the_reference(seed, n, cut, max_pending, restart_at):
    from app.stream.ordering import ReferenceTimeOrderer
    stream = _phone_like_stream(random.Random(seed), n)
    results = []
    for cls in (ReferenceTimeOrderer, TimeOrderer):
        orderer = cls(max_pending=max_pending)
        out = []
        for start in range(0, len(stream), cut):
            if start <= restart_at < start + cut:
                out += orderer.restart()
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
