"""Compiled (numba) per-step wheel-soil contact: the terramechanics functions the
:class:`~lunar_drake.systems.wheel_regolith_contact.WheelRegolithContact` system calls
each plant step, fused into three calls. The formulas are
:mod:`lunar_drake.dynamics.terramechanics`' (slip ratio and angle, travel direction,
Wong-Reece forces, normal force with damping, static weight, patch length, the static
shear patch); results equal the numpy functions up to round-off. Vectors are in the
world frame W, per wheel (n, 3); forces N, moments N m, speeds m/s. No Drake.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics.contact_geometry import geometry_in_memory
from lunar_drake.moon import GRAVITY_MPS2
from lunar_drake.terrain.heightfield import heights_in_box


def soil_constants(
    *,
    wheel: tm.WheelParams,
    soil: tm.SoilParams,
    patch: tm.ShearPatchParams,
    v_eps: float,
    direction_eps: float,
    gravity_mps2: float = GRAVITY_MPS2,
) -> tuple[np.ndarray, np.ndarray]:
    """(Wong-Reece kernel parameters, the other constants (13,)) for :func:`kinematics`
    and :func:`forces`: radius, v_eps, direction_eps, damping coefficient and exponent
    (``d(z) = coef z^n``), static and dynamic patch speeds, rear angle ratio, patch
    cohesion ``c b``, ``tan phi``, ``K``, ``K_y``, ``4 zeta_p^2 / g``."""
    par = tm._kernel_parameters(wheel, soil, gravity_mps2)
    coef = float(tm.contact_damping(1.0, wheel=wheel, soil=soil, gravity_mps2=gravity_mps2))
    const = np.array([
        wheel.radius_m, v_eps, direction_eps, coef, soil.n, patch.static_speed_mps,
        patch.dynamic_speed_mps, soil.rear_angle_ratio, soil.c * wheel.width_m,
        math.tan(soil.phi), soil.K, soil.K_y, 4.0 * patch.damping_ratio**2 / gravity_mps2,
    ])  # fmt: skip
    return par, const


@numba.njit(cache=True)
def _dot(a, b, i):  # pragma: no cover - numba
    return a[i, 0] * b[i, 0] + a[i, 1] * b[i, 1] + a[i, 2] * b[i, 2]


@numba.njit(cache=True)
def kinematics(v, wv, axle, sinkage, n_W, forward, lateral, on, par, const):  # pragma: no cover
    """Stage 1 of a contact step from the hub velocities ``v`` and rates ``wv`` (n, 3),
    the axles and the footprint geometry (sinkage (n,) m, normal/forward/lateral (n, 3),
    ``on`` (n,) bool: the footprint on the raster). Returns (wheel_state rows (n, 6)
    with drawbar pull 0, normal force N (n,), patch slip velocity (n, 2), rolling speed
    ``r omega`` (n,), patch length (n,), static weight (n,), Wong-Reece drawbar pull,
    lateral force and soil moment about +axle (n,) each)."""
    n = v.shape[0]
    r, v_eps, dir_eps, coef, soil_n, v0, v1, rear = (
        const[0], const[1], const[2], const[3], const[4], const[5], const[6], const[7]
    )  # fmt: skip
    z = np.empty(n)
    slip = np.empty(n)
    tan_b = np.empty(n)
    beta = np.empty(n)
    d = np.empty(n)
    v_x = np.empty(n)
    v_y = np.empty(n)
    z_dot = np.empty(n)
    omega_r = np.empty(n)
    for i in range(n):
        z[i] = min(max(sinkage[i], -1.0), r) if on[i] else -1.0
        v_x[i] = _dot(v, forward, i)
        v_y[i] = _dot(v, lateral, i)
        z_dot[i] = -_dot(v, n_W, i)
        # Absolute spin about the axle: the rim's slip against the ground does not care
        # which body the wheel hangs from (a pitching rocker must not look like slip).
        omega_r[i] = _dot(wv, axle, i) * r
        den = max(max(abs(omega_r[i]), abs(v_x[i])), v_eps)
        slip[i] = min(max((omega_r[i] - v_x[i]) / den, -1.0), 1.0)
        beta[i] = math.atan(v_y[i] / max(abs(v_x[i]), v_eps))
        tan_b[i] = math.tan(beta[i])
        # The soil is compacted by a wheel that translates or spins (digging in when
        # immobilized): the model follows v + r omega, mirrored when it reverses and
        # faded out near rest.
        d[i] = min(max((v_x[i] + omega_r[i]) / dir_eps, -1.0), 1.0)
    out = np.empty((n, 6))
    tm._wong_reece_kernel(slip, tan_b, z, d, par, tm._U, tm._WU, out)
    state = np.zeros((n, 6))
    N = np.empty(n)
    slip_velocity = np.empty((n, 2))
    length = np.empty(n)
    ws = np.empty(n)
    fx = np.empty(n)
    fy = np.empty(n)
    m_soil = np.empty(n)
    for i in range(n):
        zp = max(z[i], 0.0)
        Ni = max(out[i, 0] + coef * zp**soil_n * z_dot[i], 0.0) if zp > 0.0 else 0.0
        N[i] = Ni if on[i] else 0.0
        sb = 1.0 if beta[i] > 0.0 else (-1.0 if beta[i] < 0.0 else 0.0)
        fx[i] = out[i, 1] - out[i, 2]
        fy[i] = -sb * (out[i, 4] + abs(math.sin(beta[i])) * out[i, 5])
        m_soil[i] = -out[i, 3]
        # Static patch weight: 1 for a wheel that does not roll, 0 at driving speeds.
        t = min(max((abs(omega_r[i]) - v0) * (1.0 / (v1 - v0)), 0.0), 1.0)
        ws[i] = 1.0 - t * t * (3.0 - 2.0 * t)
        slip_velocity[i, 0] = v_x[i] - omega_r[i]
        slip_velocity[i, 1] = v_y[i]
        th1 = math.acos(1.0 - min(max(z[i], 0.0), r) * (1.0 / r))
        if rear == 0.0:
            length[i] = r * math.sin(th1)
        else:
            length[i] = r * (math.sin(th1) + math.sin(rear * th1))
        state[i, 0] = sinkage[i] if on[i] else 0.0
        state[i, 1] = N[i]
        state[i, 2] = slip[i]
        state[i, 3] = beta[i]
        state[i, 5] = 0.0 if on[i] else 1.0
    return state, N, slip_velocity, omega_r, length, ws, fx, fy, m_soil


#: Per-wheel blocks of :func:`step_kinematics`' packed output, in order, with their
#: columns: (name, columns); each block is ``n * columns`` values, row-major (n, columns).
STAGE1_BLOCKS = (
    ("p", 3), ("axle", 3), ("n_W", 3), ("forward_W", 3), ("lateral_W", 3), ("r_c", 3),
    ("state", 6), ("N", 1), ("slip_velocity", 2), ("rolling_speed", 1),
    ("patch_length", 1), ("static_weight", 1), ("fx", 1), ("fy", 1), ("m_soil", 1),
)  # fmt: skip


@numba.njit(cache=True)
def points_in_world(X, pts_B):  # pragma: no cover - numba
    """(k, 3) points ``pts_B`` (k, 3) of a body (m, its frame) in W, the body's pose
    ``X`` (3, 4) = [R | p]: ``p + R pts_B``."""
    k = pts_B.shape[0]
    out = np.empty((k, 3))
    for i in range(k):
        for r in range(3):
            out[i, r] = X[r, 3] + (
                X[r, 0] * pts_B[i, 0] + X[r, 1] * pts_B[i, 1] + X[r, 2] * pts_B[i, 2]
            )
    return out


@numba.njit(cache=True)
def pack_stage1(p, axle, n_W, forward, lateral, r_c, state, N, slip_velocity, omega_r, length,
                ws, fx, fy, m_soil, pen):  # pragma: no cover - numba  # fmt: skip
    """The :data:`STAGE1_BLOCKS` one after the other (``33 n`` values), then the belly
    points' penetration ``pen`` (k,)."""
    n = N.shape[0]
    k = pen.shape[0]
    out = np.empty(33 * n + k)
    o = 0
    for a in (p, axle, n_W, forward, lateral, r_c):
        out[o : o + 3 * n] = a.ravel()
        o += 3 * n
    out[o : o + 6 * n] = state.ravel()
    o += 6 * n
    out[o : o + n] = N
    o += n
    out[o : o + 2 * n] = slip_velocity.ravel()
    o += 2 * n
    for a in (omega_r, length, ws, fx, fy, m_soil):
        out[o : o + n] = a
        o += n
    out[o:] = pen
    return out


