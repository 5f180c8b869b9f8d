"""ConfigError, the engine's one error for "what the user asked for cannot be done".

Kept apart from config.py so that modules config.py itself uses (profiles) can raise it;
``app.engine.config.ConfigError`` is this class.
"""

from __future__ import annotations


class ConfigError(Exception):
    """Something the user asked for cannot be done: a one-line message, no traceback."""
