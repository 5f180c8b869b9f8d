'''The filter template that `orientation-lab new-filter FILE.py` writes: the course's
``filterTemplate.m`` in Python, with the four functions of tasks 4, 6, 9 and the normalisation
as documented stubs (see :data:`TEMPLATE`).
'''

from __future__ import annotations

from pathlib import Path

TEMPLATE = '''"""My orientation filter (the SSY345 / TSRT14 project, tasks 3-12), for Orientation Lab.

    orientation-lab --filter {name}                    the window: YOURS beside OWN and PHONE
    orientation-lab filter LOG --estimator {name}      its estimates over a log, as CSV
    orientation-lab evaluate LOG --estimator {name}    its error against the phone's own

Save this file and the window reloads it (a replay is re-run up to where it is).

The four functions below start as stubs that raise NotImplementedError: Orientation Lab then
skips that step (x and P stay as they were) and shows which step is not written yet, so the
filter runs from the first task on: all stubs give a flat phone; write tu_qw (task 4) and it
turns with the gyroscope; then mu_g (task 6), the accelerometer gate (task 8), mu_m (task 9)
and the magnetometer gate (task 11).

Conventions: x[0:4] = q = (q0, q1, q2, q3) = (w, x, y, z), the orientation of the phone in the
world (East-North-Up): p_world = Q(q) p_phone. Units: s, rad/s, m/s^2, uT.

This is your own Python code: Orientation Lab runs it in its own process (it can do anything
your user account can). An exception in it pauses this filter until you save the file again;
everything else keeps running.
"""

import numpy as np


# ---- the kit's utility functions (project description, appendix A.2), in NumPy -------------

def Qq(q):
    """Q(q) of eq. (2a): the rotation matrix phone -> world."""
    q0, q1, q2, q3 = q
    return np.array([
        [2 * (q0**2 + q1**2) - 1, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
        [2 * (q1 * q2 + q0 * q3), 2 * (q0**2 + q2**2) - 1, 2 * (q2 * q3 - q0 * q1)],
        [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 2 * (q0**2 + q3**2) - 1]])


def dQqdq(q):
    """dQ(q)/dq_i, i = 0..3, of eqs. (2f)-(2i)."""
    q0, q1, q2, q3 = q
    Q0 = 2 * np.array([[2 * q0, -q3, q2], [q3, 2 * q0, -q1], [-q2, q1, 2 * q0]])
    Q1 = 2 * np.array([[2 * q1, q2, q3], [q2, 0, -q0], [q3, q0, 0]])
    Q2 = 2 * np.array([[0, q1, q0], [q1, 2 * q2, q3], [-q0, q3, 0]])
    Q3 = 2 * np.array([[0, -q0, q1], [q0, 0, q2], [q1, q2, 2 * q3]])
    return Q0, Q1, Q2, Q3


def Somega(w):
    """S(omega) of eq. (2d): dq/dt = 1/2 S(omega) q. (The kit's listing has a typo in row 3;
    this is eq. (2d).)"""
    wx, wy, wz = w
    return np.array([[0, -wx, -wy, -wz], [wx, 0, wz, -wy], [wy, -wz, 0, wx], [wz, wy, -wx, 0]])


def Sq(q):
    """S-bar(q) of eq. (2e): S(omega) q = S-bar(q) omega."""
    q0, q1, q2, q3 = q
    return np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


# ---- your functions -----------------------------------------------------------------------

def tu_qw(x, P, omega, T, Rw):
    """Task 4: the EKF time update with the gyroscope as input (model 4a, eq. 6).

    x (4,), P (4, 4): the state and its covariance; omega (3,): the angular rate [rad/s];
    T: the time since the previous sample [s]; Rw (3, 3): the rate noise covariance.
    Returns the predicted (x, P): x = F x, P = F P F^T + G Rw G^T with F and G from task 3.
    """
    raise NotImplementedError("task 4: tu_qw")


def mu_g(x, P, yacc, Ra, g0):
    """Task 6: the accelerometer measurement update, y = Q(q)^T g0 + e (eq. 7 with f = 0).

    yacc (3,): the reading [m/s^2]; Ra (3, 3): its noise covariance; g0 (3,): gravity in the
    world frame, (0, 0, g). Returns the updated (x, P).
    """
    raise NotImplementedError("task 6: mu_g")


def mu_m(x, P, ymag, m0, Rm):
    """Task 9: the magnetometer measurement update, y = Q(q)^T m0 + e (eq. 8 with f = 0).

    ymag (3,): the reading [uT]; m0 (3,): the Earth field in the world frame,
    (0, sqrt(mx^2 + my^2), mz) from a reading taken flat; Rm (3, 3): its noise covariance.
    Returns the updated (x, P).
    """
    raise NotImplementedError("task 9: mu_m")


def mu_normalizeQ(x, P):
    """Make q a unit quaternion with q0 >= 0 (and, if you like, carry P along with it).
    Returns (x, P)."""
    raise NotImplementedError("normalisation: mu_normalizeQ")


# ---- the filter (filterTemplate.m's loop body) -------------------------------------------

class Filter:
    """Orientation Lab calls step() once per time stamp, in time order."""

    def __init__(self, settings=None):
        # settings: the active calibration (`orientation-lab calibrate` -> --settings):
        # g0, m0 (None: take it from a reading), Rw, Ra, Rm (3x3), gyr_bias, acc_gate, ...
        s = settings or {{}}
        self.Rw = np.asarray(s.get("Rw", 1e-4 * np.eye(3)))
        self.Ra = np.asarray(s.get("Ra", 0.1 * np.eye(3)))
        self.Rm = np.asarray(s.get("Rm", 2.0 * np.eye(3)))
        self.g0 = np.asarray(s.get("g0", [0.0, 0.0, 9.81]))
        self.m0 = s.get("m0")
        self.x = np.array([1.0, 0.0, 0.0, 0.0])   # as in filterTemplate.m: start flat
        self.P = np.eye(4)
        self.t_prev = None
        self.omega = None                         # the latest gyroscope sample
        self.acc_out = False                      # task 8: setAccDist
        self.mag_out = False                      # task 11: setMagDist

    def step(self, t, gyr, acc, mag):
        """t [s]; gyr, acc, mag: (3,) arrays, or None when there is no such sample at t."""
        # Time update with the latest angular rate (task 5).
        if self.t_prev is not None and self.omega is not None and t > self.t_prev:
            self.x, self.P = tu_qw(self.x, self.P, self.omega, t - self.t_prev, self.Rw)
            self.x, self.P = mu_normalizeQ(self.x, self.P)
        self.t_prev = t
        if gyr is not None:
            self.omega = gyr

        if acc is not None:
            # Task 8: decide whether this reading is an outlier; skip the update if it is.
            self.acc_out = False
            if not self.acc_out:
                self.x, self.P = mu_g(self.x, self.P, acc, self.Ra, self.g0)
                self.x, self.P = mu_normalizeQ(self.x, self.P)

        if mag is not None:
            if self.m0 is None:
                # Task 9: m0 from a reading taken flat (here: the first one).
                self.m0 = np.array([0.0, np.hypot(mag[0], mag[1]), mag[2]])
            # Task 11: decide whether this reading is disturbed; skip the update if it is.
            self.mag_out = False
            if not self.mag_out:
                self.x, self.P = mu_m(self.x, self.P, mag, self.m0, self.Rm)
                self.x, self.P = mu_normalizeQ(self.x, self.P)

        return {{"q": self.x[:4], "P": self.P,
                "acc_disturbed": self.acc_out, "mag_disturbed": self.mag_out}}
'''


def template_text(name: str = "my_filter.py") -> str:
    """The template, naming the file it will be saved as."""
    return TEMPLATE.format(name=name)


def write_template(path: str | Path) -> Path:
    """Write the template to `path` (a new .py file). FileExistsError if it exists (a file of
    the user's is never overwritten), OSError if it cannot be written, ValueError if the name
    does not end in .py."""
    path = Path(path)
    if path.suffix.lower() != ".py":
        raise ValueError(f"{path}: a filter file's name ends in .py")
    with open(path, "x", encoding="utf-8", newline="\n") as stream:   # "x": never overwrite
        stream.write(template_text(path.name))
    return path
