"""Optional libraries of the numerics (scipy, allantools), imported when first needed.

They are runtime dependencies of the package (pyproject.toml), so an ordinary install has them;
an environment without them still imports ekf, and the one function that needs a library says
in one line what to install.
"""

from __future__ import annotations

import importlib
from types import ModuleType


class MissingLibrary(ImportError):
    """A library a calculation needs is not installed (a one-line message naming it)."""


def require(module: str, purpose: str) -> ModuleType:
    """Import `module` ("scipy.stats", "allantools", ...) or raise :class:`MissingLibrary`."""
    try:
        return importlib.import_module(module)
    except ImportError:
        package = module.split(".")[0]
        raise MissingLibrary(f"{purpose} needs the Python package {package!r} "
                             f"(pip install {package})") from None
