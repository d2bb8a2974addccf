"""The battery: state of charge (SOC) under a net bus power, with charge/discharge losses.

Bookkeeping over one step of ``dt_s`` seconds with net bus power ``P = array - load`` (W,
held constant over the step), capacity ``C`` (Wh), efficiencies ``eta_c``, ``eta_d``:

* ``P >= 0`` (charging): the cells store ``P dt eta_c``; at full charge (SOC 1) the
  rest is shunted (the array is throttled: ``shunted_Wh``, bus energy not used).
* ``P < 0`` (discharging): the cells give ``|P| dt / eta_d`` to deliver ``|P| dt`` to
  the bus; at SOC 0 the rest of the load is not served (``unmet_Wh``, at the bus).

SOC is clamped to [0, 1]. Not modelled: capacity fade, temperature dependence of
capacity, voltage/current limits (C-rate), self-discharge.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc

from lunar_drake.errors import check_range

__all__ = ["BatteryConfig", "BatteryStep", "battery_step"]


@dc.dataclass
class BatteryConfig:
    """The rover's battery.

    Attributes:
        capacity_Wh: usable energy at SOC 1 (Wh), (0, 1e6]; 1500: assumption (a
            kWh-class Li-ion pack for a ~300 kg polar rover; no published RP figure used).
        charge_efficiency: stored over bus energy while charging (-), (0, 1]; 0.95:
            assumption (Li-ion, round trip ~0.9).
        discharge_efficiency: bus over cell energy while discharging (-), (0, 1]; 0.95:
            assumption.
        initial_soc: SOC at simulation time 0 (-), [0, 1]; 1.0.
    """

    capacity_Wh: float = 1500.0
    charge_efficiency: float = 0.95
    discharge_efficiency: float = 0.95
    initial_soc: float = 1.0

    def validate(self) -> None:
        """Raises OutOfRangeError naming the field and its allowed range."""
        check_range("capacity_Wh", self.capacity_Wh, 0.0, 1.0e6, lo_open=True, unit=" Wh")
        check_range("charge_efficiency", self.charge_efficiency, 0.0, 1.0, lo_open=True)
        check_range("discharge_efficiency", self.discharge_efficiency, 0.0, 1.0, lo_open=True)
        check_range("initial_soc", self.initial_soc, 0.0, 1.0)


@dc.dataclass(frozen=True)
class BatteryStep:
    """The result of one step.

    Attributes:
        soc: state of charge after the step, [0, 1].
        stored_Wh: change of stored energy (Wh): > 0 charging, < 0 discharging.
        shunted_Wh: surplus bus energy not stored because the battery was full (Wh), >= 0.
        unmet_Wh: load energy not served because the battery was empty (Wh), >= 0.
    """

    soc: float
    stored_Wh: float
    shunted_Wh: float
    unmet_Wh: float


def battery_step(
    *, config: BatteryConfig, soc: float, net_power_W: float, dt_s: float
) -> BatteryStep:
    """SOC after ``dt_s`` (s) of net bus power ``net_power_W`` (W; array minus loads),
    from ``soc`` (clamped to [0, 1] first)."""
    check_range("dt_s", dt_s, 0.0, 1.0e7, unit=" s")
    check_range("net_power_W", net_power_W, -1.0e7, 1.0e7, unit=" W")
    soc0 = min(max(float(soc), 0.0), 1.0)
    cap = float(config.capacity_Wh)
    bus_Wh = float(net_power_W) * float(dt_s) / 3600.0
    if bus_Wh >= 0.0:
        eta = config.charge_efficiency
        stored = min(bus_Wh * eta, (1.0 - soc0) * cap)
        shunted = bus_Wh - stored / eta
        return BatteryStep(soc=min(soc0 + stored / cap, 1.0), stored_Wh=stored,
                           shunted_Wh=max(shunted, 0.0), unmet_Wh=0.0)  # fmt: skip
    eta = config.discharge_efficiency
    drawn = min(-bus_Wh / eta, soc0 * cap)
    unmet = -bus_Wh - drawn * eta
    return BatteryStep(soc=max(soc0 - drawn / cap, 0.0), stored_Wh=-drawn, shunted_Wh=0.0,
                       unmet_Wh=max(unmet, 0.0))  # fmt: skip