@numba.njit(cache=True)
def _unpack(values, n):  # pragma: no cover - numba
    """Views of :func:`pack_stage1`'s blocks, in :data:`STAGE1_BLOCKS` order."""
    m = 3 * n
    p = values[0:m].reshape(n, 3)
    axle = values[m : 2 * m].reshape(n, 3)
    n_W = values[2 * m : 3 * m].reshape(n, 3)
    forward = values[3 * m : 4 * m].reshape(n, 3)
    lateral = values[4 * m : 5 * m].reshape(n, 3)
    r_c = values[5 * m : 6 * m].reshape(n, 3)
    o = 6 * m
    state = values[o : o + 6 * n].reshape(n, 6)
    o += 6 * n
    N = values[o : o + n]
    o += n
    slip_velocity = values[o : o + 2 * n].reshape(n, 2)
    o += 2 * n
    omega_r = values[o : o + n]
    length = values[o + n : o + 2 * n]
    ws = values[o + 2 * n : o + 3 * n]
    fx = values[o + 3 * n : o + 4 * n]
    fy = values[o + 4 * n : o + 5 * n]
    m_soil = values[o + 5 * n : o + 6 * n]
    return (p, axle, n_W, forward, lateral, r_c, state, N, slip_velocity, omega_r, length,
            ws, fx, fy, m_soil)  # fmt: skip


