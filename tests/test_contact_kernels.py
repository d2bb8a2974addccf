"""The compiled wheel-soil contact step (dynamics/contact_kernels.py) against the
terramechanics functions it fuses (dynamics/terramechanics.py), on random wheel states:
rolling, at rest (the static patch), off the raster, out of contact."""

import dataclasses as dc

import numpy as np
import pytest

from lunar_drake.dynamics import contact_kernels as ck
from lunar_drake.dynamics import terramechanics as tm

V_EPS, DIR_EPS = 0.08, 0.02


def _unit(a):
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def _cross(a, b):
    return np.cross(a, b)


def _case(g, n=6, *, at_rest=False):
    wheel = tm.WheelParams(radius_m=0.3, width_m=0.25, grouser_height_m=0.01)
    n_W = _unit(g.normal(0, 0.1, (n, 3)) + np.array([0.0, 0.0, 1.0]))
    axle = _unit(_cross(n_W, _unit(g.normal(0, 1, (n, 3)))))
    forward = _unit(_cross(axle, n_W))
    lateral = _cross(n_W, forward)
    speed = 0.0 if at_rest else 1.0
    v = forward * g.uniform(-0.3, 0.3, (n, 1)) * speed + g.normal(0, 0.01, (n, 3))
    spin = g.uniform(0.2, 1.5, (n, 1)) * g.choice([-1.0, 1.0], (n, 1))  # rolling: r w >= 6 cm/s
    wv = axle * spin * speed + g.normal(0, 0.01, (n, 3))
    sinkage = g.uniform(-0.02, 0.05, n)
    on = g.uniform(size=n) > 0.2
    return wheel, dict(v=v, wv=wv, axle=axle, sinkage=sinkage, n_W=n_W, forward=forward,
                       lateral=lateral, on=on)  # fmt: skip


def _reference(c, wheel, soil, patch, j, r_c, dt):
    """The numpy statement of the step (as WheelRegolithContact computed it)."""
    on = c["on"]
    r = wheel.radius_m
    z = np.where(on, np.minimum(np.maximum(c["sinkage"], -1.0), r), -1.0)
    v_x = np.einsum("ij,ij->i", c["v"], c["forward"])
    v_y = np.einsum("ij,ij->i", c["v"], c["lateral"])
    z_dot = -np.einsum("ij,ij->i", c["v"], c["n_W"])
    omega_r = np.einsum("ij,ij->i", c["wv"], c["axle"]) * r
    slip = tm.slip_ratio(omega_r=omega_r, v=v_x, v_eps=V_EPS)
    beta = tm.slip_angle(v_x=v_x, v_y=v_y, v_eps=V_EPS)
    f = tm.wheel_forces(slip=slip, slip_angle=beta, z=z, wheel=wheel, soil=soil,
                        direction=tm.travel_direction(v_x + omega_r, v_eps=DIR_EPS))  # fmt: skip
    N = tm.normal_force(z, z_dot, vertical=f.vertical, wheel=wheel, soil=soil) * on
    ws = tm.static_weight(omega_r, patch=patch)
    u = tm.patch_slip_velocity(v_x=v_x, v_y=v_y, omega_r=omega_r)
    L = tm.patch_length(z, wheel=wheel, soil=soil)
    fx, fy, m = f.drawbar_pull, f.lateral, -f.torque
    if ws.max() > 0:
        fs = tm.patch_static_force(j, slip_velocity=u, N=N, length=L, wheel=wheel, soil=soil,
                                   damping_ratio=patch.damping_ratio)  # fmt: skip
        Fs = fs[:, :1] * c["forward"] + fs[:, 1:] * c["lateral"]
        m_static = np.einsum("ij,ij->i", _cross(r_c, Fs), c["axle"])
        fx, fy, m = (ws * fs[:, 0] + (1 - ws) * fx, ws * fs[:, 1] + (1 - ws) * fy,
                     ws * m_static + (1 - ws) * m)  # fmt: skip
    F = (N[:, None] * c["n_W"] + fx[:, None] * c["forward"] + fy[:, None] * c["lateral"])
    F = F * on[:, None]
    M = _cross(r_c, F)
    tau = M + ((m * on) - np.einsum("ij,ij->i", M, c["axle"]))[:, None] * c["axle"]
    state = np.stack([np.where(on, c["sinkage"], 0.0), N, slip, beta, fx * on, ~on], axis=1)
    jn = tm.update_patch_displacement(j, slip_velocity=u, rolling_speed=omega_r, length=L,
                                      dt=dt, soil=soil,
                                      saturation_moduli=patch.saturation_moduli)  # fmt: skip
    return F, tau, state, jn


@pytest.mark.parametrize("at_rest", [False, True])
@pytest.mark.parametrize("rear", [0.0, 0.3])
def test_contact_step_matches_the_terramechanics_functions(at_rest, rear):
    g = np.random.default_rng(11 + int(at_rest) + int(10 * rear))
    soil = dc.replace(tm.soil_preset("lunar_regolith"), rear_angle_ratio=rear)
    patch = tm.ShearPatchParams()
    blended = 0
    for _ in range(20):
        wheel, c = _case(g, at_rest=at_rest)
        j = g.normal(0, 0.01, (6, 2))
        r_c = -wheel.radius_m * c["n_W"]
        par, const = ck.soil_constants(wheel=wheel, soil=soil, patch=patch, v_eps=V_EPS,
                                       direction_eps=DIR_EPS)  # fmt: skip
        state, N, u, omega_r, L, ws, fx, fy, m = ck.kinematics(
            c["v"], c["wv"], c["axle"], c["sinkage"], c["n_W"], c["forward"], c["lateral"],
            c["on"], par, const)  # fmt: skip
        F, tau, drawbar = ck.forces(j, N, u, L, ws, fx, fy, m, c["n_W"], c["forward"],
                                    c["lateral"], r_c, c["axle"], c["on"], const)  # fmt: skip
        jn = ck.patch_update(j, u, omega_r, L, 0.01, const, patch.saturation_moduli)
        state[:, 4] = drawbar
        F_r, tau_r, state_r, jn_r = _reference(c, wheel, soil, patch, j, r_c, 0.01)
        scale = max(1.0, float(np.abs(F_r).max()))
        np.testing.assert_allclose(F, F_r, rtol=1e-11, atol=1e-11 * scale)
        np.testing.assert_allclose(tau, tau_r, rtol=1e-11, atol=1e-11 * scale)
        np.testing.assert_allclose(state, state_r, rtol=1e-11, atol=1e-11 * scale)
        np.testing.assert_allclose(jn, jn_r, rtol=1e-12, atol=1e-15)
        blended += int(ws.max() > 0)
        assert np.all(F[~c["on"]] == 0.0)
    # the cases exercise what they are named for: the patch blends in only at rest
    assert blended == (20 if at_rest else 0)
