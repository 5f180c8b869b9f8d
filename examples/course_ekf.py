"""A complete course EKF written the way a student would, against the `new-filter` template.

Model 4a (x = q, the gyroscope as input) with the task-8 accelerometer gate and the task-11
magnetometer gate (an AR(1) estimate of the field strength), plain NumPy, one function per
task. It follows the ``course`` preset of Orientation Lab's own filter closely enough to agree
with it to well under 0.1 degrees on real phone logs (tests/test_course_example.py), because it
starts the same way: from the first accelerometer reading (tilt), the heading from the first
magnetometer reading, and m0 from that reading turned to the world frame.

Use it as your filter::

    orientation-lab --filter examples/course_ekf.py
    orientation-lab evaluate LOG --estimator course,examples/course_ekf.py --settings course

Run as a script, it filters a simulated session and prints its error against the truth and
its difference to the built-in course filter.
"""

import math

import numpy as np


# ---- the kit's utility functions (appendix A.2) ------------------------------------------

def Qq(q):
    """Q(q), eq. (2a): rotation matrix phone -> world."""
    q0, q1, q2, q3 = q
    return np.array([
        [2 * (q0**2 + q1**2) - 1, 2 * (q1 * q2 - q0 * q3), 2 * (q1 * q3 + q0 * q2)],
        [2 * (q1 * q2 + q0 * q3), 2 * (q0**2 + q2**2) - 1, 2 * (q2 * q3 - q0 * q1)],
        [2 * (q1 * q3 - q0 * q2), 2 * (q2 * q3 + q0 * q1), 2 * (q0**2 + q3**2) - 1]])


def dQqdq(q):
    """dQ/dq_i, eqs. (2f)-(2i)."""
    q0, q1, q2, q3 = q
    Q0 = 2 * np.array([[2 * q0, -q3, q2], [q3, 2 * q0, -q1], [-q2, q1, 2 * q0]])
    Q1 = 2 * np.array([[2 * q1, q2, q3], [q2, 0, -q0], [q3, q0, 0]])
    Q2 = 2 * np.array([[0, q1, q0], [q1, 2 * q2, q3], [-q0, q3, 0]])
    Q3 = 2 * np.array([[0, -q0, q1], [q0, 0, q2], [q1, q2, 2 * q3]])
    return Q0, Q1, Q2, Q3


def Somega(w):
    """S(omega), eq. (2d) (row 3 ends in wx: the kit's listing has a typo there)."""
    wx, wy, wz = w
    return np.array([[0, -wx, -wy, -wz], [wx, 0, wz, -wy], [wy, -wz, 0, wx], [wz, wy, -wx, 0]])


def Sq(q):
    """S-bar(q), eq. (2e)."""
    q0, q1, q2, q3 = q
    return np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


def quat_mult(p, q):
    """The quaternion product p * q (Q(p * q) = Q(p) Q(q))."""
    p0, p1, p2, p3 = p
    return np.array([p0 * q[0] - p1 * q[1] - p2 * q[2] - p3 * q[3],
                     p0 * q[1] + p1 * q[0] + p2 * q[3] - p3 * q[2],
                     p0 * q[2] - p1 * q[3] + p2 * q[0] + p3 * q[1],
                     p0 * q[3] + p1 * q[2] - p2 * q[1] + p3 * q[0]])


def turn_about_up(q, angle):
    """Turn the orientation q about the world's up axis by `angle` [rad]."""
    return quat_mult(np.array([math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)]), q)