@numba.njit(cache=True)
def step_kinematics(X, V, n, z, res, left, right, bottom, top, U, Wc, pinv, radius, par,
                    const, belly_B):  # pragma: no cover - numba  # fmt: skip
    """Stage 1 in one call, from the bodies' poses ``X`` (m, 3, 4) and spatial velocities
    ``V`` (m, 6) = [w, v] (the first ``n`` are the wheels, then the chassis when
    ``belly_B`` has points), an in-memory raster
    (:func:`~lunar_drake.terrain.heightfield.heights_in_box`' arguments, the box already
    shrunk by the margin), the footprint pattern ``U, Wc, pinv`` and the belly points
    ``belly_B`` (k, 3) in the chassis frame: the same calls, in the same order, as
    :func:`points_in_world`,
    :func:`~lunar_drake.dynamics.contact_geometry.wheel_contact_geometry`,
    :func:`kinematics` and the belly points' heights (the same bits).

    Returns:
        (values, flags, p_belly, off, touch): ``values`` :func:`pack_stage1`'s (``33 n``
        values, then the belly points' penetration (k,), m; -inf off the raster);
        ``flags`` (n + k,) bool: each wheel's footprint on the raster, then each belly
        point's; the belly points (k, 3) in W; ``off``: a flag is False; ``touch``: a
        belly point is below the ground.
    """
    k = belly_B.shape[0]
    p_belly = points_in_world(X[n], belly_B) if k > 0 else np.zeros((0, 3))
    p = np.ascontiguousarray(X[:n, :, 3])
    axle = np.ascontiguousarray(X[:n, :, 1])
    v = np.ascontiguousarray(V[:n, 3:])
    wv = np.ascontiguousarray(V[:n, :3])
    sinkage, n_W, forward, lateral, p_WC, off = geometry_in_memory(
        z, res, left, right, bottom, top, p, axle, U, Wc, pinv, radius
    )
    on = ~off
    state, N, slip_velocity, omega_r, length, ws, fx, fy, m_soil = kinematics(
        v, wv, axle, sinkage, n_W, forward, lateral, on, par, const
    )
    zt, ok = heights_in_box(
        z, np.ascontiguousarray(p_belly[:, 0]), np.ascontiguousarray(p_belly[:, 1]), res,
        left, right, bottom, top,
    )  # fmt: skip
    pen = np.empty(k)
    for i in range(k):
        pen[i] = zt[i] - p_belly[i, 2] if ok[i] else -np.inf
    out = pack_stage1(p, axle, n_W, forward, lateral, p_WC - p, state, N, slip_velocity,
                      omega_r, length, ws, fx, fy, m_soil, pen)  # fmt: skip
    flags = np.empty(n + k, np.bool_)
    flags[:n] = on
    flags[n:] = ok
    off_any = False
    for i in range(n + k):
        off_any = off_any or not flags[i]
    touch = False
    for i in range(k):
        touch = touch or pen[i] > 0.0
    return out, flags, p_belly, off_any, touch


