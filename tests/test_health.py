"""The stream health the status bar shows: each tag's rate from its own times."""

from __future__ import annotations

import pytest

from app.engine.processing.health import HealthTracker
from app.stream.fastparse import FastLineParser


def _parsed(start_ms: int, count: int, step_ms: int = 10):
    text = "".join(f"{start_ms + step_ms * k}\tACC\t0.0\t0.0\t9.81\n" for k in range(count))
    return FastLineParser().feed_arrays(text.encode())


@pytest.mark.parametrize("jump_ms", [-1500, -300, 400])
def test_rates_after_a_seek_are_the_tags_rate_not_a_burst(jump_ms):
    health = HealthTracker()
    health.track(_parsed(10_000, 200))                 # 2 s at 100 Hz
    assert health.rates()["ACC"] == pytest.approx(100.0, rel=0.02)
    # a seek: the replay goes on from another time (back, or forward within the rate window)
    health.track(_parsed(12_000 + jump_ms, 30))
    assert health.rates()["ACC"] == pytest.approx(100.0, rel=0.05)


def test_a_slow_tag_keeps_its_rate_from_chunk_to_chunk():
    health = HealthTracker()
    health.track(_parsed(10_000, 2, step_ms=1000))        # 1 Hz
    for start in (12_000, 13_000, 14_000):
        health.track(_parsed(start, 1, step_ms=1000))
    assert health.rates()["ACC"] == pytest.approx(1.0)
