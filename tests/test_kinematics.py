"""Rover kinematics core: skid steer, explicit steer (all modes, steering offset), servos."""

import math

import numpy as np
import pytest

from lunar_drake.dynamics.kinematics import (
    SteeringLimitError,
    WheelGeometry,
    explicit_steer_commands,
    explicit_steer_twist,
    skid_steer_twist,
    skid_steer_wheel_speeds,
    wheel_servo_gains,
)
from lunar_drake.errors import ConfigError, OutOfRangeError


def _geom(offset=0.0, **kw):
    return WheelGeometry.rectangular(
        wheelbase=1.3, track=1.1, wheel_radius=0.25, steering_offset=offset, **kw
    )


def _twists(n, seed, *, vy=True, wz=True, vx=True):
    t = np.random.default_rng(seed).uniform(-0.5, 0.5, size=(n, 3))
    t[:, 0] *= vx
    t[:, 1] *= vy
    t[:, 2] *= wz
    return t


# ------------------------------------------------------------------------------ skid steer


@pytest.mark.parametrize("n_axles", [2, 3])
@pytest.mark.parametrize("icr_scale", [1.0, 1.6])
def test_skid_round_trip_is_exact(n_axles, icr_scale):
    g = WheelGeometry.rectangular(wheelbase=1.0, track=0.9, wheel_radius=0.2, n_axles=n_axles)
    t = _twists(50, 1, vy=False)
    w = skid_steer_wheel_speeds(t, geometry=g, icr_scale=icr_scale)
    assert w.shape == (50, 2 * n_axles)
    back = skid_steer_twist(w, geometry=g, icr_scale=icr_scale)
    np.testing.assert_allclose(back, t, atol=1e-12)
    # single twist, unbatched
    np.testing.assert_allclose(
        skid_steer_twist(skid_steer_wheel_speeds(t[3], geometry=g), geometry=g), t[3], atol=1e-12
    )


def test_skid_side_speeds():
    g = WheelGeometry.rectangular(wheelbase=1.0, track=0.8, wheel_radius=0.2)
    w = skid_steer_wheel_speeds([0.3, 0.0, 0.5], geometry=g)
    left = g.p_BS[:, 1] > 0
    # turning left: right side faster; v_side = vx -+ wz * track / 2
    np.testing.assert_allclose(w[left], (0.3 - 0.5 * 0.4) / 0.2)
    np.testing.assert_allclose(w[~left], (0.3 + 0.5 * 0.4) / 0.2)
    # an ICR expansion factor widens the effective track
    w2 = skid_steer_wheel_speeds([0.3, 0.0, 0.5], geometry=g, icr_scale=1.5)
    np.testing.assert_allclose(w2[~left], (0.3 + 0.5 * 0.6) / 0.2)


def test_skid_rejects_sideways_motion_and_one_sided_layouts():
    g = _geom()
    with pytest.raises(ConfigError, match=r"vy = 0\.1"):
        skid_steer_wheel_speeds([0.2, 0.1, 0.0], geometry=g)
    with pytest.raises(ConfigError, match=r"-0\.05"):
        skid_steer_wheel_speeds([[0.2, 0.0, 0.0], [0.1, -0.05, 0.0]], geometry=g)
    one_side = WheelGeometry(p_BS=[[0.5, 0.4], [-0.5, 0.4]])
    with pytest.raises(ConfigError, match="both sides"):
        skid_steer_wheel_speeds([0.2, 0.0, 0.0], geometry=one_side)


# -------------------------------------------------------------------------- explicit steer


MODES = {
    "ackermann": dict(vy=False),
    "crab": dict(wz=False),
    "point_turn": dict(vx=False, vy=False),
    "auto": {},
}


