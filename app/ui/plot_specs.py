"""What the live plots draw: the tabs and their plots (sensors, orientation, error vs PHONE),
the curves of each (stream, column, colour, line style, the legend toggles that show it), the
legends, and the cursor readout's table. No widgets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from app.ui.plot_data import time_text

DEFAULT_WINDOW_S = 10.0
MAX_WINDOW_S = 600.0
AXIS_COLORS = ((220, 50, 50), (40, 160, 60), (50, 100, 230))    # x, y, z
NORM_COLOR = (90, 90, 90)
REJECTED_COLOR = (225, 40, 40)
OFF_COLOR = (130, 132, 140)      # a sensor switched off: its samples are not used
OFF_JOIN_S = 0.5                 # "off" samples closer than this are one stretch
GATE_COLOR = (200, 120, 0)
MARKER_COLOR = (230, 120, 0)
FIRST_PLOTS = ("acc", "yaw", "error")    # the top plot of each tab labels the markers
ERROR_COLORS = ((130, 40, 170), (230, 120, 0), (0, 150, 150))   # total, heading, inclination
EULER_NAMES = ("yaw", "pitch", "roll")
# yaw is about z, pitch about y, roll about x: each in its axis' colour
EULER_COLORS = (AXIS_COLORS[2], AXIS_COLORS[1], AXIS_COLORS[0])
EULER_TOOLTIP = ("Euler angles z-y-x (the course's q2euler intent, its errata fixed): "
                 "R = Rz(yaw) Ry(pitch) Rx(roll), sensor -> East-North-Up; yaw about up "
                 "(0 = the phone's y axis to the north, counter-clockwise positive), pitch about "
                 "the turned y axis (±90°), roll about the phone's x axis.")
# The toolbar's note while the plots do not follow (paused, or zoomed/dragged by hand)
FOLLOW_NOTE_STYLE = ("QLabel { background: #ffe8a8; color: #5a3c00; border: 1px solid #e0b040; "
                     "border-radius: 3px; padding: 1px 6px; }")
LEFT_AXIS_WIDTH = 64        # px, the same for every plot so their time axes line up
BAND_FRACTION = 0.035       # the rejected band: this much of the plot's height, at the bottom


@dataclass
class CurveSpec:
    stream: str
    column: int
    plot: str
    label: str           # the cursor readout's row/column name
    tags: frozenset[str]  # the legend toggles that show/hide it
    color: tuple[int, int, int]
    dashed: bool = False
    dotted: bool = False


@dataclass
class PlotSpec:
    key: str
    group: str
    title: str
    units: str
    tooltip: str = ""


GROUPS = (("sensors", "Sensors"), ("orientation", "Orientation"), ("error", "Error vs PHONE"))
PLOTS = (
    PlotSpec("acc", "sensors", "acc", "m/s²", "specific force, sensor frame"),
    PlotSpec("gyr", "sensors", "gyr", "rad/s", "angular rate, sensor frame"),
    PlotSpec("mag", "sensors", "mag", "µT", "magnetic field, sensor frame"),
    PlotSpec("yaw", "orientation", "yaw", "°", EULER_TOOLTIP),
    PlotSpec("pitch", "orientation", "pitch", "°", EULER_TOOLTIP),
    PlotSpec("roll", "orientation", "roll", "°", EULER_TOOLTIP),
    PlotSpec("error", "error", "OWN vs PHONE", "°",
              "e = q_OWN ⊗ conj(q_PHONE) at PHONE's time stamps (OWN slerped to them): total "
              "angle 2·acos|e_w|, heading 2·atan|e_z/e_w| (about up), inclination (tilt)"),
)
STREAM_COLUMNS = {"acc": 5, "gyr": 4, "mag": 5, "own": 3, "phone": 3, "error": 3, "user": 3,
                  "user_error": 3}
USER_STREAMS = ("user", "user_error")   # YOURS: replaced by a re-run's history, never clear others


def curve_specs() -> list[CurveSpec]:
    specs = []
    for key in ("acc", "gyr", "mag"):
        for column, name in enumerate(("x", "y", "z")):
            specs.append(CurveSpec(key, column, key, f"{key} {name}", frozenset({name}),
                                    AXIS_COLORS[column]))
        specs.append(CurveSpec(key, 3, key, f"{key} norm", frozenset({"norm"}), NORM_COLOR))
    for column, name in enumerate(EULER_NAMES):
        specs.append(CurveSpec("own", column, name, f"OWN {name}", frozenset({"OWN"}),
                                EULER_COLORS[column]))
        specs.append(CurveSpec("phone", column, name, f"PHONE {name}", frozenset({"PHONE"}),
                                EULER_COLORS[column], dashed=True))
        specs.append(CurveSpec("user", column, name, f"YOURS {name}", frozenset({"YOURS"}),
                                EULER_COLORS[column], dotted=True))
    for column, name in enumerate(("total", "heading", "inclination")):
        specs.append(CurveSpec("error", column, "error", name, frozenset({name, "OWN"}),
                                ERROR_COLORS[column]))
        specs.append(CurveSpec("user_error", column, "error", f"YOURS {name}",
                                frozenset({name, "YOURS"}), ERROR_COLORS[column], dotted=True))
    return specs


LEGENDS = {
    "sensors": (("x", AXIS_COLORS[0], "line"), ("y", AXIS_COLORS[1], "line"),
                ("z", AXIS_COLORS[2], "line"), ("norm", NORM_COLOR, "line"),
                ("rejected", REJECTED_COLOR, "band"), ("off", OFF_COLOR, "dashed band"),
                ("gates", GATE_COLOR, "dash")),
    "orientation": (("OWN", (60, 60, 60), "line"), ("PHONE", (60, 60, 60), "dash"),
                    ("YOURS", (60, 60, 60), "dot")),
    "error": (("total", ERROR_COLORS[0], "line"), ("heading", ERROR_COLORS[1], "line"),
              ("inclination", ERROR_COLORS[2], "line"), ("OWN", (60, 60, 60), "line"),
              ("YOURS", (60, 60, 60), "dot")),
}
LEGEND_TIPS = {
    "rejected": "samples the filter rejected (a gate fired): a red band along the bottom",
    "off": "the sensor was switched off: the filter did not use these samples (a grey dashed "
           "band; no gate was asked)",
}
USER_TOGGLES = (("orientation", "YOURS"), ("error", "YOURS"), ("error", "OWN"))


READOUT_ROWS = {
    "sensors": ((("acc", "m/s²"), ("gyr", "rad/s"), ("mag", "µT")), ("x", "y", "z", "norm")),
    "orientation": ((("OWN", "°"), ("PHONE", "°"), ("YOURS", "°")), EULER_NAMES),
    "error": (((None, "°"), ("YOURS", "°")), ("total", "heading", "inclination")),
}


def readout_table(values: dict[str, float], t: float, span: float, group: str) -> str:
    """The cursor's readout: a small HTML table of the tab's values with units."""
    rows, columns = READOUT_ROWS[group]
    head = "".join(f"<th align='right'>&nbsp;{c}&nbsp;</th>" for c in columns)
    lines = [f"<table cellspacing='0' cellpadding='1'><tr><th align='left'>t = "
             f"{time_text(t, span, 3)} s</th>{head}<th></th></tr>"]
    for name, unit in rows:
        labels = [column if name is None else f"{name} {column}" for column in columns]
        if name == "YOURS" and all(label not in values for label in labels):
            continue            # no YOURS loaded (or all its curves hidden)
        cells = []
        for label in labels:
            value = values.get(label)
            cells.append("–" if value is None or not math.isfinite(value) else f"{value:.3f}")
        title = name or "OWN vs PHONE"
        if group == "error" and name == "YOURS":
            title = "YOURS vs PHONE"
        lines.append(f"<tr><td>{title}</td>" + "".join(f"<td align='right'>&nbsp;{c}&nbsp;</td>"
                                                        for c in cells)
                     + f"<td>{unit}</td></tr>")
    return "".join(lines) + "</table>"
