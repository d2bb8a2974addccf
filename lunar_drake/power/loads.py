"""Electrical loads on the rover's bus (W).

* Drive and steering motors: electrical power = positive mechanical power
  ``sum(max(tau_k omega_k, 0))`` (joint torque N*m times joint rate rad/s) over a motor +
  gearbox + driver efficiency. A constant efficiency stands in for an efficiency map
  (assumption). Negative mechanical power (braking downhill) is not regenerated and its
  losses are neglected: it draws nothing.
* A standstill holding draw while the rover is braked (brake actuators and motor
  controllers on standby).
* Constant draws: avionics, cameras, radio, instruments, heaters. No duty cycles yet.

All figures are assumptions for an RP-class (~300 kg) rover, not published values.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc

import numpy as np

from lunar_drake.errors import check_range

__all__ = [
    "LoadBreakdown",
    "LoadsConfig",
    "load_breakdown",
    "mean_load_breakdown",
    "motor_electrical_W",
]

_CONSTANT_LOADS = ("avionics_W", "cameras_W", "radio_W", "instruments_W", "heaters_W")


@dc.dataclass
class LoadsConfig:
    """The rover's electrical loads (all defaults are assumptions).

    Attributes:
        drive_efficiency: mechanical over electrical power of a drive motor, gearbox and
            driver (-), (0, 1]; 0.6.
        steer_efficiency: the same for a steering motor (-), (0, 1]; 0.5.
        holding_W: draw while braked at a standstill (W), [0, 1e4]; 8.
        avionics_W: flight computer and power electronics (W), [0, 1e4]; 45.
        cameras_W: stereo pair and gimbal (W), [0, 1e4]; 10.
        radio_W: direct-to-Earth radio (W), [0, 1e4]; 25.
        instruments_W: science instruments (W), [0, 1e4]; 20.
        heaters_W: survival/operational heaters (W), [0, 1e4]; 20.
    """

    drive_efficiency: float = 0.6
    steer_efficiency: float = 0.5
    holding_W: float = 8.0
    avionics_W: float = 45.0
    cameras_W: float = 10.0
    radio_W: float = 25.0
    instruments_W: float = 20.0
    heaters_W: float = 20.0

    def validate(self) -> None:
        """Raises OutOfRangeError naming the field and its allowed range."""
        check_range("drive_efficiency", self.drive_efficiency, 0.0, 1.0, lo_open=True)
        check_range("steer_efficiency", self.steer_efficiency, 0.0, 1.0, lo_open=True)
        for name in ("holding_W", *_CONSTANT_LOADS):
            check_range(name, getattr(self, name), 0.0, 1.0e4, unit=" W")


@dc.dataclass(frozen=True)
class LoadBreakdown:
    """Electrical power of each load (W); :attr:`total_W` their sum."""

    drive_W: float
    steer_W: float
    holding_W: float
    avionics_W: float
    cameras_W: float
    radio_W: float
    instruments_W: float
    heaters_W: float

    @property
    def total_W(self) -> float:
        return float(sum(getattr(self, f.name) for f in dc.fields(self)))


def motor_electrical_W(*, torque_Nm, speed_rad_s, efficiency: float) -> float:
    """Electrical power (W) of motors with joint torques ``torque_Nm`` (N*m) at joint rates
    ``speed_rad_s`` (rad/s) (broadcast; summed): ``sum(max(tau omega, 0)) / efficiency``."""
    check_range("efficiency", efficiency, 0.0, 1.0, lo_open=True)
    mech = np.asarray(torque_Nm, dtype=float) * np.asarray(speed_rad_s, dtype=float)
    return float(np.sum(np.maximum(mech, 0.0))) / float(efficiency)


def load_breakdown(
    *,
    config: LoadsConfig,
    drive_torque_Nm=(),
    drive_speed_rad_s=(),
    steer_torque_Nm=(),
    steer_speed_rad_s=(),
    braked: bool = False,
) -> LoadBreakdown:
    """Every load's electrical power (W) for the given joint torques (N*m) and rates
    (rad/s) of the drive and steering joints, and whether the rover is braked."""
    return LoadBreakdown(
        drive_W=motor_electrical_W(torque_Nm=drive_torque_Nm, speed_rad_s=drive_speed_rad_s,
                                   efficiency=config.drive_efficiency),
        steer_W=motor_electrical_W(torque_Nm=steer_torque_Nm, speed_rad_s=steer_speed_rad_s,
                                   efficiency=config.steer_efficiency),
        holding_W=float(config.holding_W) if braked else 0.0,
        **{name: float(getattr(config, name)) for name in _CONSTANT_LOADS},
    )  # fmt: skip


def mean_load_breakdown(
    *,
    config: LoadsConfig,
    dt_s: float,
    drive_work_J: float = 0.0,
    steer_work_J: float = 0.0,
    braked: bool = False,
) -> LoadBreakdown:
    """Every load's mean electrical power (W) over ``dt_s`` seconds in which the drive
    and steering motors did ``drive_work_J`` and ``steer_work_J`` of positive mechanical
    work (J: the integral of ``sum(max(tau omega, 0))``, as an energy meter integrates it
    at the plant's step) and the rover was braked or not throughout. For constant torques
    and rates this equals :func:`load_breakdown` (work = power x ``dt_s``)."""
    check_range("dt_s", dt_s, 0.0, 1.0e7, lo_open=True, unit=" s")
    for name, work in (("drive_work_J", drive_work_J), ("steer_work_J", steer_work_J)):
        check_range(name, work, 0.0, 1.0e12, unit=" J")
    dt = float(dt_s)
    return LoadBreakdown(
        drive_W=float(drive_work_J) / dt / float(config.drive_efficiency),
        steer_W=float(steer_work_J) / dt / float(config.steer_efficiency),
        holding_W=float(config.holding_W) if braked else 0.0,
        **{name: float(getattr(config, name)) for name in _CONSTANT_LOADS},
    )