def rotation_to_quat(R):
    """Eq. (2b), dividing by the largest of 4 q_i^2 so it never divides by ~0."""
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    k = int(np.argmax([trace, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2 * math.sqrt(max(1 + trace, 0.0))
        q = [s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif k == 1:
        s = 2 * math.sqrt(max(1 + R[0, 0] - R[1, 1] - R[2, 2], 0.0))
        q = [(R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif k == 2:
        s = 2 * math.sqrt(max(1 - R[0, 0] + R[1, 1] - R[2, 2], 0.0))
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2 * math.sqrt(max(1 - R[0, 0] - R[1, 1] + R[2, 2], 0.0))
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4]
    q = np.array(q)
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0 else q


# ---- the four functions of the template ----------------------------------------------------

def tu_qw(x, P, omega, T, Rw):
    """Task 4: q_k = F q_{k-1} + G v, F = I + T/2 S(omega), G = T/2 S-bar(q)."""
    F = np.eye(4) + T / 2 * Somega(omega)
    G = T / 2 * Sq(x)
    x = F @ x
    P = F @ P @ F.T + G @ Rw @ G.T
    return x, P


def tu_q(x, P, T, sigma):
    """Task 4's second function, for when there is no gyroscope sample: q stays, P grows as if
    omega were white noise of intensity sigma^2 [rad^2/s]."""
    G = Sq(x)
    P = P + T / 4 * sigma**2 * (G @ G.T)
    return x, P


def innovation(x, P, y, R, v0):
    """For y = Q(q)^T v0 + e: the innovation y - y_hat, its covariance S and H."""
    H = np.column_stack([Qi.T @ v0 for Qi in dQqdq(x)])
    S = H @ P @ H.T + R
    return y - Qq(x).T @ v0, S, H


def ekf_update(x, P, nu, S, H, R):
    """The Kalman update, with the Joseph form for P (stays symmetric and positive)."""
    K = P @ H.T @ np.linalg.inv(S)
    x = x + K @ nu
    I_KH = np.eye(len(x)) - K @ H
    P = I_KH @ P @ I_KH.T + K @ R @ K.T
    return x, P


def mu_g(x, P, yacc, Ra, g0):
    """Task 6: the accelerometer update (eq. 7 with f = 0)."""
    nu, S, H = innovation(x, P, yacc, Ra, g0)
    return ekf_update(x, P, nu, S, H, Ra)


def mu_m(x, P, ymag, m0, Rm):
    """Task 9: the magnetometer update (eq. 8 with f = 0)."""
    nu, S, H = innovation(x, P, ymag, Rm, m0)
    return ekf_update(x, P, nu, S, H, Rm)


def mu_normalizeQ(x, P):
    """q / |q| with q0 >= 0, and P through the Jacobian of that map, J = (I - q q^T/|q|^2)/|q|
    (the part of P along q, which a unit quaternion cannot have, is removed)."""
    n = np.linalg.norm(x)
    J = (np.eye(4) - np.outer(x, x) / n**2) / n
    x = x / n
    if x[0] < 0:
        x, J = -x, -J
    P = J @ P @ J.T
    return x, (P + P.T) / 2


# ---- the filter ---------------------------------------------------------------------------

class Filter:
    """Model 4a with the task-8 and task-11 gates."""

    MAX_DT = 0.5        # s: a longer gap is a pause, not integrated
    GYR_HOLD = 0.1      # s: a gyroscope sample drives the time update at most this long
    NO_GYRO_STD = 1.0   # rad/sqrt(s): orientation random walk without a gyroscope sample
    START_STD = 0.05    # rad: initial attitude uncertainty

    def __init__(self, settings=None):
        s = settings or {}
        self.Rw = np.asarray(s.get("Rw", 1e-4 * np.eye(3)))
        self.Ra = np.asarray(s.get("Ra", 0.1 * np.eye(3)))
        self.Rm = np.asarray(s.get("Rm", 2.0 * np.eye(3)))
        self.g0 = np.asarray(s.get("g0", [0.0, 0.0, 9.81]))
        self.bias = np.asarray(s.get("gyr_bias", np.zeros(3)))
        self.m0 = None if s.get("m0") is None else np.asarray(s["m0"], float)
        self.acc_gate = s.get("acc_gate", 1.0)     # task 8: m/s^2 around g
        self.mag_gate = s.get("mag_gate", 5.0)     # task 11: uT around L
        self.alpha = s.get("mag_alpha", 0.01)      # task 11: AR(1) coefficient
        self.x = np.array([1.0, 0.0, 0.0, 0.0])
        self.P = np.eye(4)
        self.started = False
        self.heading_known = False
        self.t = None
        self.omega, self.omega_t = None, -math.inf
        self.acc, self.mag, self.mag_t = None, None, -math.inf
        self.L = None if self.m0 is None else np.linalg.norm(self.m0)
        self.acc_out = self.mag_out = False
        self.still_since, self.acc_smooth = None, None
        self.innovations = {}

    def step(self, t, gyr, acc, mag):
        self.innovations = {}
        self.time_update(t)
        if gyr is not None:
            self.omega, self.omega_t = gyr, t
            self.watch_rest(t, moving=np.linalg.norm(gyr - self.bias) > 0.05)
        if acc is not None:
            self.accelerometer(t, acc)
        if mag is not None:
            self.magnetometer(t, mag)
        return {"q": self.x, "P": self.P, "acc_disturbed": self.acc_out,
                "mag_disturbed": self.mag_out, "innovations": self.innovations,
                "standstill": self.still_since is not None and t - self.still_since >= 0.5}

    # -- task 5: the time update --------------------------------------------------------------
    def time_update(self, t):
        if self.t is None:
            self.t = t
            return
        if t <= self.t:
            return                      # the same time stamp: nothing to integrate
        T, t_prev, self.t = t - self.t, self.t, t
        if not self.started or T > self.MAX_DT:
            return
        if self.omega is not None and t_prev - self.omega_t <= self.GYR_HOLD:
            self.x, self.P = tu_qw(self.x, self.P, self.omega - self.bias, T, self.Rw)
        else:
            self.x, self.P = tu_q(self.x, self.P, T, self.NO_GYRO_STD)
        self.x, self.P = mu_normalizeQ(self.x, self.P)

    # -- tasks 7 and 8: the accelerometer and its outlier gate ----------------------------------
    def accelerometer(self, t, acc):
        self.acc = acc
        if self.acc_smooth is None:
            self.acc_smooth = acc
        self.acc_smooth = 0.9 * self.acc_smooth + 0.1 * acc
        self.watch_rest(t, moving=np.linalg.norm(acc - self.acc_smooth) > 0.3)
        if not self.started:
            self.start(t)
            return
        nu, S, H = innovation(self.x, self.P, acc, self.Ra, self.g0)
        self.acc_out = abs(np.linalg.norm(acc) - np.linalg.norm(self.g0)) > self.acc_gate
        self.innovations["acc"] = {"innovation": nu, "S": S, "accepted": not self.acc_out}
        if not self.acc_out:
            self.x, self.P = mu_g(self.x, self.P, acc, self.Ra, self.g0)
            self.x, self.P = mu_normalizeQ(self.x, self.P)

    # -- tasks 10 and 11: the magnetometer and its disturbance gate ----------------------------
    def magnetometer(self, t, mag):
        self.mag, self.mag_t = mag, t
        if not self.started:
            return                      # wait for the accelerometer (tilt first)
        if not self.heading_known:
            self.heading_from(mag)
            return
        strength = np.linalg.norm(mag)
        if self.L is None:
            self.L = strength
        self.mag_out = abs(strength - self.L) > self.mag_gate
        self.L = (1 - self.alpha) * self.L + self.alpha * strength
        nu, S, H = innovation(self.x, self.P, mag, self.Rm, self.m0)
        self.innovations["mag"] = {"innovation": nu, "S": S, "accepted": not self.mag_out}
        if not self.mag_out:
            self.x, self.P = mu_m(self.x, self.P, mag, self.m0, self.Rm)
            self.x, self.P = mu_normalizeQ(self.x, self.P)

    # -- the start: tilt from the accelerometer, heading from the magnetometer ----------------
    def start(self, t):
        up = self.acc / np.linalg.norm(self.acc)
        fresh_mag = self.mag is not None and t - self.mag_t <= 0.1
        if fresh_mag and np.linalg.norm(np.cross(self.mag, up)) > 1e-6 * np.linalg.norm(self.mag):
            east = np.cross(self.mag, up)
            east = east / np.linalg.norm(east)
            self.x = rotation_to_quat(np.vstack([east, np.cross(up, east), up]))
            self.heading_known = True
        else:
            ref = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0.0, 1, 0])
            north = np.cross(up, ref)
            north = north / np.linalg.norm(north)
            q = rotation_to_quat(np.vstack([np.cross(north, up), north, up]))
            self.x = turn_about_up(q, -2 * math.atan2(q[3], q[0]))
            self.x = self.x / np.linalg.norm(self.x)
            self.x = -self.x if self.x[0] < 0 else self.x
        G = Sq(self.x)
        self.P = self.START_STD**2 / 4 * (G @ G.T)
        if not self.heading_known:
            self.P = self.P + (G @ G.T) / 4      # heading unknown until a magnetometer reading
        self.started = True
        if self.heading_known and self.m0 is None:
            self.set_m0(self.mag)

    def heading_from(self, mag):
        m_world = Qq(self.x) @ mag
        if m_world[0]**2 + m_world[1]**2 < 1e-6:
            return
        ref = self.m0 if self.m0 is not None else np.array([0.0, 1.0, 0.0])
        psi = math.atan2(ref[0] * m_world[1] - ref[1] * m_world[0],
                         ref[0] * m_world[0] + ref[1] * m_world[1])
        x = turn_about_up(self.x, -psi)
        x = x / np.linalg.norm(x)
        self.x = -x if x[0] < 0 else x
        G = Sq(self.x)
        self.P = self.START_STD**2 / 4 * (G @ G.T)
        self.heading_known = True
        if self.m0 is None:
            self.set_m0(mag)

    def set_m0(self, mag):
        """Task 9: m0 = (0, sqrt(mx^2 + my^2), mz) of the reading in the (levelled) world."""
        m = Qq(self.x) @ mag
        self.m0 = np.array([0.0, math.hypot(m[0], m[1]), m[2]])
        self.L = np.linalg.norm(self.m0)

    def watch_rest(self, t, moving):
        """Standstill: neither the gyroscope nor the accelerometer moved for 0.5 s."""
        if moving or self.still_since is None:
            self.still_since = t


if __name__ == "__main__":
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    import ekf
    from ekf.simulate import simulate
    from app.engine.offline.filtering import run_offline
    from app.engine.userfilter.filter import UserFilterEstimator
    from app.stream.logfile import LogData
    from app.stream.protocol import Sample

    seconds = float(sys.argv[sys.argv.index("--seconds") + 1]) if "--seconds" in sys.argv else 30
    session = simulate(duration_s=seconds, seed=3)
    samples = LogData.from_samples(Sample(t, tag, values) for t, tag, values in session.iter_rows())
    mine = UserFilterEstimator(__file__, ekf.PRESETS["course"])
    yours = run_offline(samples, mine)
    ours = run_offline(samples, "course")
    truth = yours.has_sample & ~np.isnan(yours.phone_quat[:, 0])
    error = np.degrees(ekf.quaternion.angle_between(yours.quat[truth], yours.phone_quat[truth]))
    diff = np.degrees(ekf.quaternion.angle_between(yours.quat, ours.quat))
    print(f"{seconds:g} s simulated: this filter's RMSE against the truth "
          f"{math.sqrt(np.mean(error**2)):.2f} deg; largest difference to the built-in course "
          f"filter {diff.max():.2e} deg; {mine.seconds / max(mine.calls, 1) * 1e6:.0f} us per "
          f"step")
    if mine.problem is not None:
        print(mine.problem.message)
        sys.exit(1)
