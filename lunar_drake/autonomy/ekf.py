"""On-board pose estimator: an error-state extended Kalman filter (the flight software's
robot_localization analog). numpy, with the per-tick steps compiled
(:mod:`lunar_drake.autonomy.ekf_kernels`); no Drake.

Nominal state ``x`` (15,): position ``p_WB`` (m, site frame; z relative to the start),
attitude ``q_WB`` (w, x, y, z), gyro bias ``b_g`` (rad/s, body), the odometry slip
``s`` (-: the chassis moves ``1 - s`` times what the wheels say), the side slip
``beta`` (-: unmeasured sideways motion per metre forward) and the accelerometer bias
``b_a`` (m/s^2, body). Error state (14,): ``[dp (3), dtheta (3), db_g (3), ds, dbeta,
db_a (3)]`` with the attitude error a small rotation in the *world* frame,
``R_WB = Exp(dtheta) R_hat``. ``P`` (14, 14) is its covariance.

* **Predict** (each flight tick, :func:`predict`): the gyro turns the attitude,
  ``R' = R Exp((w_m - b_g) dt)``; the encoder displacement ``u_B = (dx, dy, 0)``
  (rover kinematics) moves the position, ``p' = p + R ((1 - s) u_B + beta dx e_y)``.
  Process noise: gyro angle random walk plus ``attitude_process_noise`` (unmodelled
  rotation between gyro samples: a chassis rocking on the soil), gyro-bias random walk,
  odometry noise proportional to the distance (``odometry_noise_fraction``; vertical
  ``odometry_vertical_fraction``) and slip and side-slip random walks per metre.
* **Star tracker** (:func:`update_attitude`): the measured attitude's error rotation
  ``Log(R_m R_hat^T)`` observes ``dtheta`` with the tracker's noise (cross-boresight and
  roll sigmas, rotated from the tracker frame into the world).
* **Accelerometer tilt** (:func:`update_tilt`): when the rover is quasi-static
  (specific force within ``tilt_gate_mps2`` of gravity and rates below
  ``tilt_gate_radps``) the specific force ``f = g R^T e_z + b_a`` observes roll, pitch
  and the accelerometer bias (not yaw; tilt and bias separate only with the tracker).

Neither position nor slip is observed on board: their covariance grows with the
distance driven. Joseph-form updates; the reset Jacobian is taken as identity (errors
are small).
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import itertools
import math

import numpy as np

from lunar_drake.autonomy import ekf_kernels as _k
from lunar_drake.errors import ConfigError, check_range

N_ERR = 14
_P, _TH, _BG, _S, _B, _BA = slice(0, 3), slice(3, 6), slice(6, 9), 9, 10, slice(11, 14)
NX = 15
_ARCSEC = math.pi / (180.0 * 3600.0)


@dc.dataclass
class EstimatorConfig:
    """What the filter assumes (datasheet figures of the sensors, and odometry errors).

    Attributes:
        rate_hz: filter rate (Hz); the IMU's rate, so every gyro sample is used.
        gyro_noise_density: gyro angle random walk (rad/sqrt(s)).
        attitude_process_noise: extra attitude random walk (rad/sqrt(s)) for rotation
            the sampled gyro misses (the chassis rocks within a sample period).
        gyro_bias_random_walk: (rad/s/sqrt(s)). gyro_bias_sigma0: initial (rad/s).
        star_tracker_cross_sigma_arcsec, star_tracker_roll_sigma_arcsec: tracker noise
            about its x/y and its boresight z (arcsec); boresight along body +z.
        use_star_tracker: fuse the tracker (False: attitude from the gyro alone, yaw
            drifts).
        use_tilt: fuse the accelerometer's specific force when quasi-static.
        tilt_every: fuse it every this many filter ticks (>= 1; vibration makes
            consecutive samples correlated, and each fusion costs a Kalman update).
        accel_sigma_mps2: its noise then (m/s^2): white noise plus the chassis'
            accelerations over bumps, which average out (0.05 m/s^2 with gates of 0.2
            m/s^2 and 0.1 rad/s kept the NEES consistent while driving).
        accel_bias_sigma0: initial accelerometer bias (m/s^2), accel_bias_random_walk:
            (m/s^2/sqrt(s)). tilt_gate_mps2,
            tilt_gate_radps: quasi-static gates (m/s^2 from gravity, rad/s).
        odometry_noise_fraction: white odometry noise per step, fraction of the step's
            length (horizontal, each axis). odometry_vertical_fraction: same, vertical.
        slip_prior, slip_sigma0: the odometry slip assumed at the start (e.g. from
            the slip study on this soil) and its sigma (-): how far a pre-flight
            calibration's level slip may be from the Moon's (the default 0.025: GRC-1's
            0.068 against the 0.092 the rover made on the default site; docs/design.md,
            "How sure the on-board estimate is").
        slip_vs_slope: optional ``[[slope_deg, slip], ...]`` (slopes increasing, 0
            among them): how slip changes when climbing (positive) or descending
            (negative) along the direction of travel, e.g. ``reference_slip`` from
            ``lunar-drake slip-study`` on this soil. The filter adds ``table(climb) -
            table(0)`` to its slip state (whose prior stays ``slip_prior``: the level
            slip on this terrain, roughness included); the climb comes from the
            estimated attitude; interpolated linearly, held at the ends.
        slip_calibration: the pre-flight slip calibration (a soil preset such as
            ``grc1`` or a soil YAML file): when given, ``slip_prior`` and
            ``slip_vs_slope`` come from it (:mod:`lunar_drake.autonomy.slip_calibration`;
            ``slip_vs_slope`` must then be empty); empty: use them as written.
        slip_random_walk_per_sqrt_m: slip random walk (1/sqrt(m) of driving).
        side_slip_sigma0, side_slip_random_walk_per_sqrt_m: the same for the side slip
            (prior mean 0).
        position_sigma0_m: initial position sigma (m). attitude_sigma0_rad: initial
            attitude sigma (rad) before the first tracker fix.
    """

    rate_hz: float = 100.0
    gyro_noise_density: float = 0.12 * math.pi / 180.0 / 60.0
    attitude_process_noise: float = 3e-4
    gyro_bias_random_walk: float = 1e-7
    gyro_bias_sigma0: float = 10.0 * math.pi / 180.0 / 3600.0
    star_tracker_cross_sigma_arcsec: float = 5.0
    star_tracker_roll_sigma_arcsec: float = 40.0
    use_star_tracker: bool = True
    use_tilt: bool = True
    tilt_every: int = 10
    accel_sigma_mps2: float = 0.05
    accel_bias_sigma0: float = 1e-3 * 9.80665
    accel_bias_random_walk: float = 8e-7
    tilt_gate_mps2: float = 0.2
    tilt_gate_radps: float = 0.1
    odometry_noise_fraction: float = 0.01
    odometry_vertical_fraction: float = 0.05
    slip_prior: float = 0.1
    slip_sigma0: float = 0.025
    slip_vs_slope: list[list[float]] = dc.field(default_factory=list)
    slip_calibration: str = ""
    slip_random_walk_per_sqrt_m: float = 0.002
    side_slip_sigma0: float = 0.015
    side_slip_random_walk_per_sqrt_m: float = 0.003
    position_sigma0_m: float = 0.05
    attitude_sigma0_rad: float = 0.05

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_range("rate_hz", self.rate_hz, 0.0, 10000.0, lo_open=True, unit=" Hz")
        for name in ("gyro_noise_density", "gyro_bias_random_walk", "gyro_bias_sigma0",
                     "attitude_process_noise"):  # fmt: skip
            check_range(name, getattr(self, name), 0.0, 1.0)
        for name in ("star_tracker_cross_sigma_arcsec", "star_tracker_roll_sigma_arcsec"):
            check_range(name, getattr(self, name), 0.0, 36000.0, lo_open=True, unit=" arcsec")
        check_range("tilt_every", self.tilt_every, 1, 10000)
        check_range("accel_sigma_mps2", self.accel_sigma_mps2, 0.0, 10.0, lo_open=True,
                    unit=" m/s^2")  # fmt: skip
        check_range("accel_bias_sigma0", self.accel_bias_sigma0, 0.0, 10.0, unit=" m/s^2")
        check_range("accel_bias_random_walk", self.accel_bias_random_walk, 0.0, 1.0)
        check_range("tilt_gate_mps2", self.tilt_gate_mps2, 0.0, 10.0, unit=" m/s^2")
        check_range("tilt_gate_radps", self.tilt_gate_radps, 0.0, 10.0, unit=" rad/s")
        check_range("odometry_noise_fraction", self.odometry_noise_fraction, 0.0, 1.0)
        check_range("odometry_vertical_fraction", self.odometry_vertical_fraction, 0.0, 1.0)
        check_range("slip_prior", self.slip_prior, -1.0, 1.0, hi_open=True)
        check_range("slip_sigma0", self.slip_sigma0, 0.0, 1.0)
        table = self.slip_vs_slope
        if table:
            if any(len(row) != 2 for row in table):
                raise ConfigError(f"slip_vs_slope = {table!r}: rows must be [slope_deg, slip]")
            deg = [float(r[0]) for r in table]
            if any(b <= a for a, b in itertools.pairwise(deg)) or 0.0 not in deg:
                raise ConfigError(f"slip_vs_slope slopes {deg!r} must increase and include 0")
            for k, (d, v) in enumerate(table):
                check_range(f"slip_vs_slope[{k}] slope", d, -60.0, 60.0, unit=" deg")
                check_range(f"slip_vs_slope[{k}] slip", v, -1.0, 1.0, hi_open=True)
        if self.slip_calibration and table:
            raise ConfigError(
                f"slip_calibration = {self.slip_calibration!r} and slip_vs_slope = {table!r} "
                "are both given; the calibration makes the table: give one of them"
            )
        check_range("slip_random_walk_per_sqrt_m", self.slip_random_walk_per_sqrt_m, 0.0, 1.0)
        check_range("side_slip_sigma0", self.side_slip_sigma0, 0.0, 1.0)
        check_range("side_slip_random_walk_per_sqrt_m", self.side_slip_random_walk_per_sqrt_m,
                    0.0, 1.0)  # fmt: skip
        check_range("position_sigma0_m", self.position_sigma0_m, 0.0, 1e4, lo_open=True)
        check_range("attitude_sigma0_rad", self.attitude_sigma0_rad, 0.0, 4.0, lo_open=True)


# ----------------------------------------------------------------------- rotations


def skew(v) -> np.ndarray:
    """[v]x, the cross-product matrix (3, 3)."""
    x, y, z = (float(c) for c in v)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def so3_exp(w) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (rad) (Rodrigues)."""
    w = np.asarray(w, dtype=float)
    th = math.sqrt(float(w @ w))
    K = skew(w)
    if th < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + (math.sin(th) / th) * K + ((1.0 - math.cos(th)) / (th * th)) * K @ K


