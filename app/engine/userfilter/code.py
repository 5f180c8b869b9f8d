"""A user's filter file: loading it, finding the user's line in an error, checking its output.

A user filter is one Python file defining ``class Filter`` with ``step(self, t, gyr, acc,
mag)``. It is the user's own code and runs in its own process (app.engine.userfilter.child),
with the user's rights; nothing here sandboxes it. This module, which runs in that process,
turns everything that can go wrong with it into a :class:`~app.engine.errors.UserProblem`
(file, line, one-line message, the traceback of the user's frames) instead of an exception:

* :func:`load_code` reads and executes the file (its SHA-256 is of exactly the bytes run);
* the course's steps (``tu_qw``, ``mu_g``, ``mu_m``, ``mu_normalizeQ``) are wrapped so that a
  stub raising ``NotImplementedError`` is *skipped* (it returns its x and P unchanged) and
  noted as "not written yet";
* :func:`parse_output` checks what ``step`` returned (a quaternion, or a dict with "q" and
  optionally "P", the three lights and "innovations") and names what is wrong.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import inspect
import itertools
import linecache
import math
import sys
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, Callable

import numpy as np

from app.engine.errors import ConfigError, UserProblem
from app.engine.userfilter.octave import is_matlab_filter
from app.engine.userfilter.protocol import INNOVATION_SENSORS
from app.engine.userfilter.watchdog import UserCodeTimeout, guard

LOAD_LIMIT_S = 10.0          # executing the file, Filter(): imports may take a while

#: The course's functions (tasks 4, 6, 9 and the normalisation): a stub that raises
#: NotImplementedError is skipped, returning its (x, P) unchanged.
COURSE_STEPS = ("tu_qw", "mu_g", "mu_m", "mu_normalizeQ")
OUTPUT_KEYS = ("q", "P", "acc_disturbed", "mag_disturbed", "standstill", "innovations")
UNIT_TOLERANCE = 1e-3        # | |q| - 1 | above this is a non-unit quaternion
MAX_MESSAGE = 300

_module_numbers = itertools.count(1)


class UserFilterError(ConfigError):
    """The file cannot be used (missing, does not load, no class Filter...): ``problem`` says
    why, with the file and line. A ConfigError: the command line says its one line and exits
    with status 2, the window shows it."""

    def __init__(self, problem: UserProblem) -> None:
        super().__init__(problem.message)
        self.problem = problem


def is_filter_file(name: str | Path) -> bool:
    """Whether an estimator name is a user's filter rather than a built-in: a Python file (ends
    in .py) or a MATLAB filter (a .m file, or a folder: app.engine.userfilter.octave)."""
    return str(name).lower().endswith(".py") or is_matlab_filter(name)


def _one_line(text: str) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 1] + "…"


# ---- where in the user's code ------------------------------------------------------------------

# What a user's code may raise that stops their filter and nothing else: sys.exit() and Ctrl-C
# inside it included (our own timeout is handled apart, where it is raised).
USER_ERRORS = (Exception, SystemExit, KeyboardInterrupt)


def problem_from_exception(error: BaseException, path: Path, t_s: float | None = None,
                           kind: str = "exception", during: str = "") -> UserProblem:
    """The problem an exception raised in the user's file is: its deepest frame in that file
    (file, line, function), one line "file:line in function: Type: message", and the traceback
    from the first frame in the user's file on (our own frames left out)."""
    name = path.name
    if isinstance(error, SyntaxError) and error.filename and Path(error.filename) == path:
        line = error.lineno
        message = f"{name}:{line}: SyntaxError: {error.msg}"
        details = "".join(traceback.format_exception_only(type(error), error))
        return UserProblem(kind, _one_line(message), details, str(path), line, None, t_s)
    frames = traceback.extract_tb(error.__traceback__)
    mine = [index for index, frame in enumerate(frames) if _same_file(frame.filename, path)]
    if isinstance(error, SystemExit):
        text = _one_line(f"SystemExit({error.code!r}): sys.exit() in a filter stops the filter, "
                         "not the program")
    else:
        text = _one_line(f"{type(error).__name__}: {error}" if str(error)
                         else type(error).__name__)
    if mine:
        frame = frames[mine[-1]]
        where = f"{name}:{frame.lineno} in {frame.name}"
        # the user's frames and what they called (numpy, ...), never Orientation Lab's own
        shown = [f for f in frames[mine[0]:]
                 if _same_file(f.filename, path) or not _ours(f.filename)]
        line, function = frame.lineno, frame.name
    else:       # raised by the call itself (a step with the wrong arguments): no frame of theirs
        where, shown, line, function = name, [], None, None
    details = (("Traceback (most recent call last):\n" + "".join(traceback.format_list(shown))
                if shown else f"raised where Orientation Lab called {name} (no line of it ran):\n")
               + "".join(traceback.format_exception_only(type(error), error)))
    if during:
        details = f"{during}\n{details}"
    return UserProblem(kind, _one_line(f"{where}: {text}"), details, str(path), line, function,
                       t_s)


