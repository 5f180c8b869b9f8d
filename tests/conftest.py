"""Test set-up shared by the whole suite.

* Without a display, Qt runs offscreen (widgets, plots and pytest-qt work; OpenGL does not).
  Tests marked `gl` need a real GL context: they are skipped offscreen and `make test` runs them
  under `xvfb-run`.
* `shared_dir` locates ../shared (real phone logs, BROAD trials) and skips with a clear reason
  when a fresh clone has no such folder beside it.
* Property tests draw the same examples on every run and machine (hypothesis' "deterministic"
  profile: derandomized, no example database), so a run is reproducible;
  `HYPOTHESIS_PROFILE=explore` draws new ones.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("explore")
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))

if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# Offscreen Qt pretends an 800x600 screen; the window is tested on a 1920x1080 one (a window
# is never larger than its screen), so give the platform that screen.
if os.environ.get("QT_QPA_PLATFORM") == "offscreen":
    os.environ["QT_QPA_PLATFORM"] = ("offscreen:configfile="
                                     + str(Path(__file__).with_name("offscreen_screen.json")))

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("ORIENTATION_LAB_SHARED", REPO.parent / "shared"))


def offscreen() -> bool:
    return os.environ.get("QT_QPA_PLATFORM", "").startswith("offscreen")


def pytest_collection_modifyitems(config, items):
    if offscreen():
        skip_gl = pytest.mark.skip(reason="needs OpenGL: offscreen platform has none (run under xvfb-run)")
        for item in items:
            if "gl" in item.keywords:
                item.add_marker(skip_gl)


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not (SHARED / "data").is_dir():
        pytest.skip(f"shared data not found at {SHARED} (clone has no ../shared beside it)")
    return SHARED


@pytest.fixture(scope="session")
def realphone_dir(shared_dir: Path) -> Path:
    d = shared_dir / "data" / "realphone"
    if not d.is_dir():
        pytest.skip(f"real phone logs not found at {d}")
    return d


@pytest.fixture(scope="session")
def broad_dir(shared_dir: Path) -> Path:
    d = shared_dir / "data" / "broad"
    if not d.is_dir():
        pytest.skip(f"BROAD trials not found at {d}")
    return d
