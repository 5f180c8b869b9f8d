"""Sensor Logger's push batches -> Sensor Fusion samples, one phone's recording at a time.

The documented facts (awesome-sensor-logger ``UNITS.md``, ``COORDINATES.md``,
``CROSSPLATFORM.md``; docs/phones.md cites each): ``totalacceleration`` (Android) is the
acceleration with gravity in m/s^2; ``accelerometer`` is without gravity on both platforms and
``gravity`` is the gravity vector, m/s^2; on iOS with *Standardise Units & Frames* off both have
the opposite sign of Android's (flat on a table gravity points -z), the orientation's yaw is
measured from x pointing north; gyroscope (rad/s) and magnetometer (uT) are the same on both.
Time is UTC epoch nanoseconds."""

from __future__ import annotations

import bisect
from typing import Any

from app.stream.phone_apps import PhoneSample, count_name, enu_from_nwu, finite, gravity_sign

FRAMES = ("auto", "standardised", "not-standardised")
XYZ = ("x", "y", "z")
QUATERNION = ("qw", "qx", "qy", "qz")
DIRECT = {"totalacceleration": ("ACC", XYZ), "gyroscope": ("GYR", XYZ),
          "magnetometer": ("MAG", XYZ)}
#: Sensors of the phone this program does not use (counted apart from unknown names).
NOT_USED = frozenset({
    "accelerometeruncalibrated", "gyroscopeuncalibrated", "magnetometeruncalibrated",
    "location", "barometer", "battery", "batterytemp", "brightness", "microphone",
    "pedometer", "compass", "network", "light", "annotation", "activity", "heartrate",
    "wristmotion", "headphone", "camera", "bluetooth", "bluetoothmetadata", "wifi",
    "gameorientation", "geomagneticorientation", "watchlocation", "watchbarometer",
    "watchmagnetometer", "watchcompass", "watchmicrophone"})
#: An accelerometer sample takes the gravity sample closest in time, at most this far.
GRAVITY_MATCH_NS = 100_000_000
#: Without an orientation stream the frame cannot be told: after this much phone time the
#: app's default (not standardised) is assumed.
DECIDE_WITHIN_NS = 2_000_000_000


