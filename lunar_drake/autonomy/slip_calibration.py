"""The flight software's slip calibration: a pre-flight product, never the plant's soil.

Rover teams calibrate dead reckoning before launch, on a terrestrial simulant, with the
rover offloaded to its lunar weight (DESIGN.md decision 9). Here that campaign is the
independent steady-state Wong-Reece wheel (:func:`lunar_drake.dynamics.wheel_reference.
reference_slip`) for the rover's description on the *calibration* soil (a preset such as
``grc1``, or a soil file -- e.g. one ``lunar-drake slip-fit`` wrote from measured drives)
at lunar gravity: the steady slip climbing straight up 0, 2, ..., 12 deg, mirrored about
level for descents (the reference does not model braking: an assumption), and the level
slip as the prior. Pure Python; no Drake.
"""

from __future__ import annotations

import dataclasses as dc
import math

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics import wheel_reference
from lunar_drake.dynamics.soil_io import load_soil
from lunar_drake.errors import ConfigError
from lunar_drake.moon import GRAVITY_MPS2

#: Climbs (deg) at which the calibration measures slip.
CLIMBS_DEG = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0)
#: Descents (deg) in the table, mirrored from the climbs of the same size.
DESCENTS_DEG = (-8.0, -4.0)


@dc.dataclass(frozen=True)
class SlipCalibration:
    """A slip table for the EKF (``EstimatorConfig.slip_vs_slope``) and its level prior.

    Attributes:
        soil: the calibration soil's name. spec: what the scenario named (preset or file).
        gravity_mps2: the gravity of the campaign (lunar: the rover offloaded).
        slip_prior: the level slip (-). table: ``[[slope_deg, slip], ...]``.
    """

    soil: str
    spec: str
    gravity_mps2: float
    slip_prior: float
    table: tuple

    def describe(self, *, plant_soil: tm.SoilParams) -> dict:
        """Deterministic facts for summaries; ``is_plant_soil`` says whether the
        calibration soil equals the plant's (an oracle)."""
        return {
            "slip_calibration": self.spec,
            "soil": self.soil,
            "is_plant_soil": self.is_soil(plant_soil),
            "gravity_mps2": self.gravity_mps2,
            "slip_prior": self.slip_prior,
            "slip_vs_slope": [list(r) for r in self.table],
        }

    def is_soil(self, soil: tm.SoilParams) -> bool:
        """Whether ``soil`` has the calibration soil's parameters (name aside)."""
        return _soil_key(soil) == self._key

    @property
    def _key(self) -> tuple:
        return _soil_key(load_soil(self.spec))


def _soil_key(soil: tm.SoilParams) -> tuple:
    return tuple((k, v) for k, v in sorted(dc.asdict(soil).items()) if k != "name")


def calibrate(*, description, spec: str, gravity_mps2: float = GRAVITY_MPS2) -> SlipCalibration:
    """The slip calibration of rover ``description`` on soil ``spec`` (a preset name or
    a soil YAML file; module docstring). Cached per (rover, soil, gravity) in-process.

    Raises:
        ConfigError: the soil cannot be loaded, or the rover cannot climb the calibration's
            gentlest slopes on it.
    """
    soil = load_soil(spec)
    key = (repr(description), repr(soil), str(spec), float(gravity_mps2))
    if key not in _CACHE:
        _CACHE[key] = _calibrate(description, soil, str(spec), float(gravity_mps2))
    return _CACHE[key]


_CACHE: dict = {}


def _calibrate(description, soil, spec: str, gravity: float) -> SlipCalibration:
    wheel = tm.WheelParams(radius_m=description.wheel_radius_m, width_m=description.wheel_width_m)
    slips = {}
    for deg in CLIMBS_DEG:
        a = math.radians(deg)
        loads = wheel_reference.slope_wheel_loads(description=description, slope_rad=a,
                                                  gravity_mps2=gravity)  # fmt: skip
        try:
            s = wheel_reference.reference_slip(slope_rad=a, wheel_loads_N=loads, wheel=wheel,
                                               soil=soil)  # fmt: skip
        except tm.ImmobilizedError:
            if deg <= 4.0:
                raise ConfigError(
                    f"flight.estimator.slip_calibration = {spec!r}: {description.name} cannot "
                    f"climb {deg:g} deg on {soil.name}; a calibration needs at least 0-4 deg"
                ) from None
            break  # the table ends at the steepest climb
        slips[deg] = round(float(s), 4)
    level = slips[0.0]
    rows = [(d, round(2.0 * level - slips[-d], 4)) for d in DESCENTS_DEG if -d in slips]
    rows += sorted(slips.items())
    return SlipCalibration(soil=soil.name, spec=spec, gravity_mps2=gravity, slip_prior=level,
                           table=tuple((float(d), float(v)) for d, v in rows))  # fmt: skip


def calibrated_estimator(config, *, description):
    """``config`` (an :class:`~lunar_drake.autonomy.ekf.EstimatorConfig`) with its
    ``slip_prior`` and ``slip_vs_slope`` from ``config.slip_calibration`` when one is
    named (the table then written out, the name cleared; else unchanged), and the
    calibration (or None)."""
    if not config.slip_calibration:
        return config, None
    cal = calibrate(description=description, spec=config.slip_calibration)
    out = dc.replace(config, slip_prior=cal.slip_prior, slip_calibration="",
                     slip_vs_slope=[list(r) for r in cal.table])  # fmt: skip
    return out, cal


__all__ = ["CLIMBS_DEG", "DESCENTS_DEG", "SlipCalibration", "calibrate", "calibrated_estimator"]
