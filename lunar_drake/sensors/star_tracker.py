"""Star tracker: noisy absolute attitude of a body (paper section 7)."""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.errors import check_range
from lunar_drake.rotations import quaternion_from_rotation_matrix, rotation_exp
from lunar_drake.sensors.sampling import check_sampling

_ARCSEC = math.pi / 180.0 / 3600.0


@dc.dataclass
class StarTrackerConfig:
    """Rate, delay and attitude noise (1 sigma, sensor frame S, boresight = +z_S).

    Default: a small-satellite star tracker, e.g. Blue Canyon NST (~6 arcsec
    cross-boresight, ~40 arcsec about the boresight, 1 sigma; from memory). Roll about
    the boresight is several times worse than the cross-boresight axes because star
    separations subtend the small field of view (Liebe 2002, IEEE AES Magazine 17(1)).
    Noise is white (independent per sample); slowly varying errors (thermal
    misalignment, field-of-view errors), Sun/Earth exclusion and loss of lock at high
    rates are not modelled.

    Attributes:
        rate_hz: attitude solution rate (Hz). delay_s: delivery delay (s).
        cross_boresight_sigma_arcsec: noise about x_S and y_S (arcsec).
        roll_sigma_arcsec: noise about the boresight z_S (arcsec).
    """

    rate_hz: float = 2.0
    delay_s: float = 0.0
    cross_boresight_sigma_arcsec: float = 5.0
    roll_sigma_arcsec: float = 40.0

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_sampling(self.rate_hz, self.delay_s, max_rate_hz=1000.0)
        check_range(
            "cross_boresight_sigma_arcsec",
            self.cross_boresight_sigma_arcsec,
            0.0,
            3600.0,
            unit=" arcsec",
        )
        check_range("roll_sigma_arcsec", self.roll_sigma_arcsec, 0.0, 3600.0, unit=" arcsec")

    @property
    def sigma_rad(self) -> np.ndarray:
        """Sigma (3,) of the error rotation vector about x_S, y_S, z_S (rad)."""
        cb, roll = self.cross_boresight_sigma_arcsec, self.roll_sigma_arcsec
        return np.array([cb, cb, roll]) * _ARCSEC


def star_tracker_error_angles(
    generator: np.random.Generator, *, config: StarTrackerConfig
) -> np.ndarray:
    """Error rotation vector (3,) (rad) in S of one sample (draws 3 normals)."""
    return generator.standard_normal(3) * config.sigma_rad


def star_tracker_measurement(
    R_WB: np.ndarray,
    generator: np.random.Generator,
    *,
    config: StarTrackerConfig,
    R_BS=None,
) -> np.ndarray:
    """Measured body attitude ``q_WB`` as a unit quaternion (4,) = (w, x, y, z), w >= 0.

    ``R_WS_meas = R_WS Exp(theta_S)`` with ``theta_S`` from
    :func:`star_tracker_error_angles`; reported as ``R_WB_meas = R_WS_meas R_SB`` (the
    tracker's alignment ``R_BS`` is assumed known exactly).
    """
    R_WB = np.asarray(R_WB, dtype=np.float64)
    R_BS = np.eye(3) if R_BS is None else np.asarray(R_BS, dtype=np.float64)
    err = rotation_exp(star_tracker_error_angles(generator, config=config))
    return quaternion_from_rotation_matrix(R_WB @ R_BS @ err @ R_BS.T)
