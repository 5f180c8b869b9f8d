"""The committed demo session is exactly what `write_demo_session` produces, is valid phone text,
and gives every status light something to show."""

from __future__ import annotations

import gzip

import numpy as np

from app.stream.demo import DEMO_SESSION_PATH, demo_session_lines, write_demo_session, write_session
from app.stream.protocol import TAG_CODES, parse_line
from ekf.simulate import simulate


def _text(path) -> str:
    return gzip.decompress(path.read_bytes()).decode("ascii")


def test_committed_demo_equals_the_generator_output(tmp_path):
    assert DEMO_SESSION_PATH.is_file(), \
        "app/resources/demo_session.txt.gz missing: run python -m app.stream.demo"
    fresh = write_demo_session(tmp_path / "demo.txt.gz")
    committed, generated = _text(DEMO_SESSION_PATH), _text(fresh)
    if committed != generated:
        a, b = committed.splitlines(), generated.splitlines()
        first = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
        raise AssertionError(
            f"demo session drifted from write_demo_session at line {first + 1} "
            f"({len(a)} vs {len(b)} lines): regenerate with `python -m app.stream.demo`")
    # Reproducible bytes too (no time stamp in the gzip header), and small enough to ship.
    assert write_demo_session(tmp_path / "again.txt.gz").read_bytes() == fresh.read_bytes()
    assert DEMO_SESSION_PATH.stat().st_size < 1_500_000


def test_demo_is_time_ordered_phone_text_with_something_for_every_light():
    lines = demo_session_lines()
    samples = [parse_line(line) for line in lines]
    assert {s.tag for s in samples} == {"GYR", "ACC", "MAG", "ORI"}
    keys = [(s.t_ms, TAG_CODES[s.tag]) for s in samples]
    assert keys == sorted(keys)
    assert samples[-1].t_ms - samples[0].t_ms > 89_000
    by_tag = {tag: np.array([s.values for s in samples if s.tag == tag])
              for tag in ("GYR", "ACC", "MAG", "ORI")}
    assert abs(len(by_tag["MAG"]) - 4500) <= 1 and abs(len(by_tag["ACC"]) - 9000) <= 1
    assert np.all(by_tag["ORI"][:, 0] >= 0)
    acc_norm = np.linalg.norm(by_tag["ACC"], axis=1)
    mag_norm = np.linalg.norm(by_tag["MAG"], axis=1)
    gyr_norm = np.linalg.norm(by_tag["GYR"], axis=1)
    assert np.mean(gyr_norm < 0.02) > 0.3              # standstill: long rests
    assert np.sum(np.abs(acc_norm - 9.81) > 3.0) > 20  # acc disturbed: linear-acceleration bursts
    assert np.sum(mag_norm - np.median(mag_norm) > 10.0) > 100  # mag disturbed: a magnet episode
    assert gyr_norm.max() > 5.0                        # and fast turns


def test_write_session_plain_text_parses_back_to_the_simulated_samples(tmp_path):
    session = simulate(duration_s=5.0, seed=9, rates_hz={"gyr": 200, "mag": 100})
    path = write_session(session, tmp_path / "sim.txt")
    text = path.read_text()
    assert text.endswith("\n") and "\r" not in text
    samples = [parse_line(line) for line in text.splitlines()]
    assert len(samples) == sum(len(session.series(tag)) for tag in ("GYR", "ACC", "MAG", "ORI"))
    for tag in ("GYR", "ACC", "MAG", "ORI"):
        mine = [s for s in samples if s.tag == tag]
        series = session.series(tag)
        np.testing.assert_array_equal([s.t_ms for s in mine], series.t_ms)
        # Float32 precision, as the phone sends: within one float32 ulp (2^-23 relative).
        np.testing.assert_allclose([s.values for s in mine], series.values, rtol=1.2e-7, atol=1e-9)