@pytest.mark.parametrize("offset", [0.0, 0.12, -0.07])
@pytest.mark.parametrize("mode", list(MODES))
def test_explicit_round_trip_all_modes(mode, offset):
    g = _geom(offset)
    t = _twists(40, 7, **MODES[mode])
    cmd = explicit_steer_commands(t, geometry=g, mode=mode)
    delta, omega = cmd  # unpacks as a pair
    assert delta.shape == omega.shape == (40, 4)
    assert np.all(np.abs(delta) <= math.pi / 2 + 1e-12)
    assert not cmd.saturated.any()
    np.testing.assert_allclose(explicit_steer_twist(delta, omega, geometry=g), t, atol=1e-12)
    for i in (0, 13):  # unbatched calls give the same rows
        d1, w1 = explicit_steer_commands(t[i], geometry=g, mode=mode)
        np.testing.assert_array_equal(d1, delta[i])
        np.testing.assert_allclose(w1, omega[i], rtol=0, atol=1e-15)


def test_wheel_centre_has_no_side_slip_and_rolls_at_commanded_speed():
    """Direct check of the offset derivation: v_c = v + wz z x c is along h, |v_c| = r w."""
    g = _geom(0.15)
    t = _twists(30, 3)
    delta, omega = explicit_steer_commands(t, geometry=g)
    h = np.stack([np.cos(delta), np.sin(delta)], -1)
    left = np.stack([-np.sin(delta), np.cos(delta)], -1)
    c = g.p_BS + 0.15 * left
    v_c = np.stack(
        [t[:, None, 0] - t[:, None, 2] * c[..., 1], t[:, None, 1] + t[:, None, 2] * c[..., 0]], -1
    )
    np.testing.assert_allclose(np.sum(v_c * left, -1), 0.0, atol=1e-13)
    np.testing.assert_allclose(np.sum(v_c * h, -1), 0.25 * omega, atol=1e-13)


@pytest.mark.parametrize("offset", [0.0, 0.1])
def test_point_turn_wheels_are_tangent_to_the_circle(offset):
    g = _geom(offset)
    wz = 0.4
    delta, omega = explicit_steer_commands([0.0, 0.0, wz], geometry=g, mode="point_turn")
    h = np.stack([np.cos(delta), np.sin(delta)], -1)
    np.testing.assert_allclose(np.sum(h * g.p_BS, -1), 0.0, atol=1e-14)  # h perpendicular to p
    # rolling speed: +-wz |p| along h, minus the offset term
    radius = np.linalg.norm(g.p_BS, axis=1)
    np.testing.assert_allclose(np.abs(0.25 * omega + wz * offset), wz * radius, atol=1e-14)
    # the front-left wheel turns towards -45 deg-ish and rolls backwards (turning left)
    assert delta[0] < 0 and 0.25 * omega[0] + wz * offset < 0


def test_crab_angles_all_equal():
    g = _geom(0.1)
    for vx, vy in [(0.2, 0.1), (-0.2, 0.1), (0.0, -0.3), (0.1, -0.25)]:
        delta, omega = explicit_steer_commands([vx, vy, 0.0], geometry=g, mode="crab")
        expected = math.atan(vy / vx) if vx else math.copysign(math.pi / 2, vy)
        np.testing.assert_allclose(delta, np.full(4, expected), atol=1e-14)
        np.testing.assert_allclose(0.25 * omega * np.cos(delta), vx, atol=1e-14)
        np.testing.assert_allclose(0.25 * omega * np.sin(delta), vy, atol=1e-14)


@pytest.mark.parametrize("offset", [0.0, 0.12])
def test_ackermann_common_instantaneous_centre(offset):
    g = _geom(offset)
    for vx, wz in [(0.3, 0.2), (0.3, -0.5), (-0.2, 0.4), (0.1, 1.0)]:
        delta, _omega = explicit_steer_commands([vx, 0.0, wz], geometry=g, mode="ackermann")
        icr = np.array([0.0, vx / wz])
        left = np.stack([-np.sin(delta), np.cos(delta)], -1)
        c = g.p_BS + offset * left
        d = icr - c  # ICR lies on every wheel's axle line: cross(l, icr - c) = 0
        np.testing.assert_allclose(left[:, 0] * d[:, 1] - left[:, 1] * d[:, 0], 0.0, atol=1e-13)
        # front and rear steer in opposite directions (double Ackermann)
        assert np.all(np.sign(delta[:2]) == -np.sign(delta[2:]))


