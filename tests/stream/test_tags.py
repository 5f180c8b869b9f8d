"""The tag table (app.stream.protocol.TAGS) drives the parsers, the orderer's layout and the
numba cache."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from app.stream import ordering
from app.stream.fastparse import FastLineParser
from app.stream.protocol import (DAMAGE_REASONS, FILTER, SENSOR_CODES, TAGS, LineParser,
                                 ParseError, Tag, parse_line)
from ekf.estimator import SENSORS
from ekf.fast.jit import check_cache


def _line(tag: Tag, values: list[float]) -> str:
    return "\t".join(["1000", tag.name, *(f"{v!r}" for v in values)])


def _good(tag: Tag) -> list[float]:
    if tag.bound == "ori":
        return [0.5, 0.5, 0.5, 0.5]
    return [0.25 * (k + 1) for k in range(tag.width)]


@pytest.mark.parametrize("tag", [t for t in TAGS if not t.text], ids=lambda t: t.name)
def test_every_numeric_tag_parses_its_width_and_refuses_one_more(tag):
    sample = parse_line(_line(tag, _good(tag)))
    assert sample.tag == tag.name and len(sample.values) == tag.width
    with pytest.raises(ParseError) as error:
        parse_line(_line(tag, _good(tag) + [1.0]))
    assert error.value.reason == "value count"


@pytest.mark.parametrize("tag", [t for t in TAGS if t.bound], ids=lambda t: t.name)
def test_every_bounded_tag_is_damaged_beyond_its_bound_in_both_parsers(tag):
    values = [2.0] * tag.width if tag.bound == "ori" else [1e5] * tag.width
    line = _line(tag, values)
    with pytest.raises(ParseError) as error:
        parse_line(line)
    assert error.value.reason == f"{tag.name} out of range" in DAMAGE_REASONS
    slow, fast = LineParser(), FastLineParser()
    slow.feed((line + "\n").encode())
    arrays = fast.feed_arrays((line + "\n").encode())
    assert len(arrays) == 0
    assert fast.stats.damaged_reasons == slow.stats.damaged_reasons == {error.value.reason: 1}


def test_the_filter_tags_feed_ekf_s_sensors_in_its_order():
    assert tuple(FILTER[code].name.lower() for code in SENSOR_CODES) == SENSORS


def test_the_orderer_state_has_one_slot_per_scalar_and_one_block_per_filter_tag():
    S = ordering.S
    n = len(FILTER)
    assert S.size == len(ordering.SCALARS) + n * len(ordering.PER_TAG)
    per_tag = sorted(getattr(S, name) for name, _ in ordering.PER_TAG)
    assert np.all(np.diff(per_tag) == n) and per_tag[0] == len(ordering.SCALARS)


def test_a_changed_table_flushes_the_cached_kernels_of_a_module():
    flushed = []

    class Cache:
        def flush(self):
            flushed.append(True)

    key = njit(lambda: 1)
    kernel = njit(lambda x: x + 1)
    kernel(1)
    kernel._cache = Cache()
    kernel.py_func.__module__ = key.py_func.__module__ = "fake_module"
    module_globals = {"__name__": "fake_module", "key": key, "kernel": kernel, "math": math}
    check_cache(key, module_globals, 1)
    assert flushed == []                      # the key matches: nothing flushed
    check_cache(key, module_globals, 2)
    assert flushed == [True]