@numba.njit(cache=True)
def forces(j, N, slip_velocity, length, ws, fx_dyn, fy_dyn, m_dyn, n_W, forward, lateral, r_c,
           axle, on, const):  # pragma: no cover - numba  # fmt: skip
    """Stage 2: (force (n, 3) at each wheel centre, moment (n, 3) about it, the blended
    drawbar pull (n,)) from stage 1, the patch displacement ``j`` (n, 2) (m, contact
    frame) and the contact point ``r_c`` (n, 3) relative to the centre. The static patch
    force (Janosi-Hanamoto in ``j`` with a Mohr-Coulomb cap and bristle damping) is
    blended with the Wong-Reece forces by the static weight; the moment's axle component
    is the soil moment."""
    n = N.shape[0]
    cb, tphi, K, Ky, damp = const[8], const[9], const[10], const[11], const[12]
    F = np.empty((n, 3))
    tau = np.empty((n, 3))
    drawbar = np.empty(n)
    blend = False
    for i in range(n):
        if ws[i] > 0.0:
            blend = True
    for i in range(n):
        fx, fy, m_soil = fx_dyn[i], fy_dyn[i], m_dyn[i]
        if blend:
            Ni = max(N[i], 0.0)
            fmax = cb * length[i] + tphi * Ni
            ex, ey = j[i, 0] * (1.0 / K), j[i, 1] * (1.0 / Ky)
            rho = math.hypot(ex, ey)
            mob = fmax * -math.expm1(-rho) / (rho + (1.0 if rho == 0.0 else 0.0))
            c = math.sqrt(damp * fmax * Ni)
            sx = -(mob * ex) - (c * K**-0.5) * slip_velocity[i, 0]
            sy = -(mob * ey) - (c * Ky**-0.5) * slip_velocity[i, 1]
            cap = fmax / max(max(math.hypot(sx, sy), fmax), 1e-300)
            sx, sy = sx * cap, sy * cap
            Fs0 = sx * forward[i, 0] + sy * lateral[i, 0]
            Fs1 = sx * forward[i, 1] + sy * lateral[i, 1]
            Fs2 = sx * forward[i, 2] + sy * lateral[i, 2]
            # The patch force acts at the rim: its moment about the axle is the lever arm's.
            m_static = ((r_c[i, 1] * Fs2 - r_c[i, 2] * Fs1) * axle[i, 0]
                        + (r_c[i, 2] * Fs0 - r_c[i, 0] * Fs2) * axle[i, 1]
                        + (r_c[i, 0] * Fs1 - r_c[i, 1] * Fs0) * axle[i, 2])  # fmt: skip
            wd = 1.0 - ws[i]
            fx = ws[i] * sx + wd * fx
            fy = ws[i] * sy + wd * fy
            m_soil = ws[i] * m_static + wd * m_soil
        o = 1.0 if on[i] else 0.0
        for k in range(3):
            F[i, k] = (N[i] * n_W[i, k] + fx * forward[i, k] + fy * lateral[i, k]) * o
        M0 = r_c[i, 1] * F[i, 2] - r_c[i, 2] * F[i, 1]
        M1 = r_c[i, 2] * F[i, 0] - r_c[i, 0] * F[i, 2]
        M2 = r_c[i, 0] * F[i, 1] - r_c[i, 1] * F[i, 0]
        m_axle = M0 * axle[i, 0] + M1 * axle[i, 1] + M2 * axle[i, 2]
        # The moment about the centre of F at the contact point, corrected so its axle
        # component is the soil moment (Wong-Reece: -torque) rather than the lever arm.
        corr = m_soil * o - m_axle
        tau[i, 0] = M0 + corr * axle[i, 0]
        tau[i, 1] = M1 + corr * axle[i, 1]
        tau[i, 2] = M2 + corr * axle[i, 2]
        drawbar[i] = fx * o
    return F, tau, drawbar


