"""Widgets: draw snapshots, forward user intent as engine commands."""