def test_front_steer_ackermann_about_fixed_rear_axle():
    p = [[1.2, 0.5], [1.2, -0.5], [0.0, 0.5], [0.0, -0.5]]  # origin on the rear axle
    g = WheelGeometry(p_BS=p, steerable=[True, True, False, False], wheel_radius=0.2)
    delta, omega = explicit_steer_commands([0.4, 0.0, 0.3], geometry=g, mode="ackermann")
    np.testing.assert_array_equal(delta[2:], 0.0)
    # tan(delta) = L / (R -+ track / 2), R = vx / wz
    r = 0.4 / 0.3
    np.testing.assert_allclose(np.tan(delta[:2]), [1.2 / (r - 0.5), 1.2 / (r + 0.5)], rtol=1e-14)
    np.testing.assert_allclose(
        explicit_steer_twist(delta, omega, geometry=g), [0.4, 0.0, 0.3], atol=1e-13
    )
    with pytest.raises(SteeringLimitError, match="not steerable"):
        explicit_steer_commands([0.1, 0.2, 0.0], geometry=g, mode="crab")


def test_reversing_keeps_angles_and_flips_speeds():
    g = _geom(0.1)
    t = _twists(20, 11)
    d1, w1 = explicit_steer_commands(t, geometry=g)
    d2, w2 = explicit_steer_commands(-t, geometry=g)
    np.testing.assert_allclose(d2, d1, atol=1e-14)
    np.testing.assert_allclose(w2, -w1, atol=1e-14)


def test_zero_twist_keeps_previous_angles():
    g = _geom(0.1)
    prev = np.array([0.3, -0.2, 0.1, 1.0])
    delta, omega = explicit_steer_commands([0.0, 0.0, 0.0], geometry=g, previous_delta=prev)
    np.testing.assert_array_equal(delta, prev)
    np.testing.assert_array_equal(omega, 0.0)
    delta, omega = explicit_steer_commands(np.zeros(3), geometry=g)
    np.testing.assert_array_equal(delta, 0.0)
    # a wheel whose steering axis is the ICR keeps its angle and spins at -wz o / r
    fl, wz = g.p_BS[0], 0.4
    twist = [wz * fl[1], -wz * fl[0], wz]  # v = -wz z x p_fl, so v_p(fl) = 0
    delta, omega = explicit_steer_commands(twist, geometry=g, previous_delta=prev)
    assert delta[0] == prev[0]
    np.testing.assert_allclose(omega[0], -wz * 0.1 / 0.25)
    assert np.all(delta[1:] != prev[1:])


def test_steering_limits_raise_or_clip():
    g = _geom(0.0, steering_limit=math.radians(30))
    twist = [0.2, 0.2, 0.0]  # needs 45 deg on every wheel
    with pytest.raises(SteeringLimitError) as err:
        explicit_steer_commands(twist, geometry=g)
    msg = str(err.value)
    assert "'fl'" in msg and "45.000 deg" in msg and "30.000 deg" in msg
    assert isinstance(err.value, ConfigError) and isinstance(err.value, ValueError)
    cmd = explicit_steer_commands(twist, geometry=g, clip=True)
    np.testing.assert_allclose(cmd.delta, math.radians(30))
    np.testing.assert_allclose(cmd.needed_delta, math.radians(45))
    assert cmd.saturated.all()
    # speed = projection of the needed velocity on the saturated heading
    np.testing.assert_allclose(cmd.omega, 0.2 * math.sqrt(2) * math.cos(math.radians(15)) / 0.25)
    # within limits nothing is flagged, and flipping brings -150 deg into range
    cmd = explicit_steer_commands([-0.3, -0.1, 0.0], geometry=g)
    assert not cmd.saturated.any()
    np.testing.assert_allclose(cmd.delta, math.atan(1 / 3))
    assert np.all(cmd.omega < 0)


