"""Your filter (YOURS): a user's Python file run beside the main estimator.

code.py loads the file and checks its class; filter.py wraps it as an ``ekf.Estimator``;
watchdog.py bounds the time a call may take; lane.py runs it on the engine's rows within a
share of the engine's time; host.py is the engine's side (load, unload, reload, the whole
session's YOURS curve); template.py writes the `new-filter` template.

The modules import each other directly; this package gathers no names (import a name from
the module that defines it).
"""
