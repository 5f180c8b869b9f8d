"""Named window layouts (as x-IMU3's GUI and PlotJuggler save theirs): where the docks are,
the splitters between the 3D views and the plots, and which tab of plots shows.

Kept in the window's QSettings under "layouts/<name>/..."; the layout the window closed with is
"window/..." and comes back at the next start.
"""

from __future__ import annotations

from typing import Any

from PySide6 import QtCore

LAYOUT_VERSION = 2     # QMainWindow.saveState version: a state from another layout is ignored


class LayoutStore:
    def __init__(self, settings: QtCore.QSettings) -> None:
        self.settings = settings

    def names(self) -> list[str]:
        self.settings.beginGroup("layouts")
        try:
            return sorted(self.settings.childGroups())
        finally:
            self.settings.endGroup()

    @staticmethod
    def _key(name: str) -> str:
        return "layouts/" + name.replace("/", "∕")

    def save(self, name: str, window: Any) -> None:
        self.write_current(self.settings, window, self._key(name))
        self.settings.sync()

    def apply(self, name: str, window: Any) -> bool:
        if name not in self.names():
            return False
        return self.read_current(self.settings, window, self._key(name))

    def delete(self, name: str) -> None:
        self.settings.remove(self._key(name))
        self.settings.sync()

    @staticmethod
    def write_current(settings: QtCore.QSettings, window: Any, prefix: str) -> None:
        settings.setValue(f"{prefix}/state", window.saveState(LAYOUT_VERSION))
        settings.setValue(f"{prefix}/central_splitter", window.central_splitter.saveState())
        settings.setValue(f"{prefix}/views_splitter", window.views_splitter.saveState())
        settings.setValue(f"{prefix}/plot_tab", window.plots.current_group())

    @staticmethod
    def read_current(settings: QtCore.QSettings, window: Any, prefix: str) -> bool:
        state = settings.value(f"{prefix}/state")
        restored = state is not None and window.restoreState(state, LAYOUT_VERSION)
        for key, splitter in (("central_splitter", window.central_splitter),
                              ("views_splitter", window.views_splitter)):
            value = settings.value(f"{prefix}/{key}")
            if value is not None:
                splitter.restoreState(value)
        tab = settings.value(f"{prefix}/plot_tab")
        if isinstance(tab, str) and tab in window.plots.groups:
            window.plots.set_current_group(tab)
        return bool(restored)
