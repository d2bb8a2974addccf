"""Localization sensor models: IMU, star tracker, wheel encoders (numpy, no Drake).

Paper section 7, "Localization": "the pose estimation solution which integrated wheel
odometry, a star tracker, and the IMU". These are the measurement cores; the Drake
systems in ``lunar_drake/systems/{imu,star_tracker,wheel_encoders}.py`` sample them
periodically.

Randomness is counter based (:mod:`lunar_drake.rng`): the noise of sample ``k`` on
channel ``j`` is ``hash_normal(key, k, j)`` with ``key = stream_key(seed, name)``, so a
measurement depends only on (seed, name, sample index, truth) and a system holds no
random-generator state. ``hash_normal`` is an Irwin-Hall sum of four uniforms: unit
variance, but its tails stop at +-3.46 sigma (fine for sensor noise; do not use these
streams to study rare outliers).

Frames: W the world/site frame (x east, y north, z up), B a body, S the sensor frame
fixed in B (pose ``X_BS``). Units: SI (m, s, rad) unless a name says otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.rng import hash_normal

__all__ = [
    "LUNAR_GRAVITY_M_S2",
    "LUNAR_GRAVITY_W",
    "MOON_ROTATION_RATE_RAD_S",
    "ImuConfig",
    "StarTrackerConfig",
    "WheelEncoderConfig",
    "encoder_angles",
    "encoder_counts",
    "imu_bias_increment",
    "imu_ideal",
    "imu_initial_bias",
    "imu_measurement",
    "imu_white_noise",
    "quaternion_from_rotation_matrix",
    "rotation_exp",
    "rotation_log",
    "rotation_matrix_from_quaternion",
    "sample_index",
    "star_tracker_error_angles",
    "star_tracker_measurement",
]

#: Mean lunar surface gravity (m/s^2); NASA GSFC Moon Fact Sheet: 1.62 m/s^2.
LUNAR_GRAVITY_M_S2 = 1.62
#: Gravity in the site frame W (z up), m/s^2.
LUNAR_GRAVITY_W = (0.0, 0.0, -LUNAR_GRAVITY_M_S2)
#: Sidereal rotation rate of the Moon (rad/s): 2 pi / 27.321661 d (Moon Fact Sheet).
MOON_ROTATION_RATE_RAD_S = 2.0 * math.pi / (27.321661 * 86400.0)

_DEG = math.pi / 180.0
_ARCSEC = _DEG / 3600.0
_G0 = 9.80665  # standard gravity, m/s^2 (for "mg" and "ug" figures)

# IMU noise channels (second hash index): white noise 0-5, bias steps 6-11,
# initial bias 12-17; each block ordered gyro x, y, z, accel x, y, z.
_CH_WHITE = np.arange(0, 6)
_CH_BIAS_STEP = np.arange(6, 12)
_CH_BIAS_INIT = np.arange(12, 18)


def _positive(name: str, value: float, unit: str, *, allow_zero: bool = False) -> None:
    ok = value >= 0 if allow_zero else value > 0
    if not (ok and math.isfinite(value)):
        bound = ">= 0" if allow_zero else "> 0"
        raise OutOfRangeError(f"{name} = {value!r} {unit}; must be finite and {bound}")


def sample_index(time_s: float, rate_hz: float) -> int:
    """Index k of the periodic sample at ``time_s`` (samples at t = k / rate_hz).

    Must lie in [0, 2**31) (the hash counter range): 248 days at 100 Hz.
    """
    k = round(time_s * rate_hz)
    if not 0 <= k < 2**31:
        raise OutOfRangeError(f"sample index {k} at t = {time_s!r} s; must be in [0, 2**31)")
    return int(k)


# ------------------------------------------------------------------------------------- IMU


@dataclass(frozen=True)
class ImuConfig:
    """Noise model of a 6-axis IMU (gyro + accelerometer), per axis, 1 sigma.

    Default: a tactical-grade MEMS IMU, the Analog Devices ADIS16495 (datasheet figures
    from memory): gyro angle random walk 0.12 deg/sqrt(h), in-run bias stability
    0.8 deg/h; accelerometer velocity random walk 0.008 m/s/sqrt(h), in-run bias
    stability 3.2 ug. Datasheets give bias *instability* (a flicker floor), not a random
    walk; the bias random walks below are chosen so the walk reaches the bias-stability
    figure after ~25 min (sigma = q sqrt(t)), an approximation. Initial (turn-on, after
    calibration) biases follow tactical-grade figures of ~10 deg/h and ~1 mg (e.g.
    Honeywell HG1700 class, from memory).

    Attributes:
        sample_rate_hz: output rate (Hz). Default 100.
        gyro_noise_density: white rate noise (rad/s/sqrt(Hz)) = angle random walk
            (rad/sqrt(s)). Default 0.12 deg/sqrt(h) = 3.49e-5.
        gyro_bias_random_walk: rate of the gyro bias random walk (rad/s/sqrt(s)).
            Default 1e-7 (~1.2 deg/h/sqrt(h)).
        gyro_bias_initial_sigma: initial gyro bias (rad/s). Default 10 deg/h = 4.85e-5.
        accel_noise_density: white specific-force noise (m/s^2/sqrt(Hz)) = velocity
            random walk (m/s/sqrt(s)). Default 0.008 m/s/sqrt(h) = 1.33e-4.
        accel_bias_random_walk: rate of the accelerometer bias random walk
            (m/s^2/sqrt(s)). Default 8e-7.
        accel_bias_initial_sigma: initial accelerometer bias (m/s^2). Default 1 mg.

    The per-sample white-noise sigma is ``density * sqrt(sample_rate_hz)``; the bias
    steps by ``random_walk * sqrt(1 / sample_rate_hz)`` each sample.
    """

    sample_rate_hz: float = 100.0
    gyro_noise_density: float = 0.12 * _DEG / 60.0
    gyro_bias_random_walk: float = 1e-7
    gyro_bias_initial_sigma: float = 10.0 * _DEG / 3600.0
    accel_noise_density: float = 0.008 / 60.0
    accel_bias_random_walk: float = 8e-7
    accel_bias_initial_sigma: float = 1e-3 * _G0

    def __post_init__(self):
        _positive("sample_rate_hz", self.sample_rate_hz, "Hz")
        for name, unit in (
            ("gyro_noise_density", "rad/s/sqrt(Hz)"),
            ("gyro_bias_random_walk", "rad/s/sqrt(s)"),
            ("gyro_bias_initial_sigma", "rad/s"),
            ("accel_noise_density", "m/s^2/sqrt(Hz)"),
            ("accel_bias_random_walk", "m/s^2/sqrt(s)"),
            ("accel_bias_initial_sigma", "m/s^2"),
        ):
            _positive(name, getattr(self, name), unit, allow_zero=True)

    @property
    def white_sigma(self) -> np.ndarray:
        """Per-sample white-noise sigma (6,): gyro (rad/s) x3, accel (m/s^2) x3."""
        s = math.sqrt(self.sample_rate_hz)
        return np.repeat([self.gyro_noise_density * s, self.accel_noise_density * s], 3)

    @property
    def bias_step_sigma(self) -> np.ndarray:
        """Sigma (6,) of the bias random-walk step per sample."""
        s = math.sqrt(1.0 / self.sample_rate_hz)
        return np.repeat([self.gyro_bias_random_walk * s, self.accel_bias_random_walk * s], 3)

    @property
    def bias_initial_sigma(self) -> np.ndarray:
        """Sigma (6,) of the initial bias."""
        return np.repeat([self.gyro_bias_initial_sigma, self.accel_bias_initial_sigma], 3)


def _noise(key: int, step, channels: np.ndarray) -> np.ndarray:
    k = np.asarray(step, dtype=np.int64)[..., None]
    return hash_normal(key, k, channels, dtype=np.float64)


def imu_white_noise(key: int, step, *, config: ImuConfig) -> np.ndarray:
    """White measurement noise (..., 6) of sample(s) ``step``: gyro (rad/s), accel (m/s^2)."""
    return _noise(key, step, _CH_WHITE) * config.white_sigma


def imu_bias_increment(key: int, step, *, config: ImuConfig) -> np.ndarray:
    """Bias random-walk step (..., 6) applied after sample(s) ``step``."""
    return _noise(key, step, _CH_BIAS_STEP) * config.bias_step_sigma


def imu_initial_bias(key: int, *, config: ImuConfig) -> np.ndarray:
    """Bias (6,) at sample 0: gyro (rad/s), accel (m/s^2)."""
    return _noise(key, 0, _CH_BIAS_INIT) * config.bias_initial_sigma


def imu_ideal(
    *,
    R_WB: np.ndarray,
    w_WB_W: np.ndarray,
    alpha_WB_W: np.ndarray,
    a_WBo_W: np.ndarray,
    R_BS: np.ndarray | None = None,
    p_BS: np.ndarray | None = None,
    gravity_W=LUNAR_GRAVITY_W,
    w_planet_W=(0.0, 0.0, 0.0),
) -> np.ndarray:
    """Noise-free IMU reading (6,) = [angular rate (rad/s), specific force (m/s^2)] in S.

    Args:
        R_WB: body orientation (3, 3).
        w_WB_W, alpha_WB_W: body angular velocity (rad/s) and acceleration (rad/s^2) in W.
        a_WBo_W: translational acceleration of B's origin in W (m/s^2).
        R_BS, p_BS: sensor orientation and position (m) in B; default identity, zero.
        gravity_W: gravitational acceleration in W (m/s^2); default lunar.
        w_planet_W: rotation of W relative to inertial space (rad/s), added to the
            gyro reading; the simulated site frame is treated as inertial, so this is 0
            by default (the Moon turns at 2.66e-6 rad/s, :data:`MOON_ROTATION_RATE_RAD_S`).

    The accelerometer measures specific force ``f = a_WS - g`` of the sensor point
    ``So = Bo + R_WB p_BS`` (a_WS = a_WBo + alpha x r + w x (w x r)); at rest on level
    ground it reads ``+|g|`` along up.
    """
    R_WB = np.asarray(R_WB, dtype=np.float64)
    R_BS = np.eye(3) if R_BS is None else np.asarray(R_BS, dtype=np.float64)
    R_WS = R_WB @ R_BS
    w = np.asarray(w_WB_W, dtype=np.float64)
    a = np.asarray(a_WBo_W, dtype=np.float64)
    if p_BS is not None:
        r = R_WB @ np.asarray(p_BS, dtype=np.float64)
        a = a + np.cross(np.asarray(alpha_WB_W, dtype=np.float64), r) + np.cross(w, np.cross(w, r))
    gyro = R_WS.T @ (w + np.asarray(w_planet_W, dtype=np.float64))
    accel = R_WS.T @ (a - np.asarray(gravity_W, dtype=np.float64))
    return np.concatenate([gyro, accel])


def imu_measurement(
    ideal: np.ndarray, bias: np.ndarray, key: int, step: int, *, config: ImuConfig
) -> tuple[np.ndarray, np.ndarray]:
    """One IMU sample: ``(ideal + bias + white noise, next bias)``, both (6,)."""
    meas = np.asarray(ideal, dtype=np.float64) + bias + imu_white_noise(key, step, config=config)
    return meas, bias + imu_bias_increment(key, step, config=config)


# --------------------------------------------------------------------------- rotations


def rotation_exp(theta) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors ``theta`` (..., 3) (rad), Rodrigues."""
    t = np.asarray(theta, dtype=np.float64)
    ang = np.linalg.norm(t, axis=-1)[..., None, None]
    k = np.zeros((*t.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -t[..., 2], t[..., 1], -t[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = t[..., 2], -t[..., 1], t[..., 0]
    small = ang < 1e-6
    safe = np.where(small, 1.0, ang)
    a = np.where(small, 1.0 - ang**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - ang**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def rotation_log(R) -> np.ndarray:
    """Rotation vectors (..., 3) (rad) of rotation matrices (..., 3, 3), angle in [0, pi)."""
    q = quaternion_from_rotation_matrix(R)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    ang = 2.0 * np.arctan2(s, q[..., 0])
    scale = np.where(s < 1e-12, 2.0, ang / np.where(s < 1e-12, 1.0, s))
    return v * scale[..., None]


def quaternion_from_rotation_matrix(R) -> np.ndarray:
    """Unit quaternions (..., 4) = (w, x, y, z) with w >= 0 of rotation matrices (..., 3, 3).

    Shepperd's method (largest-diagonal branch), then normalised.
    """
    R = np.asarray(R, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack([tr, m00, m11, m22], axis=-1)
    pick = np.argmax(cand, axis=-1)
    q = np.empty((*R.shape[:-2], 4))
    d21, d02, d10 = (
        R[..., 2, 1] - R[..., 1, 2],
        R[..., 0, 2] - R[..., 2, 0],
        R[..., 1, 0] - R[..., 0, 1],
    )
    s21, s02, s10 = (
        R[..., 2, 1] + R[..., 1, 2],
        R[..., 0, 2] + R[..., 2, 0],
        R[..., 1, 0] + R[..., 0, 1],
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        for branch in range(4):
            if branch == 0:
                r = np.sqrt(np.maximum(1.0 + tr, 0.0))
                qq = np.stack([0.5 * r, 0.5 * d21 / r, 0.5 * d02 / r, 0.5 * d10 / r], -1)
            elif branch == 1:
                r = np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 0.0))
                qq = np.stack([0.5 * d21 / r, 0.5 * r, 0.5 * s10 / r, 0.5 * s02 / r], -1)
            elif branch == 2:
                r = np.sqrt(np.maximum(1.0 - m00 + m11 - m22, 0.0))
                qq = np.stack([0.5 * d02 / r, 0.5 * s10 / r, 0.5 * r, 0.5 * s21 / r], -1)
            else:
                r = np.sqrt(np.maximum(1.0 - m00 - m11 + m22, 0.0))
                qq = np.stack([0.5 * d10 / r, 0.5 * s02 / r, 0.5 * s21 / r, 0.5 * r], -1)
            sel = pick == branch
            q[sel] = qq[sel]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def rotation_matrix_from_quaternion(q) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) = (w, x, y, z) (normalised)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


# ---------------------------------------------------------------------------- star tracker


@dataclass(frozen=True)
class StarTrackerConfig:
    """Star tracker attitude noise, 1 sigma, in the sensor frame S (boresight = +z_S).

    Default: a small-satellite star tracker, e.g. Blue Canyon NST (~6 arcsec
    cross-boresight, ~40 arcsec about the boresight, 1 sigma; from memory). Roll about
    the boresight is several times worse than the cross-boresight axes because star
    separations subtend the small field of view (Liebe 2002, IEEE AES Magazine 17(1)).

    Attributes:
        sample_rate_hz: attitude solution rate (Hz). Default 2.
        cross_boresight_sigma_arcsec: noise about x_S and y_S (arcsec). Default 5.
        roll_sigma_arcsec: noise about the boresight z_S (arcsec). Default 40.

    Noise is white (independent per sample); slowly varying errors (thermal
    misalignment, field-of-view errors) are not modelled.
    """

    sample_rate_hz: float = 2.0
    cross_boresight_sigma_arcsec: float = 5.0
    roll_sigma_arcsec: float = 40.0

    def __post_init__(self):
        _positive("sample_rate_hz", self.sample_rate_hz, "Hz")
        _positive(
            "cross_boresight_sigma_arcsec",
            self.cross_boresight_sigma_arcsec,
            "arcsec",
            allow_zero=True,
        )
        _positive("roll_sigma_arcsec", self.roll_sigma_arcsec, "arcsec", allow_zero=True)

    @property
    def sigma_rad(self) -> np.ndarray:
        """Sigma (3,) of the error rotation vector about x_S, y_S, z_S (rad)."""
        cb, roll = self.cross_boresight_sigma_arcsec, self.roll_sigma_arcsec
        return np.array([cb, cb, roll]) * _ARCSEC


def star_tracker_error_angles(key: int, step, *, config: StarTrackerConfig) -> np.ndarray:
    """Error rotation vectors (..., 3) (rad) in S of sample(s) ``step``."""
    return _noise(key, step, np.arange(3)) * config.sigma_rad


def star_tracker_measurement(
    R_WB: np.ndarray, key: int, step, *, config: StarTrackerConfig, R_BS=None
) -> np.ndarray:
    """Measured body attitude as quaternion(s) (..., 4) = (w, x, y, z), w >= 0.

    ``step`` is a sample index or an array of them (``R_WB`` (3, 3) or (..., 3, 3)
    broadcast against it).

    ``R_WS_meas = R_WS Exp(theta_S)`` with ``theta_S`` from
    :func:`star_tracker_error_angles`; reported as ``R_WB_meas = R_WS_meas R_SB``
    (the tracker's alignment ``R_BS`` is assumed known exactly).
    """
    R_WB = np.asarray(R_WB, dtype=np.float64)
    R_BS = np.eye(3) if R_BS is None else np.asarray(R_BS, dtype=np.float64)
    err = rotation_exp(star_tracker_error_angles(key, step, config=config))
    R_meas = R_WB @ R_BS @ err @ R_BS.T
    return quaternion_from_rotation_matrix(R_meas)


# ---------------------------------------------------------------------------- encoders


@dataclass(frozen=True)
class WheelEncoderConfig:
    """Incremental wheel encoders.

    Attributes:
        counts_per_revolution: counts per wheel revolution after gearing (> 0). Default
            4096 (e.g. a 1024-line quadrature encoder x4 decoding on the wheel shaft,
            or a motor encoder times the gear ratio).
        sample_rate_hz: read-out rate (Hz). Default 20.
        angle_noise_sigma_rad: optional white noise (rad) added to the angle before
            quantization (e.g. shaft wind-up, backlash). Default 0: quantization only.
    """

    counts_per_revolution: int = 4096
    sample_rate_hz: float = 20.0
    angle_noise_sigma_rad: float = 0.0

    def __post_init__(self):
        if int(self.counts_per_revolution) != self.counts_per_revolution or not (
            self.counts_per_revolution > 0
        ):
            raise OutOfRangeError(
                f"counts_per_revolution = {self.counts_per_revolution!r}; must be an integer > 0"
            )
        _positive("sample_rate_hz", self.sample_rate_hz, "Hz")
        _positive("angle_noise_sigma_rad", self.angle_noise_sigma_rad, "rad", allow_zero=True)

    @property
    def resolution_rad(self) -> float:
        """Angle of one count (rad)."""
        return 2.0 * math.pi / self.counts_per_revolution


def encoder_counts(
    angles, *, config: WheelEncoderConfig, key: int | None = None, step=0
) -> np.ndarray:
    """Counts (float array of integers) for wheel angles (rad), nearest count.

    Rounding to the nearest count makes the error uniform in +-resolution/2 (zero
    mean); a real incremental encoder truncates, which only adds a constant half count
    that cancels in odometry differences. With ``angle_noise_sigma_rad > 0`` a ``key``
    is required; the noise of wheel i at sample ``step`` is keyed (key, step, i).
    """
    a = np.asarray(angles, dtype=np.float64)
    if config.angle_noise_sigma_rad > 0:
        if key is None:
            raise ConfigError("encoder_counts: angle_noise_sigma_rad > 0 needs a stream key")
        a = a + _noise(key, step, np.arange(a.shape[-1])) * config.angle_noise_sigma_rad
    return np.rint(a / config.resolution_rad)


def encoder_angles(counts, *, config: WheelEncoderConfig) -> np.ndarray:
    """Angles (rad) of encoder counts."""
    return np.asarray(counts, dtype=np.float64) * config.resolution_rad