_APP = Path(__file__).resolve().parents[2]
_OUR_PACKAGES = (_APP, _APP.parent / "ekf")


def _ours(filename: str) -> bool:
    """Whether a frame is Orientation Lab's own code (app/ or ekf/), not the user's."""
    try:
        where = Path(filename).resolve()
    except (OSError, ValueError):
        return False
    return any(where.is_relative_to(package) for package in _OUR_PACKAGES)


def _same_file(filename: str, path: Path) -> bool:
    try:
        return Path(filename).resolve() == path
    except (OSError, ValueError):
        return False


def raise_site(error: BaseException, path: Path) -> str:
    """"my_filter.py:58" for the deepest frame of `error` in the user's file ("" if none)."""
    frames = [f for f in traceback.extract_tb(error.__traceback__) if _same_file(f.filename, path)]
    return f"{path.name}:{frames[-1].lineno}" if frames else ""


# ---- loading --------------------------------------------------------------------------------

@dataclass
class FilterCode:
    """A loaded filter file: the module (executed from exactly the bytes hashed), its Filter
    class, and the course steps noted as not written yet (step name -> where it raised)."""

    path: Path
    sha256: str
    module: ModuleType
    filter_class: type
    takes_settings: bool
    missing: dict[str, str] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.path.name

    def note_missing(self, step: str, error: BaseException) -> None:
        if step not in self.missing:
            self.missing[step] = raise_site(error, self.path)

    def missing_steps(self) -> list[str]:
        """["mu_g (my_filter.py:61)", ...] in the course's order."""
        order = {name: index for index, name in enumerate(COURSE_STEPS)}
        steps = sorted(self.missing, key=lambda s: (order.get(s, len(order)), s))
        return [f"{s} ({self.missing[s]})" if self.missing[s] else s for s in steps]


def _skippable(function: Callable, step: str, code: FilterCode) -> Callable:
    """A course step that, while it raises NotImplementedError, returns its x and P unchanged."""
    @functools.wraps(function)
    def step_or_skip(*args, **kwargs):
        try:
            return function(*args, **kwargs)
        except NotImplementedError as error:
            code.note_missing(step, error)
            x = args[0] if len(args) > 0 else kwargs.get("x")
            P = args[1] if len(args) > 1 else kwargs.get("P")
            return x, P
    step_or_skip.__wrapped_course_step__ = True
    return step_or_skip


def _takes_settings(cls: type) -> bool:
    try:
        parameters = inspect.signature(cls).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.name == "settings" or p.kind is inspect.Parameter.VAR_KEYWORD
               for p in parameters)


