"""The on-board estimator's per-tick core: the layout of its state vector and the
compiled tick that dead-reckons with the encoders and the gyro
(:class:`~lunar_drake.systems.state_estimator.StateEstimator` calls it once per filter
tick). The same operations as :func:`~lunar_drake.autonomy.odometry.body_displacement`
followed by :func:`~lunar_drake.autonomy.ekf.predict`, in one call. No Drake.

State vector (float64): the EKF's nominal state (:data:`~lunar_drake.autonomy.ekf.NX`),
its covariance (``N_ERR x N_ERR``, row-major), the last star-tracker fix seen (w, x, y,
z), the wheel angles at the previous tick (rad, one per wheel) and ``started`` (1.0 once
the first tick has recorded the sensors).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from lunar_drake.autonomy import ekf_kernels as _k
from lunar_drake.dynamics.kinematics import _explicit_steer_twist_1

_PC0 = _k.NX
_FIX0 = _PC0 + _k.N_ERR**2
_ANGLES0 = _FIX0 + 4
X = slice(0, _k.NX)  # nominal state
PC = slice(_PC0, _FIX0)  # covariance, row-major
FIX = slice(_FIX0, _ANGLES0)  # the last star-tracker fix seen


def layout(n_wheels: int) -> tuple[slice, int, int]:
    """(slice of the previous wheel angles, index of ``started``, state size) for a rover
    with ``n_wheels`` wheels."""
    angles = slice(_ANGLES0, _ANGLES0 + int(n_wheels))
    return angles, angles.stop, angles.stop + 1


@numba.njit(cache=True)
def fix_is_new(s, fix):  # pragma: no cover - numba
    """A star-tracker fix ``fix`` (4,) is new: the filter has started, the fix is a
    quaternion (norm > 0.5, not the sensor's initial zeros) and differs from the last
    one seen in state ``s``."""
    if s[s.size - 1] <= 0.5:
        return False
    norm2 = 0.0
    same = True
    for i in range(4):
        norm2 += fix[i] * fix[i]
        same = same and fix[i] == s[_FIX0 + i]
    return norm2 > 0.25 and not same


@numba.njit(cache=True)
def tick(s, angles, fix, imu, steer, dt, skid, pinv, p_BS, offset, radius, table_deg,
         table_slip, noise):  # pragma: no cover - numba  # fmt: skip
    """The state after one tick (a new array): once started, the chassis displacement
    from the wheel-angle increments (skid: ``pinv`` of
    :func:`~lunar_drake.dynamics.kinematics.skid_twist_map`; explicit
    steer: the steering angles ``steer`` (n,) rad and the wheel geometry ``p_BS``,
    ``offset``, ``radius``) and the EKF prediction with the IMU reading ``imu`` (6,)
    (its gyro rate, rad/s) over ``dt`` s (:func:`~lunar_drake.autonomy.ekf_kernels.predict`'s
    table and noise); then the fix and the angles are recorded and ``started`` set."""
    n = angles.size
    a0 = _ANGLES0
    out = s.copy()
    if s[a0 + n] > 0.5:
        delta = np.empty(n)
        for i in range(n):
            delta[i] = angles[i] - s[a0 + i]
        if skid:
            v = delta * radius
            dx = 0.0
            for i in range(n):
                dx += v[i] * pinv[0, i]
            dy = 0.0
        else:
            d = _explicit_steer_twist_1(steer, delta, p_BS, offset, radius)
            dx, dy = d[0], d[1]
        ne = _k.N_ERR
        x, P = _k.predict(s[:_PC0].copy(), s[_PC0:_FIX0].copy().reshape(ne, ne), imu[:3], dx,
                          dy, dt, table_deg, table_slip, noise)  # fmt: skip
        out[:_PC0] = x
        out[_PC0:_FIX0] = P.ravel()
    out[_FIX0:_ANGLES0] = fix
    out[a0 : a0 + n] = angles
    out[a0 + n] = 1.0
    return out


@numba.njit(cache=True)
def pose(s):  # pragma: no cover - numba
    """The pose (6,) = x, y, z (m), roll, pitch, yaw (rad) of state ``s``, as
    :func:`~lunar_drake.autonomy.ekf.pose_and_covariance`."""
    R = _k.quat_to_matrix(s[3:7])
    out = np.empty(6)
    out[0], out[1], out[2] = s[0], s[1], s[2]
    out[3] = math.atan2(R[2, 1], R[2, 2])
    out[4] = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    out[5] = math.atan2(R[1, 0], R[0, 0])
    return out


@numba.njit(cache=True)
def pose_covariance(s):  # pragma: no cover - numba
    """The (36,) row-major covariance of [position error, world-frame attitude error]
    (m^2, rad^2) of state ``s``: the top-left 6 x 6 block of the EKF's."""
    ne = _k.N_ERR
    out = np.empty(36)
    for r in range(6):
        for c in range(6):
            out[6 * r + c] = s[_PC0 + ne * r + c]
    return out
