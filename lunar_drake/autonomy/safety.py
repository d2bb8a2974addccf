"""The virtual bumper: on-board checks that safe the rover. Pure; no Drake.

While a command drives the wheels, :func:`bumper_step` watches, each bumper tick:

* **tilt** -- the estimated roll or pitch beyond ``max_tilt_deg`` (default: the
  rover's ``max_rated_slope_deg``) for ``tilt_persist_s``;
* **stall** -- the wheels turning (encoders) slower than ``stall_speed_fraction`` of
  their commanded rate for ``stall_persist_s`` (a motor at its torque limit, a wheel
  jammed or dug in to the axle);
* **slip** -- the yaw rate the encoders imply (rover kinematics) disagreeing with the
  gyro's by more than ``max_yaw_slip_radps + yaw_slip_fraction |encoder rate|`` for
  ``slip_persist_s``: the chassis turns against what its wheels say -- spun round by a
  slide down a slope, a wheel spinning on one side. The fraction leaves room for a
  skid-steer rover, which on this soil turns at only 25-50 % of its kinematic rate
  (measured on the ``skid`` mission). Longitudinal slip (wheels turning, chassis not moving
  as much) is not observable on board without visual odometry: the EKF carries it as an
  unobserved state (:mod:`lunar_drake.autonomy.ekf`); the ground's VO measures it.

The loss of the uplink for longer than ``uplink_timeout_s`` while driving is checked by
the executor (:func:`~lunar_drake.autonomy.commands.executor_step`), which owns the
uplink. **low_soc** -- the battery's state of charge (the power sensor) below
``min_soc`` while driving -- trips at once. A trip safes the rover until the ground
sends a resume.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.errors import check_range

#: Bumper timers, in order (s).
TIMERS = ("tilt", "stall", "slip")


@dc.dataclass
class SafetyConfig:
    """The virtual bumper's limits (flight ``safety``).

    Attributes:
        enabled: run the bumper (the uplink timeout stays in force unless 0).
        rate_hz: bumper tick (Hz).
        max_tilt_deg: roll or pitch limit (deg); None: the rover's
            ``max_rated_slope_deg``.
        tilt_persist_s: how long beyond it before safing (s).
        stall_speed_fraction: wheels slower than this fraction of the commanded rate
            (mean over wheels) count as stalled.
        stall_persist_s: how long (s).
        max_yaw_slip_radps: largest encoder-vs-gyro yaw-rate disagreement (rad/s) ...
        yaw_slip_fraction: ... plus this fraction of the encoders' yaw rate.
        slip_persist_s: how long beyond it (s).
        uplink_timeout_s: safe when no uplink message (heartbeats included) has arrived
            for this long while a command runs (s); 0: never.
        min_soc: safe when the battery's state of charge falls below this while
            driving (fraction, [0, 1); 0: never).
    """

    enabled: bool = True
    rate_hz: float = 10.0
    max_tilt_deg: float | None = None
    tilt_persist_s: float = 0.5
    stall_speed_fraction: float = 0.25
    stall_persist_s: float = 3.0
    max_yaw_slip_radps: float = 0.1
    yaw_slip_fraction: float = 0.8
    slip_persist_s: float = 3.0
    uplink_timeout_s: float = 60.0
    min_soc: float = 0.2

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_range("rate_hz", self.rate_hz, 0.0, 1000.0, lo_open=True, unit=" Hz")
        if self.max_tilt_deg is not None:
            check_range("max_tilt_deg", self.max_tilt_deg, 0.0, 90.0, lo_open=True, unit=" deg")
        check_range("tilt_persist_s", self.tilt_persist_s, 0.0, 3600.0, unit=" s")
        check_range("stall_speed_fraction", self.stall_speed_fraction, 0.0, 1.0)
        check_range("stall_persist_s", self.stall_persist_s, 0.0, 3600.0, unit=" s")
        check_range("max_yaw_slip_radps", self.max_yaw_slip_radps, 0.0, 10.0, lo_open=True,
                    unit=" rad/s")  # fmt: skip
        check_range("yaw_slip_fraction", self.yaw_slip_fraction, 0.0, 10.0)
        check_range("slip_persist_s", self.slip_persist_s, 0.0, 3600.0, unit=" s")
        check_range("uplink_timeout_s", self.uplink_timeout_s, 0.0, 1.0e6, unit=" s")
        check_range("min_soc", self.min_soc, 0.0, 1.0, hi_open=True)

    def tilt_limit_rad(self, description) -> float:
        """The tilt limit (rad) for this rover."""
        deg = description.max_rated_slope_deg if self.max_tilt_deg is None else self.max_tilt_deg
        return math.radians(deg)


def bumper_step(timers, *, dt_s: float, driving: bool, roll_rad: float, pitch_rad: float,
                wheel_rate_cmd, wheel_rate_meas, yaw_rate_encoders: float,
                yaw_rate_gyro: float, tilt_limit_rad: float, config: SafetyConfig,
                soc: float = math.nan) -> tuple[np.ndarray, str]:  # fmt: skip
    """One bumper tick. ``timers`` (3,) are how long each condition of :data:`TIMERS`
    has held (s); ``driving``: a command is driving the wheels. Wheel rates (rad/s) are
    commanded and measured (encoder differences); yaw rates (rad/s) from the encoders
    (kinematics) and the gyro; ``soc`` the battery's state of charge (NaN: no power
    sensor). Returns the new timers and the tripped condition ("" if none; the first
    of TIMERS over its persistence time, else ``low_soc``)."""
    t = np.zeros(3) if not driving else np.asarray(timers, np.float64).copy()
    if not driving:
        return t, ""
    cmd = np.abs(np.asarray(wheel_rate_cmd, np.float64))
    meas = np.abs(np.asarray(wheel_rate_meas, np.float64))
    tilted = max(abs(roll_rad), abs(pitch_rad)) > tilt_limit_rad
    turning_wheels = float(cmd.mean()) > 1e-3
    stalled = turning_wheels and float(meas.mean()) < config.stall_speed_fraction * float(
        cmd.mean()
    )
    allowed = config.max_yaw_slip_radps + config.yaw_slip_fraction * abs(yaw_rate_encoders)
    slipping = turning_wheels and abs(yaw_rate_encoders - yaw_rate_gyro) > allowed
    for k, on in enumerate((tilted, stalled, slipping)):
        t[k] = t[k] + dt_s if on else 0.0
    persist = (config.tilt_persist_s, config.stall_persist_s, config.slip_persist_s)
    for k, name in enumerate(TIMERS):
        if t[k] > 0.0 and t[k] >= persist[k] - 1e-9:
            return t, name
    if config.min_soc > 0.0 and soc < config.min_soc:  # NaN (no sensor) compares False
        return t, "low_soc"
    return t, ""


__all__ = ["TIMERS", "SafetyConfig", "bumper_step"]