def so3_log(R) -> np.ndarray:
    """Rotation vector (rad) of the rotation matrix ``R`` (angle < pi)."""
    R = np.asarray(R, dtype=float)
    c = max(-1.0, min(1.0, 0.5 * (np.trace(R) - 1.0)))
    th = math.acos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-8:
        return 0.5 * v
    return (th / (2.0 * math.sin(th))) * v


def quat_to_matrix(q) -> np.ndarray:
    w, x, y, z = (float(c) for c in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quat(R) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix."""
    R = np.asarray(R, dtype=float)
    t = np.trace(R)
    if t > 0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = np.array([0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s,
                      (R[1, 0] - R[0, 1]) / s])  # fmt: skip
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = np.empty(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


# --------------------------------------------------------------------------- filter


def initial_state(*, p0, q0, config: EstimatorConfig) -> tuple[np.ndarray, np.ndarray]:
    """(x (15,), P (14, 14)) at the start: position ``p0`` (m), attitude ``q0``."""
    x = np.zeros(NX)
    x[0:3] = p0
    x[3:7] = np.asarray(q0, float) / np.linalg.norm(q0)
    x[10] = config.slip_prior
    P = np.zeros((N_ERR, N_ERR))
    P[_P, _P] = np.eye(3) * config.position_sigma0_m**2
    P[_TH, _TH] = np.eye(3) * config.attitude_sigma0_rad**2
    P[_BG, _BG] = np.eye(3) * config.gyro_bias_sigma0**2
    P[_S, _S] = config.slip_sigma0**2
    P[_B, _B] = config.side_slip_sigma0**2
    P[_BA, _BA] = np.eye(3) * config.accel_bias_sigma0**2
    return x, P


def slope_slip(R_WB, dx: float, table) -> float:
    """The slip change ``table(climb) - table(0)`` ([[slope_deg, slip], ...]) for the
    climb along the direction of travel: the chassis x axis' elevation, signed by the
    direction of the step ``dx`` (m; backwards flips it)."""
    sin_climb = float(R_WB[2, 0]) * (1.0 if dx >= 0.0 else -1.0)
    climb_deg = math.degrees(math.asin(max(-1.0, min(1.0, sin_climb))))
    t = np.asarray(table, dtype=float)
    return float(np.interp(climb_deg, t[:, 0], t[:, 1]) - np.interp(0.0, t[:, 0], t[:, 1]))


def kernel_params(config: EstimatorConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The config as :func:`predict`'s compiled kernel reads it: the slip-vs-slope table's
    slopes (deg) and slips (empty without a table) and the noise parameters
    (:data:`~lunar_drake.autonomy.ekf_kernels.NOISE_FIELDS`). Compute once per filter."""
    t = np.asarray(config.slip_vs_slope, dtype=np.float64).reshape(-1, 2)
    noise = np.array([float(getattr(config, f)) for f in _k.NOISE_FIELDS])
    return np.ascontiguousarray(t[:, 0]), np.ascontiguousarray(t[:, 1]), noise


def predict(x, P, *, gyro_radps, d_body, dt: float, config: EstimatorConfig, params=None):
    """(x, P) after one tick: gyro rate (3,) (rad/s, body), encoder displacement
    ``d_body`` = (dx, dy) (m, body frame) over the tick, ``dt`` (s). ``params``:
    :func:`kernel_params` of ``config`` (computed when not given).

    The model (module docstring): ``s' = clip(s + table(climb) - table(0))`` when a
    slip-vs-slope table is given, ``p' = p + (1 - s') R u + beta dx R e_y``,
    ``R' = R Exp((w_m - b_g) dt)``, ``P' = F P F^T + Q`` with ``F = I`` plus
    ``dp/dtheta = -[move]x``, ``dp/ds = -R u``, ``dp/dbeta = dx R e_y``,
    ``dtheta/db_g = -R dt``; computed by the compiled
    :func:`lunar_drake.autonomy.ekf_kernels.predict` in one call."""
    table_deg, table_slip, noise = kernel_params(config) if params is None else params
    return _k.predict(np.asarray(x, np.float64), np.asarray(P, np.float64),
                      np.asarray(gyro_radps, np.float64), float(d_body[0]), float(d_body[1]),
                      float(dt), table_deg, table_slip, noise)  # fmt: skip


def _update(x, P, r, H, Rn):
    """Joseph-form Kalman update and reset (compiled:
    :func:`lunar_drake.autonomy.ekf_kernels.update`)."""
    xn, Pn, nis = _k.update(np.asarray(x, np.float64), np.asarray(P, np.float64),
                            np.asarray(r, np.float64), np.asarray(H, np.float64),
                            np.asarray(Rn, np.float64))  # fmt: skip
    return xn, Pn, float(nis)


def update_attitude(x, P, *, q_measured, config: EstimatorConfig, R_BS=None):
    """(x, P, NIS) after a star-tracker fix ``q_measured`` (body attitude, w x y z)."""
    R_hat = quat_to_matrix(x[3:7])
    Rm = quat_to_matrix(q_measured)
    r = so3_log(Rm @ R_hat.T)
    R_WS = R_hat @ (np.eye(3) if R_BS is None else np.asarray(R_BS, float))
    sig = np.array([config.star_tracker_cross_sigma_arcsec] * 2
                   + [config.star_tracker_roll_sigma_arcsec]) * _ARCSEC  # fmt: skip
    Rn = R_WS @ np.diag(sig**2) @ R_WS.T
    H = np.zeros((3, N_ERR))
    H[:, _TH] = np.eye(3)
    return _update(x, P, r, H, Rn)


def update_tilt(x, P, *, accel_mps2, gyro_radps, gravity_mps2: float, config: EstimatorConfig):
    """(x, P, NIS or None): the accelerometer's specific force when the rover is
    quasi-static (else unchanged, None): ``f = g R^T e_z + b_a + noise``. Observes roll,
    pitch and the accelerometer bias."""
    f = np.asarray(accel_mps2, float)
    nf = float(np.linalg.norm(f))
    bg = x[7:10]
    if (
        abs(nf - gravity_mps2) > config.tilt_gate_mps2
        or np.linalg.norm(np.asarray(gyro_radps, float) - bg) > config.tilt_gate_radps
    ):
        return x, P, None
    R_hat = quat_to_matrix(x[3:7])
    ez = np.array([0.0, 0.0, 1.0])
    r = f - (gravity_mps2 * (R_hat.T @ ez) + x[12:15])
    H = np.zeros((3, N_ERR))
    H[:, _TH] = gravity_mps2 * (R_hat.T @ skew(ez))
    H[:, _BA] = np.eye(3)
    Rn = np.eye(3) * config.accel_sigma_mps2**2
    return _update(x, P, r, H, Rn)


def pose_and_covariance(x, P) -> tuple[np.ndarray, np.ndarray]:
    """(pose (6,) = x, y, z, roll, pitch, yaw; covariance (6, 6) of [dp, dtheta] with
    dtheta the world-frame attitude error)."""
    R = quat_to_matrix(x[3:7])
    roll = math.atan2(R[2, 1], R[2, 2])
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    yaw = math.atan2(R[1, 0], R[0, 0])
    return np.array([x[0], x[1], x[2], roll, pitch, yaw]), P[:6, :6].copy()


def pose_error(*, p_true, R_true, x) -> np.ndarray:
    """[p_true - p_hat, Log(R_true R_hat^T)] (6,): the error in the filter's convention."""
    R_hat = quat_to_matrix(x[3:7])
    return np.concatenate(
        [np.asarray(p_true, float) - x[0:3], so3_log(np.asarray(R_true) @ R_hat.T)]
    )


__all__ = [
    "NX",
    "N_ERR",
    "EstimatorConfig",
    "initial_state",
    "kernel_params",
    "matrix_to_quat",
    "pose_and_covariance",
    "pose_error",
    "predict",
    "quat_to_matrix",
    "so3_exp",
    "so3_log",
    "update_attitude",
    "update_tilt",
]
