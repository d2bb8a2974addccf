"""Wheel odometry with star-tracker attitude (propagated by the gyro between fixes): the
on-board dead-reckoning estimate.

Each flight tick the wheel-angle increments (encoders) and the steering angles the
flight software commanded give the chassis displacement in the body frame by the
rovers' forward kinematics (least squares over the wheels:
:func:`~lunar_drake.dynamics.kinematics.explicit_steer_twist`, or
:func:`~lunar_drake.dynamics.kinematics.skid_steer_twist` with the lateral motion taken
as zero); the star tracker's attitude turns it into the site frame. Wheel slip is not
observed, so the estimate drifts by the slip (the EKF of the autonomy issue replaces
this). The estimate starts at the scenario's spawn point with z = 0: the flight
software does not know the terrain height, so z is relative to the start.
"""

from __future__ import annotations

import math

import numpy as np

from lunar_drake.dynamics.kinematics import (
    WheelGeometry,
    explicit_steer_twist,
    skid_steer_twist,
)


def body_displacement(
    wheel_delta_rad, steer_rad, *, geometry: WheelGeometry, skid: bool
) -> np.ndarray:
    """Chassis displacement (dx, dy, dyaw) in the body frame (m, m, rad) from wheel angle
    increments (rad) and steering angles (rad; ignored for skid steer)."""
    d = np.asarray(wheel_delta_rad, dtype=np.float64)
    if skid:
        return skid_steer_twist(d, geometry=geometry)
    return explicit_steer_twist(np.asarray(steer_rad, dtype=np.float64), d, geometry=geometry)


def odometry_step(
    p_W, wheel_delta_rad, steer_rad, R_WB, *, geometry: WheelGeometry, skid: bool
) -> np.ndarray:
    """The chassis position (3,) in W (m) after one step of dead reckoning."""
    d = body_displacement(wheel_delta_rad, steer_rad, geometry=geometry, skid=skid)
    return np.asarray(p_W, np.float64) + np.asarray(R_WB, np.float64) @ np.array([d[0], d[1], 0.0])


def propagate_attitude(q_WB, w_B, dt: float) -> np.ndarray:
    """``q_WB`` (4,) = (w, x, y, z) rotated by the body rate ``w_B`` (3,) (rad/s, body
    frame, e.g. the gyro) held for ``dt`` s: ``q_WB * Exp(w_B dt)``, normalised, w >= 0.
    (Scalar arithmetic: one quaternion per flight tick.)"""
    aw, ax, ay, az = (float(v) for v in q_WB)
    tx, ty, tz = (float(v) * dt for v in w_B)
    half = 0.5 * math.sqrt(tx * tx + ty * ty + tz * tz)
    k = 0.5 - half * half / 12.0 if half < 1e-6 else math.sin(half) / (2.0 * half)
    bw, bx, by, bz = math.cos(half), k * tx, k * ty, k * tz
    q = np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )
    q /= math.sqrt(q @ q)
    return -q if q[0] < 0 else q
