"""PowerConfig: the array, battery and loads of the rover, one section each."""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc

from lunar_drake.errors import LunarDrakeError, check_range
from lunar_drake.power.battery import BatteryConfig
from lunar_drake.power.loads import LoadsConfig
from lunar_drake.power.solar_array import SolarArrayConfig

__all__ = ["PowerConfig"]


@dc.dataclass
class PowerConfig:
    """The rover's power system (the panel's size and mount are the rover description's).

    Attributes:
        enabled: simulate the power system (the plant's ``rover.power`` and
            ``truth.power`` ports, ``power.csv``, the summary's ``power`` section).
        period_s: period of the array evaluation and the battery update (s), (0, 3600];
            the motors' and the holding draw's energy is integrated at the plant's time
            step and averaged over it. The Sun moves 1.4e-4 deg/s: 1 s is fine.
        array: cells and their derating (:class:`SolarArrayConfig`).
        battery: capacity, efficiencies, initial SOC (:class:`BatteryConfig`).
        loads: motors and constant draws (:class:`LoadsConfig`).
    """

    enabled: bool = True
    period_s: float = 1.0
    array: SolarArrayConfig = dc.field(default_factory=SolarArrayConfig)
    battery: BatteryConfig = dc.field(default_factory=BatteryConfig)
    loads: LoadsConfig = dc.field(default_factory=LoadsConfig)

    def validate(self) -> None:
        """Raises the section's error, its message prefixed with the section's name
        (``array.cell_efficiency = 1.5 is out of range; allowed (0, 1]``)."""
        check_range("period_s", self.period_s, 0.0, 3600.0, lo_open=True, unit=" s")
        for name in ("array", "battery", "loads"):
            try:
                getattr(self, name).validate()
            except LunarDrakeError as exc:
                raise type(exc)(f"{name}.{exc}") from None
