"""Helpers for the tests of MATLAB filters run in GNU Octave: the solved course filter under
tests/octave_filters/course, folders made from it with one file changed (an error of each kind),
and the mark that skips a test where Octave is not installed."""

from __future__ import annotations

import os
import shutil
import textwrap
from pathlib import Path

import pytest

COURSE_M = Path(__file__).resolve().parent / "octave_filters" / "course"
COURSE_LEAN = COURSE_M.with_name("course_lean")     # the same filter, the helpers inlined

needs_octave = pytest.mark.skipif(
    shutil.which("octave-cli") is None and shutil.which("octave") is None,
    reason="GNU Octave is not installed (Debian: apt-get install octave; CI installs it)")

# Files that replace one of the solved filter's, each with one mistake (a comment line first, so
# the line numbers in the messages are the ones written here).
BROKEN = {
    "syntax": ("mu_g.m", """
        function [x, P] = mu_g(x, P, yacc, Ra, g0)
          % line 2
          K = P * (H' ;
        end
    """),
    "runtime": ("mu_g.m", """
        function [x, P] = mu_g(x, P, yacc, Ra, g0)
          % line 2
          H = ones(3, 4);
          K = P * H;
        end
    """),
    "wrong_size": ("tu_qw.m", """
        function [x, P] = tu_qw(x, P, omega, T, Rw)
          F = eye(4) + T/2*Somega(omega);
          x = (F*x)';
        end
    """),
    "not_finite": ("mu_m.m", """
        function [x, P] = mu_m(x, P, mag, m0, Rm)
          x = x / 0 - x / 0;
        end
    """),
    "endless": ("tu_qw.m", """
        function [x, P] = tu_qw(x, P, omega, T, Rw)
          k = 0;
          while true
            k = k + 1;
          end
        end
    """),
    "keyboard": ("mu_m.m", """
        function [x, P] = mu_m(x, P, mag, m0, Rm)
          answer = input('continue? ');
        end
    """),
    "crash": ("mu_m.m", """
        function [x, P] = mu_m(x, P, mag, m0, Rm)
          exit(7);
        end
    """),
}


def matlab_filter(folder: Path, broken: str | None = None, **files: str) -> Path:
    """A copy of the solved course filter in folder/course (with BROKEN[broken] written over
    one of its files, and any files given as name=text, e.g. filter_settings="...")."""
    target = Path(folder) / "course"
    shutil.copytree(COURSE_M, target)
    changes = dict(files)
    if broken is not None:
        name, text = BROKEN[broken]
        changes[name.removesuffix(".m")] = text
    for name, text in changes.items():
        (target / f"{name}.m").write_text(textwrap.dedent(text).lstrip("\n"))
    return target


def save_m(path: Path, text: str) -> None:
    """Write a .m file so that a watcher sees it saved (its mtime moves on even on a
    coarse-clocked file system)."""
    before = path.stat().st_mtime_ns if path.exists() else 0
    path.write_text(textwrap.dedent(text).lstrip("\n"))
    stamp = max(before + 2_000_000_000, path.stat().st_mtime_ns)
    os.utime(path, ns=(stamp, stamp))