def load_code(path: str | Path, source: bytes | None = None) -> FilterCode:
    """Run the file (`source`: its bytes, already read); UserFilterError (with the file and line)
    when it cannot be used."""
    path = Path(path).expanduser().resolve()
    if source is None:
        try:
            source = path.read_bytes()
        except OSError as error:
            raise UserFilterError(UserProblem(
                "load", f"{path.name}: cannot read ({error.strerror or error})",
                file=str(path))) from None
    name = f"orientation_lab_user_filter_{next(_module_numbers)}"
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, loader=None))
    module.__file__ = str(path)
    text = source.decode("utf-8", errors="replace")
    # Tracebacks show the lines that ran, even if the file on disk changes again.
    linecache.cache[str(path)] = (len(text), None, text.splitlines(True), str(path))
    sys.modules[name] = module      # dataclasses and pickling look the module up by name
    watch = guard(LOAD_LIMIT_S, "loading the file")
    try:
        with watch:
            exec(compile(source, str(path), "exec"), module.__dict__)
    except (*USER_ERRORS, UserCodeTimeout) as error:   # noqa: BLE001 (anything on import)
        watch.disarm()
        sys.modules.pop(name, None)
        raise UserFilterError(problem_from_exception(error, path, kind="load")) from None
    cls = module.__dict__.get("Filter")
    if not isinstance(cls, type) or not callable(getattr(cls, "step", None)):
        sys.modules.pop(name, None)
        raise UserFilterError(UserProblem(
            "load", f"{path.name}: no class Filter with a method step(self, t, gyr, acc, mag)",
            "A filter file defines class Filter; see `orientation-lab new-filter FILE.py` for a "
            "template.", str(path)))
    code = FilterCode(path, hashlib.sha256(source).hexdigest(), module, cls, _takes_settings(cls))
    for step in COURSE_STEPS:
        function = module.__dict__.get(step)
        if inspect.isfunction(function):
            module.__dict__[step] = _skippable(function, step, code)
    return code


def instantiate(code: FilterCode, settings: dict[str, Any]) -> Any:
    """A new Filter (with settings when its constructor takes them); UserFilterError if it
    raises."""
    watch = guard(LOAD_LIMIT_S, "Filter()")
    try:
        with watch:
            return (code.filter_class(settings=settings) if code.takes_settings
                    else code.filter_class())
    except NotImplementedError as error:
        raise UserFilterError(problem_from_exception(
            error, code.path, kind="exception", during="Filter() is not written yet")) from None
    except (*USER_ERRORS, UserCodeTimeout) as error:      # noqa: BLE001
        watch.disarm()
        raise UserFilterError(problem_from_exception(error, code.path)) from None


# ---- what step returned ---------------------------------------------------------------------

@dataclass
class Output:
    """One step's return value, checked: q (4,) unit, w >= 0; P (n, n) n >= 4 or None; the
    lights (None: not reported); innovations: sensor -> (nu (k,), S (k, k), accepted or None);
    notes: remarks that do not stop the filter (unknown keys)."""

    q: np.ndarray
    P: np.ndarray | None = None
    acc_disturbed: bool | None = None
    mag_disturbed: bool | None = None
    standstill: bool | None = None
    innovations: dict[str, tuple[np.ndarray, np.ndarray, bool | None]] = field(
        default_factory=dict)
    notes: list[str] = field(default_factory=list)


class BadOutput(Exception):
    """What is wrong with a return value, in one line."""


def _numbers(value: Any, what: str) -> np.ndarray:
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise BadOutput(f"{what} is not numbers (got {type(value).__name__})") from None
    return array


def _quaternion(value: Any, notes: list[str], unnormalised_ok: bool = False) -> np.ndarray:
    q = _numbers(value, "q")
    if q.size != 4 or (q.ndim > 1 and max(q.shape) != 4):
        raise BadOutput(f"q has shape {q.shape}, expected 4 numbers (w, x, y, z)")
    q = q.reshape(4)
    if not np.all(np.isfinite(q)):
        raise BadOutput(f"q is not finite: {np.array2string(q, precision=4)}")
    norm = math.sqrt(float(q @ q))
    if abs(norm - 1.0) > UNIT_TOLERANCE and unnormalised_ok and norm > 0.0:
        notes.append("q is normalised for display: mu_normalizeQ is not written yet")
    elif abs(norm - 1.0) > UNIT_TOLERANCE:
        raise BadOutput(f"q is not a unit quaternion: |q| = {norm:.6g} (normalise it, e.g. "
                        "with mu_normalizeQ)")
    q = q / norm
    return -q if q[0] < 0 else q