class SensorLoggerConverter:
    """One phone's recording: batches -> Sensor Fusion samples (see the module docstring).

    frames: "auto" (tell from the data), "standardised" (Android's conventions: Android, or
    iOS with Standardise Units & Frames on) or "not-standardised" (iOS's own)."""

    def __init__(self, frames: str = "auto") -> None:
        if frames not in FRAMES:
            raise ValueError(f"frames: one of {', '.join(FRAMES)}, got {frames!r}")
        self.frames = frames
        self.sign: int | None = {"standardised": 1, "not-standardised": -1}.get(frames)
        self.android = False          # totalacceleration seen: the ACC comes from it
        self.decision = "" if self.sign is None else f"{frames} (set)"
        self.ignored: dict[str, int] = {}
        self.unknown: dict[str, int] = {}
        self.malformed = 0
        self.null_values = 0
        self.without_gravity = 0
        self.problems: list[str] = []    # new problems for the user, taken by the endpoint
        self._gravity: list[tuple[int, tuple[float, ...]]] = []   # the latest gravity samples
        self._held: dict[str, list[tuple[int, tuple[float, ...]]]] = {}
        self._held_since: int | None = None

    def convert(self, payload: list[Any]) -> list[PhoneSample]:
        grouped: dict[str, list[tuple[int, tuple[float, ...]]]] = {}
        for entry in payload:
            parsed = self._entry(entry)
            if parsed is not None:
                grouped.setdefault(parsed[0], []).append(parsed[1:])   # type: ignore[arg-type]
        if "totalacceleration" in grouped:
            self.android = True
        samples: list[PhoneSample] = []
        for name, (tag, _) in DIRECT.items():
            samples += [PhoneSample(t // 1_000_000, tag, v) for t, v in grouped.get(name, ())]
        ios = {name: grouped.get(name, []) for name in ("accelerometer", "gravity",
                                                        "orientation")}
        if self.android:
            samples += [PhoneSample(t // 1_000_000, "ORI", v) for t, v in ios["orientation"]]
            return samples
        return samples + self._ios(ios)

    def _entry(self, entry: Any) -> tuple[str, int, tuple[float, ...]] | None:
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            self.malformed += 1
            return None
        name = entry["name"].lower()
        keys = DIRECT[name][1] if name in DIRECT else QUATERNION if name == "orientation" \
            else XYZ if name in ("accelerometer", "gravity") else None
        if keys is None:
            count_name(self.ignored if name in NOT_USED else self.unknown, name)
            return None
        t = entry.get("time")
        values = entry.get("values")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or t < 0 \
                or not isinstance(values, dict):
            self.malformed += 1
            return None
        numbers = finite(values.get(key) for key in keys)
        if numbers is None:
            self.null_values += 1
            return None
        return name, int(t), numbers

    def _ios(self, batch: dict[str, list[tuple[int, tuple[float, ...]]]]) \
            -> list[PhoneSample]:
        """ACC from accelerometer + gravity, ORI from orientation, once the frame is known."""
        if self.sign is None:
            for name, items in batch.items():
                self._held.setdefault(name, []).extend(items)
            held = self._held
            self._decide(held)
            if self.sign is None:
                firsts = [items[0][0] for items in held.values() if items]
                lasts = [items[-1][0] for items in held.values() if items]
                if not firsts or max(lasts) - min(firsts) < DECIDE_WITHIN_NS:
                    return []
                self.sign = -1
                self.decision = "not-standardised (assumed: no orientation stream to tell)"
                self.problems.append(
                    "Sensor Logger sends no orientation, so whether Standardise Units & Frames "
                    "is on cannot be told: assuming it is off (the app's default); if OWN "
                    "shows the phone upside down, turn on the Orientation sensor")
            batch, self._held = held, {}
        sign = self.sign
        gravity = self._gravity + sorted(batch.get("gravity", []))
        samples = [PhoneSample(t // 1_000_000, "ORI", self._ori(q))
                   for t, q in batch.get("orientation", [])]
        if batch.get("accelerometer") and not gravity:
            self.without_gravity += len(batch["accelerometer"])
            self.problems.append("Sensor Logger sends the accelerometer without gravity and no "
                                 "Gravity stream: turn on Gravity (or Total Acceleration)")
        elif gravity:
            times = [t for t, _ in gravity]
            for t, a in batch.get("accelerometer", []):
                g = _nearest(gravity, times, t)
                if g is None:
                    self.without_gravity += 1
                    continue
                samples.append(PhoneSample(t // 1_000_000, "ACC",
                                           tuple(sign * (ai + gi) for ai, gi in zip(a, g))))
        self._gravity = gravity[-1:]
        return samples

    def _ori(self, q: tuple[float, ...]) -> tuple[float, ...]:
        return q if self.sign == 1 else enu_from_nwu(q)

    def _decide(self, held: dict[str, list[tuple[int, tuple[float, ...]]]]) -> None:
        """The sign of gravity (and so the frames) from gravity and orientation samples of
        the same times, when there are such pairs."""
        orientation = sorted(held.get("orientation", []))
        if not orientation:
            return
        times = [t for t, _ in orientation]
        votes = 0
        for t, g in held.get("gravity", []):
            q = _nearest(orientation, times, t, max_ns=20_000_000)
            if q is not None:
                votes += gravity_sign(g, q)
        if votes:
            self.sign = 1 if votes > 0 else -1
            self.decision = ("standardised (gravity points up, as on Android)" if votes > 0
                             else "not-standardised (iOS's own frames: gravity points down)")


def _nearest(items: list[tuple[int, tuple[float, ...]]], times: list[int], t: int,
             max_ns: int = GRAVITY_MATCH_NS) -> tuple[float, ...] | None:
    """The values of the item closest in time to t (at most max_ns away), else None."""
    index = bisect.bisect_left(times, t)
    best = None
    for j in (index - 1, index):
        if 0 <= j < len(times) and abs(times[j] - t) <= max_ns:
            if best is None or abs(times[j] - t) < abs(times[best] - t):
                best = j
    return None if best is None else items[best][1]
