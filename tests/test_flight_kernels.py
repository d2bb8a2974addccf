"""The flight software's compiled per-tick calls against the functions they fuse: the
estimator's predict tick and pose, the rover kinematics' steering, the follower's aim
point, and the energy meter's step (each checked against its own numpy formulation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lunar_drake.autonomy import ekf
from lunar_drake.autonomy import estimator_tick as core
from lunar_drake.autonomy.follower import aim_point
from lunar_drake.autonomy.odometry import body_displacement
from lunar_drake.dynamics.kinematics import (
    explicit_steer_commands,
    explicit_steer_one,
    skid_twist_map,
    steer_kernel_args,
    wheel_geometry_for,
)
from lunar_drake.models.rover_description import rover_preset
from lunar_drake.power.actuator_energy import energy_step


def _state(rng, config, n_wheels=4):
    angles, started, size = core.layout(n_wheels)
    yaw = rng.uniform(-3, 3)
    x, P = ekf.initial_state(
        p0=rng.normal(0, 5, 3), q0=[math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)],
        config=config,
    )  # fmt: skip
    x[10] = 0.1  # slip
    s = np.zeros(size)
    s[core.X] = x
    s[core.PC] = (P + 0.01 * np.diag(rng.uniform(0, 1, ekf.N_ERR))).ravel()
    s[core.FIX] = [1.0, 0.0, 0.0, 0.0]
    s[angles] = rng.normal(0, 10, n_wheels)
    s[started] = 1.0
    return s, angles


@pytest.mark.parametrize("preset", ["krex2_rp", "husky_rp"])
def test_the_estimator_tick_is_the_displacement_and_predict_it_fuses(preset):
    desc = rover_preset(preset)
    g = wheel_geometry_for(desc)
    skid = desc.steering == "skid"
    config = ekf.EstimatorConfig(slip_vs_slope=[[-10.0, 0.2], [0.0, 0.1], [10.0, 0.3]])
    params = ekf.kernel_params(config)
    pinv = skid_twist_map(g) if skid else np.zeros((2, 4))
    rng = np.random.default_rng(3)
    for _ in range(30):
        s, angles = _state(rng, config)
        new_angles = s[angles] + rng.normal(0, 0.05, 4)
        steer = rng.uniform(-0.5, 0.5, 4)
        imu = rng.normal(0, 0.02, 6)
        fix = rng.normal(0, 1, 4)
        got = core.tick(s, new_angles, fix, imu, steer, 0.01, skid, pinv, g.p_BS,
                        g.steering_offset, g.wheel_radius, *params)  # fmt: skip
        d = body_displacement(new_angles - s[angles], steer, geometry=g, skid=skid)
        x, P = ekf.predict(s[core.X], s[core.PC].reshape(ekf.N_ERR, ekf.N_ERR),
                           gyro_radps=imu[:3], d_body=d[:2], dt=0.01, config=config)  # fmt: skip
        np.testing.assert_allclose(got[core.X], x, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(got[core.PC], P.ravel(), rtol=1e-12, atol=1e-16)
        np.testing.assert_array_equal(got[core.FIX], fix)
        np.testing.assert_array_equal(got[angles], new_angles)
        assert got[-1] == 1.0
        pose, cov = ekf.pose_and_covariance(got[core.X], got[core.PC].reshape(14, 14))
        np.testing.assert_array_equal(core.pose(got), pose)
        np.testing.assert_array_equal(core.pose_covariance(got), cov.ravel())
    # Not started: nothing is predicted, the sensors are only recorded.
    s[-1] = 0.0
    got = core.tick(s, new_angles, fix, imu, steer, 0.01, skid, pinv, g.p_BS,
                    g.steering_offset, g.wheel_radius, *params)  # fmt: skip
    np.testing.assert_array_equal(got[: core.FIX.start], s[: core.FIX.start])
    np.testing.assert_array_equal(got[angles], new_angles)


def test_a_fix_is_new_only_once_started_and_when_it_changes():
    s, _ = _state(np.random.default_rng(1), ekf.EstimatorConfig())
    assert not core.fix_is_new(s, s[core.FIX].copy())  # the same fix
    assert core.fix_is_new(s, np.array([0.0, 1.0, 0.0, 0.0]))
    assert not core.fix_is_new(s, np.zeros(4))  # the sensor's initial value
    s[-1] = 0.0
    assert not core.fix_is_new(s, np.array([0.0, 1.0, 0.0, 0.0]))  # not started


def test_one_compiled_steering_call_is_the_clipped_steering_commands():
    g = wheel_geometry_for(rover_preset("krex2_rp"))
    args = steer_kernel_args(g)
    rng = np.random.default_rng(5)
    twists = rng.normal(0, [0.2, 0.2, 0.3], (300, 3))
    twists[::10] = 0.0  # standing still: the previous angles are kept
    twists[5::10, :2] = 0.0  # point turns
    twists[7::10, 1] = 2.0  # far sideways: some wheels at their limit
    for t in twists:
        prev = rng.uniform(-1, 1, 4)
        cmd = explicit_steer_commands(t, geometry=g, previous_delta=prev, clip=True)
        delta, omega = explicit_steer_one(*t, prev, args)
        np.testing.assert_array_equal(delta, cmd.delta)
        np.testing.assert_array_equal(omega, cmd.omega)


def _aim_reference(xy, wp, index, lookahead):
    """The aim point in numpy vector form (the follower's original formulation)."""
    p = np.asarray(xy, float)
    n = len(wp)
    while index < n - 1 and np.hypot(*(wp[index + 1] - p)) < lookahead:
        index += 1
    for k in range(index, n - 1):
        a, b = wp[k], wp[k + 1]
        d, f = b - a, a - p
        A = float(d @ d)
        if A == 0.0:
            continue
        B, C = 2.0 * float(f @ d), float(f @ f) - lookahead**2
        disc = B * B - 4.0 * A * C
        if disc < 0.0:
            continue
        t = (-B + math.sqrt(disc)) / (2.0 * A)
        if 0.0 <= t <= 1.0:
            return a + t * d, k
    return wp[-1].copy(), max(index, n - 2 if n >= 2 else 0)


def test_the_compiled_aim_point_is_the_vector_formulation():
    rng = np.random.default_rng(0)
    for trial in range(3000):
        n = int(rng.integers(1, 8))
        wp = np.cumsum(rng.normal(0, 3, (n, 2)), axis=0)
        if trial % 7 == 0 and n > 1:
            wp[1] = wp[0]  # a zero-length leg
        xy = rng.normal(0, 5, 2)
        index = int(rng.integers(0, max(n - 1, 1)))
        lookahead = float(rng.uniform(0.5, 4.0))
        aim, k = aim_point(xy, wp, index, lookahead)
        ref, k_ref = _aim_reference(xy, wp, index, lookahead)
        assert k == k_ref
        np.testing.assert_allclose(aim, ref, rtol=0, atol=1e-12)


def test_the_energy_step_is_the_grouped_positive_power():
    rng = np.random.default_rng(2)
    tau, state = rng.normal(0, 5, 10), rng.normal(0, 2, 30)
    ia, iv = np.array([0, 2, 3, 7, 9]), np.array([20, 21, 25, 28, 29])
    group = np.array([0, 0, 1, 1, 2])
    e0 = rng.uniform(0, 100, 3)
    ref = e0 + 0.01 * np.array(
        [sum(max(tau[a] * state[v], 0.0) for a, v, g in zip(ia, iv, group, strict=True)
              if g == k)
         for k in range(3)]
    )  # fmt: skip
    np.testing.assert_allclose(energy_step(e0, tau, state, ia, iv, group, 0.01), ref, rtol=1e-15)


def test_aim_point_refuses_a_path_that_is_not_a_list_of_points():
    from lunar_drake.errors import ConfigError

    for bad in ([1.0, 2.0, 3.0], np.zeros((0, 2)), np.zeros((3, 3))):
        with pytest.raises(ConfigError, match="waypoints have shape"):
            aim_point((0.0, 0.0), bad, 0, 1.0)