def _covariance(value: Any) -> np.ndarray:
    P = _numbers(value, "P")
    if P.ndim != 2 or P.shape[0] != P.shape[1] or P.shape[0] < 4:
        raise BadOutput(f"P has shape {P.shape}, expected a square matrix of 4x4 or larger "
                        "(the quaternion first)")
    if not np.all(np.isfinite(P)):
        raise BadOutput("P is not finite (NaN or inf)")
    return P


def _flag(value: Any, key: str) -> bool | None:
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or (isinstance(value, (int, np.integer))
                                                and value in (0, 1)):
        return bool(value)
    raise BadOutput(f"{key} must be True or False, got {value!r}")


def _innovation(sensor: str, value: Any) -> tuple[np.ndarray, np.ndarray, bool | None]:
    accepted = None
    if isinstance(value, dict):
        if "innovation" not in value or "S" not in value:
            raise BadOutput(f"innovations[{sensor!r}] needs 'innovation' and 'S'")
        nu, S, accepted = value["innovation"], value["S"], value.get("accepted")
    elif isinstance(value, (tuple, list)) and len(value) in (2, 3):
        nu, S = value[0], value[1]
        accepted = value[2] if len(value) == 3 else None
    else:
        raise BadOutput(f"innovations[{sensor!r}] must be (innovation, S) or a dict")
    nu = _numbers(nu, f"innovations[{sensor!r}] innovation").reshape(-1)
    k = nu.size
    if not 1 <= k <= 3:
        raise BadOutput(f"innovations[{sensor!r}]: the innovation has {k} components "
                        "(1 to 3 per sensor)")
    S = _numbers(S, f"innovations[{sensor!r}] S")
    S = S.reshape(1, 1) if S.size == 1 and k == 1 else S
    if S.shape != (k, k):
        raise BadOutput(f"innovations[{sensor!r}]: S has shape {S.shape}, expected ({k}, {k})")
    if not (np.all(np.isfinite(nu)) and np.all(np.isfinite(S))):
        raise BadOutput(f"innovations[{sensor!r}] is not finite")
    return nu, S, _flag(accepted, f"innovations[{sensor!r}]['accepted']")


def parse_output(result: Any, unnormalised_ok: bool = False) -> Output:
    """Check what Filter.step returned; BadOutput names what is wrong. unnormalised_ok: a
    finite non-unit q is normalised with a note instead (while mu_normalizeQ is a stub)."""
    notes: list[str] = []
    if not isinstance(result, dict):
        if result is None:
            raise BadOutput("step returned None: return the quaternion, or a dict with 'q'")
        return Output(_quaternion(result, notes, unnormalised_ok), notes=notes)
    if "q" not in result:
        raise BadOutput(f"the dict step returned has no 'q' (keys: {', '.join(map(str, result))})")
    out = Output(_quaternion(result["q"], notes, unnormalised_ok), notes=notes)
    if result.get("P") is not None:
        out.P = _covariance(result["P"])
    for key in ("acc_disturbed", "mag_disturbed", "standstill"):
        setattr(out, key, _flag(result.get(key), key))
    innovations = result.get("innovations")
    if innovations is not None:
        if not isinstance(innovations, dict):
            raise BadOutput("innovations must be a dict: sensor -> (innovation, S)")
        for sensor, value in innovations.items():
            if sensor not in INNOVATION_SENSORS:
                raise BadOutput(f"innovations: unknown sensor {sensor!r} (use "
                                f"{', '.join(INNOVATION_SENSORS)})")
            if value is not None:
                out.innovations[sensor] = _innovation(sensor, value)
    unknown = [str(key) for key in result if key not in OUTPUT_KEYS]
    if unknown:
        out.notes.append(f"step returned keys that Orientation Lab does not use (ignored): "
                         f"{', '.join(unknown)}")
    return out


def output_problem(error: BadOutput, code: FilterCode, t_s: float) -> UserProblem:
    """A BadOutput as the problem that pauses the filter."""
    message = f"{code.name}: Filter.step returned garbage at t = {t_s:.3f} s: {error}"
    return UserProblem("output", _one_line(message), str(error), str(code.path), None, "step", t_s)