def test_mode_checks():
    g = _geom()
    with pytest.raises(ConfigError, match=r"vy = 0\.1"):
        explicit_steer_commands([0.2, 0.1, 0.3], geometry=g, mode="ackermann")
    with pytest.raises(ConfigError, match=r"wz = 0\.3"):
        explicit_steer_commands([0.2, 0.1, 0.3], geometry=g, mode="crab")
    with pytest.raises(ConfigError, match=r"vx = 0\.2"):
        explicit_steer_commands([0.2, 0.0, 0.3], geometry=g, mode="point_turn")
    with pytest.raises(ConfigError, match="'diagonal'"):
        explicit_steer_commands([0.2, 0.0, 0.3], geometry=g, mode="diagonal")


def test_geometry_validation():
    with pytest.raises(ConfigError, match="shape"):
        WheelGeometry(p_BS=[1.0, 2.0])
    with pytest.raises(OutOfRangeError, match="wheel_radius"):
        WheelGeometry(wheel_radius=0.0)
    with pytest.raises(OutOfRangeError, match="steering_limit"):
        WheelGeometry(steering_limit=4.0)
    with pytest.raises(ConfigError, match="steering_offset"):
        WheelGeometry(steering_offset=[0.1, 0.2])
    g = WheelGeometry()
    assert g.n_wheels == 4 and g.names[0] == "wheel0"
    with pytest.raises(ValueError):
        g.p_BS[0, 0] = 3.0  # read-only


def test_servo_gains_place_the_bandwidth():
    inertia = 0.8
    for zeta, f_bw in [(math.sqrt(0.5), 4.0), (1.0, 2.0), (0.4, 10.0)]:
        kp, kd = wheel_servo_gains(inertia=inertia, bandwidth_hz=f_bw, damping_ratio=zeta)
        wn = math.sqrt(kp / inertia)
        assert kd / (2 * inertia * wn) == pytest.approx(zeta, rel=1e-12)
        s = 2j * math.pi * f_bw
        gain = abs(kp / (inertia * s * s + kd * s + kp))
        assert gain == pytest.approx(1 / math.sqrt(2), rel=1e-9)
    kp, kd = wheel_servo_gains(inertia=1.0, bandwidth_hz=1.0, damping_ratio=math.sqrt(0.5))
    assert kp == pytest.approx((2 * math.pi) ** 2) and kd == pytest.approx(
        math.sqrt(2) * 2 * math.pi
    )
    with pytest.raises(OutOfRangeError, match="inertia"):
        wheel_servo_gains(inertia=-1.0, bandwidth_hz=1.0, damping_ratio=0.7)


@pytest.mark.parametrize("offset", [0.0, 0.07])
def test_one_twist_compiled_path_agrees_with_the_batch_path(offset):
    """A single twist (the flight software's call) goes through one compiled call; it
    gives the batch path's results: saturation to the bit, angles, speeds and needed
    angles to 1e-13 relative, sideways and standing twists and clipped wheels included. (The
    compiled call uses libm's atan2 and hypot; numpy's vector loops on an AVX-512 machine
    use their own SIMD forms, 1 ulp apart from libm's in ~8 % of random atan2 calls.)"""
    g = _geom(offset, steering_limit=math.radians(70))
    rng = np.random.default_rng(11)
    special = [[0.0, 0.3, 0.0], [0.0, -0.3, 0.0], [0.0, 0.0, 0.0], [1e-12, 0.0, 0.0],
               [0.2, 0.2, 0.0], [0.0, 0.0, 0.4]]  # fmt: skip
    twists = np.r_[_twists(400, 5), special]
    for k, t in enumerate(twists):
        prev = rng.uniform(-1.2, 1.2, 4) if k % 3 else None
        one = explicit_steer_commands(t, geometry=g, previous_delta=prev, clip=True)
        batch = explicit_steer_commands(t[None], geometry=g, previous_delta=prev, clip=True)
        np.testing.assert_array_equal(one.saturated, batch.saturated[0])
        for name in ("delta", "omega", "needed_delta"):
            np.testing.assert_allclose(getattr(one, name), getattr(batch, name)[0],
                                       rtol=1e-13, atol=1e-15, err_msg=name)  # fmt: skip
    assert explicit_steer_commands([0.05, 0.3, 0.0], geometry=g, clip=True).saturated.any()
    with pytest.raises(SteeringLimitError):  # without clip the batch path's error
        explicit_steer_commands([0.05, 0.3, 0.0], geometry=g)
