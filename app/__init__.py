"""Orientation Lab: everything a user touches (I/O, engine, command line, window)."""

__version__ = "0.1.0"
