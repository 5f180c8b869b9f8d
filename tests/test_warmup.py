"""The engine's warm-up: a first start compiles the stream's kernels in a second process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from app.engine import warmup

ROOT = Path(__file__).resolve().parents[1]


def test_the_stream_helper_loads_this_copy_of_the_app_and_ends_well():
    helper = warmup._start_stream_helper()
    assert helper is not None
    assert helper.wait(120) == 0


def test_an_empty_kernel_cache_is_seen_as_a_first_start(tmp_path):
    probe = "from app.engine.warmup import _cache_is_empty; print(_cache_is_empty())"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), PYTHONPATH=str(ROOT))
    empty = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True,
                           text=True, timeout=120, cwd=tmp_path)
    assert empty.stdout.split()[-1] == "True", empty.stderr
    warmup.warm_up()        # this process's cache: filled by the warm-up
    assert warmup._cache_is_empty() is False
