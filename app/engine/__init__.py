"""The engine, Qt-free: ordered samples -> estimates (one runner for live and offline), the
background thread, commands, snapshots and the one configuration module shared by the command
line and the window.

Its rooms: :mod:`~app.engine.processing` (bytes -> estimates, shared by every path),
:mod:`~app.engine.live` (the engine thread, its parts, its output), :mod:`~app.engine.sessions`
(recording, replaying and indexing sessions), :mod:`~app.engine.offline` (whole logs: filter,
evaluate, re-filter, export), :mod:`~app.engine.tuning` (calibration, profiles, auto-tune) and
:mod:`~app.engine.userfilter` (your filter in its own process); beside them the engine's inputs
and outputs: :mod:`~app.engine.config` (what a user names by text), :mod:`~app.engine.commands`
(what a user asks while it runs), :mod:`~app.engine.snapshot` (what it hands the window),
:mod:`~app.engine.errors` (what goes wrong) and :mod:`~app.engine.warmup` (compiling the kernels).

Modules import each other directly by their full names; this package imports none of them, so
importing one small module of the engine (your filter's process imports only
``app.engine.userfilter``'s lean modules and ``app.engine.errors``) does not load the whole
engine.
"""