@numba.njit(cache=True)
def patch_update(j, slip_velocity, rolling_speed, length, dt, const,
                 saturation):  # pragma: no cover - numba  # fmt: skip
    """Patch displacement (n, 2) after ``dt`` s
    (:func:`~lunar_drake.dynamics.terramechanics.update_patch_displacement`)."""
    n = j.shape[0]
    K, Ky = const[10], const[11]
    jn = np.empty((n, 2))
    for i in range(n):
        L = length[i]
        x = abs(rolling_speed[i]) * dt / max(L, 1e-300)
        zero = 1.0 if x == 0.0 else 0.0
        gain = (dt * (zero - math.expm1(-x))) / (x + zero)
        e = math.exp(-x)
        a = j[i, 0] * e + slip_velocity[i, 0] * gain
        b = j[i, 1] * e + slip_velocity[i, 1] * gain
        rho = math.hypot(a * (1.0 / K), b * (1.0 / Ky))
        s = saturation / max(rho, saturation) * (1.0 if L > 0.0 else 0.0)
        jn[i, 0] = a * s
        jn[i, 1] = b * s
    return jn


@numba.njit(cache=True)
def step_forces(values, n, on, j, const):  # pragma: no cover - numba
    """Stage 2 from :func:`pack_stage1`'s ``values``, the wheels' ``on`` (n,) and the
    patch displacement ``j`` (n, 2): (spatial force (n, 6) = [moment about the wheel
    centre, force], world; the wheel_state rows (n, 6) with the blended drawbar pull),
    by :func:`forces`."""
    (_, axle, n_W, forward, lateral, r_c, state, N, slip_velocity, _, length, ws, fx, fy,
     m_soil) = _unpack(values, n)  # fmt: skip
    F, tau, drawbar = forces(j, N, slip_velocity, length, ws, fx, fy, m_soil, n_W, forward,
                             lateral, r_c, axle, on, const)  # fmt: skip
    F6 = np.empty((n, 6))
    F6[:, :3] = tau
    F6[:, 3:] = F
    rows = state.copy()
    rows[:, 4] = drawbar
    return F6, rows


@numba.njit(cache=True)
def step_patch(values, n, j, dt, const, saturation):  # pragma: no cover - numba
    """:func:`patch_update` from :func:`pack_stage1`'s ``values``."""
    parts = _unpack(values, n)
    return patch_update(j, parts[8], parts[9], parts[10], dt, const, saturation)
