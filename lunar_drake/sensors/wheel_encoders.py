"""Incremental wheel encoders: quantized wheel angles (wheel odometry input, paper section 7)."""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.errors import OutOfRangeError, check_range
from lunar_drake.sensors.sampling import check_sampling


@dc.dataclass
class WheelEncoderConfig:
    """Rate, delay, resolution and noise of the wheel encoders.

    Attributes:
        rate_hz: read-out rate (Hz). delay_s: delivery delay (s).
        counts_per_revolution: counts per wheel revolution after gearing (> 0). Default
            4096 (e.g. a 1024-line quadrature encoder x4 decoding on the wheel shaft,
            or a motor encoder times the gear ratio).
        angle_noise_sigma_rad: white noise (rad) added to the angle before quantization
            (e.g. shaft wind-up, backlash). Default 0: quantization only.
    """

    rate_hz: float = 20.0
    delay_s: float = 0.0
    counts_per_revolution: int = 4096
    angle_noise_sigma_rad: float = 0.0

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_sampling(self.rate_hz, self.delay_s)
        n = self.counts_per_revolution
        if isinstance(n, bool) or int(n) != n or not 0 < n <= 2**24:
            raise OutOfRangeError(
                f"counts_per_revolution = {n!r} is out of range; allowed integers in [1, 16777216]"
            )
        check_range("angle_noise_sigma_rad", self.angle_noise_sigma_rad, 0.0, 1.0, unit=" rad")

    @property
    def resolution_rad(self) -> float:
        """Angle of one count (rad)."""
        return 2.0 * math.pi / self.counts_per_revolution


def encoder_angles(
    angles, *, config: WheelEncoderConfig, generator: np.random.Generator | None = None
) -> np.ndarray:
    """Measured wheel angles (rad): the nearest count to the true angle (plus, with
    ``angle_noise_sigma_rad > 0``, white noise drawn from ``generator`` before
    quantization), times the count angle.

    Rounding to the nearest count makes the error uniform in +-resolution/2 (zero
    mean); a real incremental encoder truncates, which only adds a constant half count
    that cancels in odometry differences.
    """
    a = np.asarray(angles, dtype=np.float64)
    if config.angle_noise_sigma_rad > 0:
        if generator is None:
            raise ValueError("encoder_angles: angle_noise_sigma_rad > 0 needs a generator")
        a = a + generator.standard_normal(a.shape) * config.angle_noise_sigma_rad
    return np.rint(a / config.resolution_rad) * config.resolution_rad
