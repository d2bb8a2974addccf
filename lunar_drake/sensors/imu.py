"""6-axis IMU (gyro + accelerometer): ideal reading, bias and white noise (paper section 7).

Frames: W the site frame (treated as inertial), B the body, S the sensor frame fixed in
B (``X_BS``). Each sample draws 12 standard normals from its generator: 6 of white
noise (gyro x, y, z, accel x, y, z) and 6 bias random-walk steps applied after it.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numba
import numpy as np

from lunar_drake.errors import check_range
from lunar_drake.moon import GRAVITY_W
from lunar_drake.sensors.sampling import check_sampling

_DEG = math.pi / 180.0
_G0 = 9.80665  # standard gravity, m/s^2 (for "mg" and "ug" figures)


@dc.dataclass
class ImuConfig:
    """Rate, delay and noise model of a 6-axis IMU, per axis, 1 sigma.

    Default: a tactical-grade MEMS IMU, the Analog Devices ADIS16495 (datasheet figures
    from memory): gyro angle random walk 0.12 deg/sqrt(h), in-run bias stability
    0.8 deg/h; accelerometer velocity random walk 0.008 m/s/sqrt(h), in-run bias
    stability 3.2 ug. Datasheets give bias *instability* (a flicker floor), not a random
    walk; the bias random walks below are chosen so the walk reaches the bias-stability
    figure after ~25 min (sigma = q sqrt(t)), an approximation. Initial (turn-on, after
    calibration) biases follow tactical-grade figures of ~10 deg/h and ~1 mg (e.g.
    Honeywell HG1700 class, from memory).

    Attributes:
        rate_hz: sample rate (Hz). delay_s: delivery delay of each sample (s).
        gyro_noise_density: white rate noise (rad/s/sqrt(Hz)) = angle random walk
            (rad/sqrt(s)). Default 0.12 deg/sqrt(h) = 3.49e-5.
        gyro_bias_random_walk: rate of the gyro bias random walk (rad/s/sqrt(s)).
        gyro_bias_initial_sigma: initial gyro bias (rad/s). Default 10 deg/h = 4.85e-5.
        accel_noise_density: white specific-force noise (m/s^2/sqrt(Hz)) = velocity
            random walk (m/s/sqrt(s)). Default 0.008 m/s/sqrt(h) = 1.33e-4.
        accel_bias_random_walk: rate of the accelerometer bias random walk
            (m/s^2/sqrt(s)).
        accel_bias_initial_sigma: initial accelerometer bias (m/s^2). Default 1 mg.

    The per-sample white-noise sigma is ``density * sqrt(rate_hz)``; the bias steps by
    ``random_walk * sqrt(1 / rate_hz)`` each sample.
    """

    rate_hz: float = 100.0
    delay_s: float = 0.0
    gyro_noise_density: float = 0.12 * _DEG / 60.0
    gyro_bias_random_walk: float = 1e-7
    gyro_bias_initial_sigma: float = 10.0 * _DEG / 3600.0
    accel_noise_density: float = 0.008 / 60.0
    accel_bias_random_walk: float = 8e-7
    accel_bias_initial_sigma: float = 1e-3 * _G0

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_sampling(self.rate_hz, self.delay_s)
        for name, unit in (
            ("gyro_noise_density", " rad/s/sqrt(Hz)"),
            ("gyro_bias_random_walk", " rad/s/sqrt(s)"),
            ("gyro_bias_initial_sigma", " rad/s"),
            ("accel_noise_density", " m/s^2/sqrt(Hz)"),
            ("accel_bias_random_walk", " m/s^2/sqrt(s)"),
            ("accel_bias_initial_sigma", " m/s^2"),
        ):
            check_range(name, getattr(self, name), 0.0, 1.0, unit=unit)

    @property
    def white_sigma(self) -> np.ndarray:
        """Per-sample white-noise sigma (6,): gyro (rad/s) x3, accel (m/s^2) x3."""
        s = math.sqrt(self.rate_hz)
        return np.repeat([self.gyro_noise_density * s, self.accel_noise_density * s], 3)

    @property
    def bias_step_sigma(self) -> np.ndarray:
        """Sigma (6,) of the bias random-walk step per sample."""
        s = math.sqrt(1.0 / self.rate_hz)
        return np.repeat([self.gyro_bias_random_walk * s, self.accel_bias_random_walk * s], 3)

    @property
    def bias_initial_sigma(self) -> np.ndarray:
        """Sigma (6,) of the initial bias."""
        return np.repeat([self.gyro_bias_initial_sigma, self.accel_bias_initial_sigma], 3)


def imu_initial_bias(generator: np.random.Generator, *, config: ImuConfig) -> np.ndarray:
    """Bias (6,) at the first sample: gyro (rad/s), accel (m/s^2)."""
    return generator.standard_normal(6) * config.bias_initial_sigma


def imu_ideal(
    *,
    R_WB: np.ndarray,
    w_WB_W: np.ndarray,
    alpha_WB_W: np.ndarray,
    a_WBo_W: np.ndarray,
    R_BS: np.ndarray | None = None,
    p_BS: np.ndarray | None = None,
    gravity_W=GRAVITY_W,
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
            by default (the Moon turns at 2.66e-6 rad/s, ``moon.ROTATION_RATE_RAD_S``).

    The accelerometer measures specific force ``f = a_WS - g`` of the sensor point
    ``So = Bo + R_WB p_BS`` (a_WS = a_WBo + alpha x r + w x (w x r)); at rest on level
    ground it reads ``+|g|`` along up. The mission's IMU takes this reading from Drake's
    ``Gyroscope`` and ``Accelerometer`` (:func:`lunar_drake.systems.imu.add_imu`); a
    test holds the two to 1e-12.
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
    ideal: np.ndarray, bias: np.ndarray, generator: np.random.Generator, *, config: ImuConfig
) -> tuple[np.ndarray, np.ndarray]:
    """One IMU sample: ``(ideal + bias + white noise, next bias)``, both (6,).

    Draws 12 normals from ``generator``: white noise first, then the bias step.
    """
    ideal = np.asarray(ideal, dtype=np.float64)
    return noisy_reading(ideal[:3], ideal[3:], np.asarray(bias, dtype=np.float64),
                         generator.standard_normal(12), config.white_sigma,
                         config.bias_step_sigma)  # fmt: skip


@numba.njit(cache=True)
def noisy_reading(gyro, accel, bias, z, white_sigma, bias_step_sigma):  # pragma: no cover
    """``(ideal + bias + z[:6] white_sigma, bias + z[6:] bias_step_sigma)``, (6,) each:
    the ideal reading ``(gyro, accel)`` (3,) each, the bias (6,) and 12 standard normals
    ``z`` (white noise first, then the bias step); sigmas (6,) per sample."""
    meas = np.empty(6)
    next_bias = np.empty(6)
    for i in range(6):
        ideal = gyro[i] if i < 3 else accel[i - 3]
        meas[i] = (ideal + bias[i]) + z[i] * white_sigma[i]
        next_bias[i] = bias[i] + z[6 + i] * bias_step_sigma[i]
    return meas, next_bias
