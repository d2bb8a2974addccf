"""Tests for lunar_drake.dynamics.terramechanics (pure numpy core)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import quad

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics.terramechanics import (
    GRC1,
    LUNAR_REGOLITH,
    ImmobilizedError,
    SoilParams,
    WheelParams,
    bekker_load,
    compaction_resistance,
    contact_damping,
    contact_stiffness,
    drawbar_pull,
    equilibrium_sinkage,
    normal_force,
    shear_stress,
    slip_angle,
    slip_ratio,
    slip_vs_drawbar_curve,
    soil_preset,
    static_sinkage,
    travel_direction,
    wheel_forces,
)
from lunar_drake.errors import ConfigError, OutOfRangeError, format_value
from lunar_drake.moon import GRAVITY_MPS2

WHEEL = WheelParams(radius_m=0.25, width_m=0.2)
W_WHEEL = 50.0 * GRAVITY_MPS2  # 81 N: a ~50 kg-per-wheel rover on the Moon
PRESETS = (LUNAR_REGOLITH, GRC1)


# ------------------------------------------------------------------ hand-computed values
def test_bekker_load_hand_computed():
    # Lunar soil n = 1, k_c = 1400, k_phi = 820000; r = 0.25 m, b = 0.2 m:
    # k_c + b k_phi = 1400 + 164000 = 165400 N/m^2; sqrt(2 r) = sqrt(0.5) = 0.70710678
    # W = (3 - 1)/3 * 165400 * 0.70710678 * z^1.5 = 77970.3077 * z^1.5
    # z = 0.01 m -> z^1.5 = 0.001 -> W = 77.9703077 N
    assert bekker_load(0.01, wheel=WHEEL, soil=LUNAR_REGOLITH) == pytest.approx(77.9703077, 1e-8)
    # n = 0.5, k_c = 1000, k_phi = 5e5: k_c + b k_phi = 1000 + 100000 = 101000
    # W = 2.5/3 * 101000 * 0.70710678 * z^1 = 59514.8207 z -> z = 0.02: W = 1190.29641 N
    soil = SoilParams(name="half", n=0.5, k_c=1000.0, k_phi=5.0e5)
    assert bekker_load(0.02, wheel=WHEEL, soil=soil) == pytest.approx(1190.29641, 1e-8)
    # Out of contact: zero.
    assert bekker_load(-0.01, wheel=WHEEL, soil=LUNAR_REGOLITH) == 0.0


def test_static_sinkage_hand_computed_and_round_trip():
    # z = (W / 77970.3077)^(2/3); W = 81 N -> (1.038857e-3)^(2/3) = 0.01025740 m
    z = static_sinkage(W_WHEEL, wheel=WHEEL, soil=LUNAR_REGOLITH)
    assert z == pytest.approx(0.01025740, rel=1e-6)
    loads = np.array([1.0, 20.0, 81.0, 500.0, 3000.0])
    for soil in (*PRESETS, SoilParams(name="half", n=0.5, k_c=1000.0, k_phi=5.0e5)):
        zz = static_sinkage(loads, wheel=WHEEL, soil=soil)
        np.testing.assert_allclose(bekker_load(zz, wheel=WHEEL, soil=soil), loads, rtol=1e-12)
        assert np.all(np.diff(zz) > 0)
    assert static_sinkage(0.0, wheel=WHEEL, soil=LUNAR_REGOLITH) == 0.0


def test_compaction_resistance_hand_computed():
    # Bekker's closed form (kept as a classical reference; the wheel model integrates
    # sigma sin(theta) instead): R_c = (k_c + b k_phi) z^(n+1)/(n+1) = 165400 * 1e-4 / 2.
    assert compaction_resistance(0.01, wheel=WHEEL, soil=LUNAR_REGOLITH) == pytest.approx(8.27)
    # n = 0.5: 101000 * 0.02^1.5 / 1.5 = 101000 * 0.00282843 / 1.5 = 190.447426 N
    soil = SoilParams(name="half", n=0.5, k_c=1000.0, k_phi=5.0e5)
    assert compaction_resistance(0.02, wheel=WHEEL, soil=soil) == pytest.approx(190.447426, 1e-8)
    # With theta_m = 0 (c1 = c2 = 0) and n = 1 the Wong-Reece resistance
    # r b k r int_0^th1 (cos t - cos th1) sin t dt = b k r^2 (1 - cos th1)^2 / 2
    # = b k z^2 / 2 -- Bekker's R_c for n = 1 exactly.
    flat = SoilParams(name="flat", c1=0.0, c2=0.0)
    f = wheel_forces(slip=0.3, slip_angle=0.0, z=0.01, wheel=WHEEL, soil=flat)
    assert float(f.resistance) == pytest.approx(8.27, rel=1e-9)


def test_janosi_hanamoto_shear_hand_computed():
    # sigma = 1000 Pa, j = K = 0.018 m, c = 170 Pa, phi = 35 deg (tan = 0.70020754):
    # tau = (170 + 700.20754) * (1 - e^-1) = 870.20754 * 0.63212056 = 550.076075 Pa
    tau = shear_stress(1000.0, 0.018, soil=LUNAR_REGOLITH)
    assert tau == pytest.approx(550.076075, 1e-8)
    assert shear_stress(1000.0, -0.018, soil=LUNAR_REGOLITH) == pytest.approx(-550.076075, 1e-8)
    assert shear_stress(1000.0, 0.0, soil=LUNAR_REGOLITH) == 0.0
    # Large displacement saturates at the Mohr-Coulomb strength 870.20754 Pa.
    assert shear_stress(1000.0, 10.0, soil=LUNAR_REGOLITH) == pytest.approx(870.20754, 1e-7)


def test_vertical_load_closed_form_without_shear_or_peak_shift():
    # s = 0 gives j = r[(th1 - t) - (sin th1 - sin t)] != 0, so remove shear with
    # c = 0, phi = 0; c1 = c2 = 0 puts theta_m at the bottom. Then (n = 1)
    # V = r b k r int_0^th1 (cos t - cos th1) cos t dt
    #   = b k r^2 (th1/2 + sin(2 th1)/4 - cos th1 sin th1).
    soil = SoilParams(name="noshear", c=0.0, phi=0.0, c1=0.0, c2=0.0)
    r, b = WHEEL.radius_m, WHEEL.width_m
    k = soil.k_c / b + soil.k_phi
    for z in (0.002, 0.01, 0.05):
        th1 = math.acos(1.0 - z / r)
        v = b * k * r * r * (th1 / 2 + math.sin(2 * th1) / 4 - math.cos(th1) * math.sin(th1))
        f = wheel_forces(slip=0.0, slip_angle=0.0, z=z, wheel=WHEEL, soil=soil)
        assert float(f.vertical) == pytest.approx(v, rel=1e-10)
        assert float(f.thrust) == 0.0 and float(f.torque) == 0.0


# ------------------------------------------------------------------------ quadrature
def _reference_integrals(s, beta, z, wheel, soil):
    """Adaptive-quadrature (scipy.integrate.quad) version of the model, one wheel:
    (vertical, drawbar pull, torque, lateral)."""
    r, b = wheel.radius_m, wheel.width_m
    rs = r + wheel.grouser_ratio * wheel.grouser_height_m
    th1 = math.acos(1.0 - z / r)
    thm = (soil.c1 + soil.c2 * s) * th1
    th2 = -soil.rear_angle_ratio * th1
    kk = soil.k_c / b + soil.k_phi

    def sigma(t):
        if t >= thm:
            return kk * r**soil.n * max(math.cos(t) - math.cos(th1), 0.0) ** soil.n
        ts = th1 - (t - th2) / (thm - th2) * (th1 - thm)
        return kk * r**soil.n * max(math.cos(ts) - math.cos(th1), 0.0) ** soil.n

    def integral(fun):
        opts = {"epsabs": 1e-12, "epsrel": 1e-10, "limit": 200}
        return quad(fun, th2, thm, **opts)[0] + quad(fun, thm, th1, **opts)[0]

    def tau(t):
        j = rs * ((th1 - t) - (1.0 - s) * (math.sin(th1) - math.sin(t)))
        strength = soil.c + sigma(t) * math.tan(soil.phi)
        return strength * (1.0 - math.exp(-abs(j) / soil.K)) * math.copysign(1.0, j)

    def tau_y(t):
        jy = r * (1.0 - s) * (th1 - t) * math.tan(abs(beta))
        return (soil.c + sigma(t) * math.tan(soil.phi)) * (1.0 - math.exp(-jy / soil.K_y))

    xc = math.pi / 4 - soil.phi / 2
    d1 = 1 / math.tan(xc) + math.tan(xc + soil.phi)
    d2 = 1 / math.tan(xc) + math.tan(soil.phi) / math.tan(xc) ** 2

    def bulldozing(t):
        h = r * (math.cos(t) - math.cos(th1))
        rb = d1 * (soil.c * h + d2 * soil.density * GRAVITY_MPS2 * h * h / 2)
        return rb * (r - h * math.cos(t))

    V = b * integral(lambda t: r * sigma(t) * math.cos(t) + rs * tau(t) * math.sin(t))
    DP = b * integral(lambda t: rs * tau(t) * math.cos(t) - r * sigma(t) * math.sin(t))
    T = rs * rs * b * integral(tau)
    Fy = -math.copysign(1.0, beta) * (
        r * b * integral(tau_y) + abs(math.sin(beta)) * integral(bulldozing)
    )
    return V, DP, T, Fy


@pytest.mark.parametrize(
    ("soil", "wheel"),
    [
        (LUNAR_REGOLITH, WHEEL),
        (GRC1, WHEEL),
        (SoilParams(name="rebound", n=0.8, k_c=900.0, k_phi=1.5e6, rear_angle_ratio=0.3), WHEEL),
        (LUNAR_REGOLITH, WheelParams(radius_m=0.25, width_m=0.2, grouser_height_m=0.01)),
    ],
    ids=["lunar", "grc1", "rebound", "grousers"],
)
def test_fixed_quadrature_matches_adaptive_quad(soil, wheel):
    for z in (0.004, 0.015, 0.04):
        for s, beta in ((0.05, 0.1), (0.3, -0.3), (0.9, 0.6), (-0.4, 0.2)):
            V, DP, T, Fy = _reference_integrals(s, beta, z, wheel, soil)
            f = wheel_forces(slip=s, slip_angle=beta, z=z, wheel=wheel, soil=soil)
            assert float(f.vertical) == pytest.approx(V, rel=2e-4)
            assert float(f.drawbar_pull) == pytest.approx(DP, rel=2e-4, abs=2e-4 * V)
            assert float(f.torque) == pytest.approx(T, rel=2e-4, abs=1e-9)
            assert float(f.lateral) == pytest.approx(Fy, rel=2e-4, abs=1e-9)


# ----------------------------------------------------------------------- slip behaviour
@pytest.mark.parametrize("soil", PRESETS, ids=lambda s: s.name)
def test_equilibrium_sinkage_carries_the_load_and_grows_with_slip(soil):
    W = np.array([20.0, 81.0, 300.0])
    z0 = equilibrium_sinkage(W, wheel=WHEEL, soil=soil)
    f = wheel_forces(slip=0.0, slip_angle=0.0, z=z0, wheel=WHEEL, soil=soil)
    np.testing.assert_allclose(f.vertical, W, rtol=1e-10)
    assert np.all(np.diff(z0) > 0)
    # The Wong-Reece stresses (peak ahead of the bottom) carry less than Bekker's closed
    # form at the same depth, so the wheel sits deeper.
    assert np.all(z0 > static_sinkage(W, wheel=WHEEL, soil=soil))
    # Slip-sinkage: theta_m moves forward and the rear shear pulls down as slip grows.
    s = np.array([0.0, 0.2, 0.5, 0.9])
    zs = equilibrium_sinkage(np.full(4, W_WHEEL), wheel=WHEEL, soil=soil, slip=s)
    assert np.all(np.diff(zs) > 0) and zs[-1] > 1.2 * zs[0]
    assert equilibrium_sinkage(0.0, wheel=WHEEL, soil=soil) == 0.0
    with pytest.raises(ImmobilizedError, match="past its axle"):
        equilibrium_sinkage(1e6, wheel=WHEEL, soil=soil)


@pytest.mark.parametrize("soil", PRESETS, ids=lambda s: s.name)
def test_thrust_monotone_in_slip(soil):
    s = np.linspace(0.0, 0.9, 46)
    for W in (20.0, W_WHEEL, 400.0):
        # Each slip at its own equilibrium sinkage (at a fixed depth the thrust peaks:
        # theta_m moving forward lowers the normal stress, and the load carried with it).
        c = slip_vs_drawbar_curve(W=W, wheel=WHEEL, soil=soil, slip=s)
        rising = s <= 0.7  # then it saturates (within 1 %) as the wheel digs in
        assert np.all(np.diff(c.thrust[rising]) > 0)
        assert np.all(np.diff(c.torque[rising]) > 0)
        assert c.thrust[-1] > 0.99 * c.thrust.max()
        # Bounded by the Mohr-Coulomb strength of the contact (W tan phi + c * area).
        area = WHEEL.width_m * WHEEL.radius_m * np.arccos(1 - c.sinkage / WHEEL.radius_m)
        assert np.all(c.thrust < W * math.tan(soil.phi) + soil.c * area)
    # Braking: strongly negative slip gives negative thrust.
    f = wheel_forces(slip=-0.3, slip_angle=0.0, z=0.0103, wheel=WHEEL, soil=soil)
    assert float(f.thrust) < 0 and float(f.torque) < 0


@pytest.mark.parametrize("soil", PRESETS, ids=lambda s: s.name)
def test_drawbar_pull_crosses_zero_at_small_positive_slip(soil):
    s = np.linspace(0.0, 0.99, 100)
    dp = drawbar_pull(s, W=W_WHEEL, wheel=WHEEL, soil=soil)
    assert dp[0] < 0  # rolling resistance at s = 0
    k = int(np.argmax(dp > 0))
    assert k > 0 and np.all(dp[:k] <= 0) and np.all(dp[k:] > 0)
    assert 0.0 < s[k] < 0.2
    curve = slip_vs_drawbar_curve(W=W_WHEEL, wheel=WHEEL, soil=soil)
    np.testing.assert_allclose(
        curve.drawbar_pull, drawbar_pull(curve.slip, W=W_WHEEL, wheel=WHEEL, soil=soil)
    )
    np.testing.assert_allclose(curve.drawbar_pull, curve.thrust - curve.resistance)
    assert np.all(np.diff(curve.sinkage) > 0)


def test_grousers_add_thrust_and_ratio_zero_is_a_smooth_rim():
    kw = {"slip": 0.3, "slip_angle": 0.0, "z": 0.01, "soil": LUNAR_REGOLITH}
    smooth = wheel_forces(wheel=WHEEL, **kw)
    g = WheelParams(radius_m=0.25, width_m=0.2, grouser_height_m=0.015)
    off = WheelParams(radius_m=0.25, width_m=0.2, grouser_height_m=0.015, grouser_ratio=0.0)
    assert float(wheel_forces(wheel=g, **kw).thrust) > float(smooth.thrust)
    assert float(wheel_forces(wheel=off, **kw).thrust) == float(smooth.thrust)
    assert tm.shear_radius(g) == pytest.approx(0.265)
    with pytest.raises(OutOfRangeError, match="grouser_height_m"):
        WheelParams(radius_m=0.25, grouser_height_m=0.3)


# ------------------------------------------------------------------- normal force law
def test_normal_force_continuous_at_contact_onset():
    kw = {"wheel": WHEEL, "soil": LUNAR_REGOLITH}

    def vertical(z):
        return wheel_forces(slip=0.0, slip_angle=0.0, z=z, **kw).vertical

    # V(0) = 0 for any approach speed; damping vanishes at z = 0.
    for zd in (-1.0, 0.0, 0.5, 10.0):
        assert normal_force(0.0, zd, vertical=vertical(0.0), **kw) == 0.0
        assert normal_force(-1e-3, zd, vertical=vertical(-1e-3), **kw) == 0.0
    assert contact_damping(0.0, **kw) == 0.0
    # Approaching contact the force goes continuously to 0 even when hitting fast.
    zs = np.geomspace(1e-12, 1e-3, 50)
    forces = normal_force(zs, 2.0, vertical=vertical(zs), **kw)
    assert np.all(np.diff(forces) > 0) and forces[0] < 1e-6
    # Never pulls: fast rebound clips to 0, never negative.
    z = np.linspace(-0.01, 0.05, 61)
    for zd in (-100.0, -1.0, 0.0, 1.0):
        assert np.all(normal_force(z, zd, vertical=vertical(z), **kw) >= 0.0)
    assert normal_force(0.01, -100.0, vertical=vertical(0.01), **kw) == 0.0


def test_contact_stiffness_and_damping_ratio():
    kw = {"wheel": WHEEL, "soil": LUNAR_REGOLITH}
    z = np.array([0.002, 0.01, 0.04])
    h = 1e-7
    numeric = (bekker_load(z + h, **kw) - bekker_load(z - h, **kw)) / (2 * h)
    np.testing.assert_allclose(contact_stiffness(z, **kw), numeric, rtol=1e-6)
    assert contact_stiffness(-0.01, **kw) == 0.0
    # d(z) = 2 zeta sqrt(k(z) m) with Bekker's k and m = W(z)/g: ratio zeta at every z.
    m = bekker_load(z, **kw) / GRAVITY_MPS2
    zeta = contact_damping(z, **kw) / (2.0 * np.sqrt(contact_stiffness(z, **kw) * m))
    np.testing.assert_allclose(zeta, LUNAR_REGOLITH.damping_ratio, rtol=1e-12)
    # The damping term is linear in z_dot: N = V + d(z) zd (when positive).
    V = np.array([10.0, 60.0, 300.0])
    np.testing.assert_allclose(
        normal_force(z, 0.01, vertical=V, **kw), V + contact_damping(z, **kw) * 0.01, rtol=1e-12
    )


# ------------------------------------------------------------------------- lateral force
@pytest.mark.parametrize("soil", PRESETS, ids=lambda s: s.name)
def test_lateral_force_odd_in_slip_angle_and_zero_at_zero(soil):
    beta = np.radians([0.5, 2.0, 5.0, 15.0, 40.0, 80.0])
    z = equilibrium_sinkage(W_WHEEL, wheel=WHEEL, soil=soil)
    for s in (0.0, 0.2, 0.6):
        pos = wheel_forces(slip=s, slip_angle=beta, z=z, wheel=WHEEL, soil=soil)
        neg = wheel_forces(slip=s, slip_angle=-beta, z=z, wheel=WHEEL, soil=soil)
        np.testing.assert_array_equal(pos.lateral, -neg.lateral)
        assert np.all(pos.lateral < 0)  # sliding left -> pushed right
        assert np.all(np.diff(pos.lateral) < 0)  # grows with |beta|
        zero = wheel_forces(slip=s, slip_angle=0.0, z=z, wheel=WHEEL, soil=soil)
        assert float(zero.lateral) == 0.0
        tiny = wheel_forces(slip=s, slip_angle=1e-9, z=z, wheel=WHEEL, soil=soil)
        assert -1e-5 < float(tiny.lateral) < 0.0  # continuous through 0
        # The lateral force does not change the longitudinal ones.
        np.testing.assert_allclose(pos.thrust, float(zero.thrust), rtol=1e-13)
    # Bulldozing: with no shear strength left (c = 0, phi -> 0 is not allowed for the
    # wedge, so compare a dense and a light soil) the side wall adds force.
    light = dataclasses.replace(soil, density=100.0)
    f_light = wheel_forces(slip=0.2, slip_angle=0.5, z=z, wheel=WHEEL, soil=light)
    f_dense = wheel_forces(slip=0.2, slip_angle=0.5, z=z, wheel=WHEEL, soil=soil)
    assert float(f_dense.lateral) < float(f_light.lateral) < 0.0


# ------------------------------------------------------------------- vectorization
def test_vectorized_call_equals_scalar_calls():
    slip = np.array([0.0, 0.12, 0.5, -0.3])
    beta = np.array([0.0, 0.05, -0.2, 0.3])
    z = np.array([0.0103, 0.008, 0.0, 0.012])  # wheel 2 out of contact
    direction = np.array([1.0, 0.4, -1.0, -0.2])
    for soil in PRESETS:
        for d in (None, direction):
            vec = wheel_forces(slip=slip, slip_angle=beta, z=z, wheel=WHEEL, soil=soil, direction=d)
            for i in range(4):
                one = wheel_forces(
                    slip=slip[i],
                    slip_angle=beta[i],
                    z=z[i],
                    wheel=WHEEL,
                    soil=soil,
                    direction=None if d is None else d[i],
                )
                for name in (
                    "vertical",
                    "thrust",
                    "resistance",
                    "drawbar_pull",
                    "lateral",
                    "torque",
                ):
                    assert np.shape(getattr(one, name)) == ()
                    assert getattr(vec, name)[i] == pytest.approx(
                        float(getattr(one, name)), rel=1e-13, abs=1e-13
                    )
            # Out of contact: exactly zero.
            for name in ("thrust", "resistance", "drawbar_pull", "lateral", "torque"):
                assert getattr(vec, name)[2] == 0.0
    # Broadcasting a (3, 1) slip against 4 wheels gives (3, 4).
    f = wheel_forces(
        slip=np.array([[0.1], [0.2], [0.3]]),
        slip_angle=0.0,
        z=z,
        wheel=WHEEL,
        soil=LUNAR_REGOLITH,
    )
    assert f.thrust.shape == (3, 4)


# -------------------------------------------------------------- direction and kinematics
def test_travel_direction_blend_rest_mirror_and_continuity():
    kw = {"z": 0.0103, "wheel": WHEEL, "soil": LUNAR_REGOLITH}
    # At rest (s = 0, beta = 0, direction 0): no force at all.
    rest = wheel_forces(slip=0.0, slip_angle=0.0, direction=0.0, **kw)
    for name in ("thrust", "resistance", "drawbar_pull", "lateral", "torque"):
        assert float(getattr(rest, name)) == 0.0
    # direction = 1 is the plain forward model.
    a = wheel_forces(slip=0.3, slip_angle=0.1, direction=1.0, **kw)
    b = wheel_forces(slip=0.3, slip_angle=0.1, **kw)
    assert float(a.drawbar_pull) == pytest.approx(float(b.drawbar_pull), rel=1e-14)
    # direction = -1 is the mirror image: reversing at slip s (s < 0 when driving
    # backward) gives minus the forward forces at -s, same lateral force.
    rev = wheel_forces(slip=-0.3, slip_angle=0.1, direction=-1.0, **kw)
    assert float(rev.thrust) == pytest.approx(-float(b.thrust), rel=1e-14)
    assert float(rev.torque) == pytest.approx(-float(b.torque), rel=1e-14)
    assert float(rev.resistance) == pytest.approx(-float(b.resistance), rel=1e-14)
    assert float(rev.lateral) == pytest.approx(float(b.lateral), rel=1e-14)
    # Continuous through v = 0 for a spinning wheel (s = 1 on both sides): the jump
    # between v = -delta and v = +delta shrinks in proportion to delta (Lipschitz, with
    # a slope set by v_eps = 1e-3 m/s: at most ~(|DP fwd| + |DP bwd|) / v_eps).
    jumps = []
    for delta in (1e-4, 1e-6, 1e-8):
        v = np.array([-delta, delta])
        s = slip_ratio(omega_r=0.05, v=v)
        f = wheel_forces(slip=s, slip_angle=0.0, direction=travel_direction(v), **kw)
        assert np.all(f.thrust > 0)  # the spinning wheel pushes forward either way
        jumps.append(abs(f.drawbar_pull[1] - f.drawbar_pull[0]))
    assert jumps[0] < 200.0 * 2e-4 / 1e-3
    assert jumps[1] == pytest.approx(jumps[0] * 1e-2, rel=1e-3)
    assert jumps[2] == pytest.approx(jumps[0] * 1e-4, rel=1e-3)


def test_slip_ratio_and_slip_angle_conventions():
    # Driving: r w = 1, v = 0.8 -> (1 - 0.8)/1 = 0.2; braking: r w = 0.8, v = 1 -> -0.2.
    assert slip_ratio(omega_r=1.0, v=0.8) == pytest.approx(0.2)
    assert slip_ratio(omega_r=0.8, v=1.0) == pytest.approx(-0.2)
    assert slip_ratio(omega_r=1.0, v=0.0) == 1.0  # pure spin
    assert slip_ratio(omega_r=0.0, v=1.0) == -1.0  # locked wheel
    assert slip_ratio(omega_r=0.0, v=0.0) == 0.0
    # Continuous at rest: 1e-6 m/s of rim speed with v_eps = 1e-3 -> 1e-3.
    assert slip_ratio(omega_r=1e-6, v=0.0, v_eps=1e-3) == pytest.approx(1e-3)
    assert slip_ratio(omega_r=1.0, v=-1.0) == 1.0  # clipped
    assert slip_angle(v_x=1.0, v_y=1.0) == pytest.approx(math.pi / 4)
    assert slip_angle(v_x=-1.0, v_y=1.0) == pytest.approx(math.pi / 4)
    assert slip_angle(v_x=0.0, v_y=1e-6, v_eps=1e-3) == pytest.approx(1e-3, rel=1e-6)
    np.testing.assert_array_equal(
        travel_direction(np.array([-1.0, -5e-4, 0.0, 2.0])), [-1.0, -0.5, 0.0, 1.0]
    )


# ------------------------------------------------------------------------ validation
@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("k_phi", -1.0),
        ("k_phi", 0.0),
        ("phi", math.pi / 2),
        ("phi", math.radians(95.0)),
        ("K", 0.0),
        ("K", -0.01),
        ("n", 0.0),
        ("n", -1.0),
        ("n", 3.0),
        ("c", -1.0),
        ("k_c", -5.0),
        ("K_y", 0.0),
        ("density", 0.0),
        ("rear_angle_ratio", 1.0),
        ("damping_ratio", -0.1),
        ("c1", 1.5),
        ("phi", math.nan),
    ],
)
def test_soil_out_of_range_raises_naming_field_and_value(field, value):
    with pytest.raises(OutOfRangeError) as info:
        SoilParams(**{field: value})
    msg = str(info.value)
    assert msg.startswith(f"{field} = ")
    assert format_value(value) in msg


def test_soil_combined_and_type_errors():
    with pytest.raises(OutOfRangeError, match="c1 \\+ c2"):
        SoilParams(c1=0.7, c2=0.5)
    with pytest.raises(ConfigError, match="must be a real number"):
        SoilParams(n="1")
    with pytest.raises(ConfigError, match="must be a real number"):
        SoilParams(K=True)
    with pytest.raises(ConfigError, match="name"):
        SoilParams(name="")


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("radius_m", 0.0),
        ("radius_m", -0.2),
        ("radius_m", 10.0),
        ("width_m", 0.0),
        ("width_m", -0.1),
        ("width_m", 5.0),
        ("width_m", math.inf),
    ],
)
def test_wheel_out_of_range_raises(field, value):
    with pytest.raises(OutOfRangeError) as info:
        WheelParams(**{field: value})
    assert str(info.value).startswith(f"{field} = {format_value(value)}")


def test_presets():
    assert soil_preset("lunar_regolith") == LUNAR_REGOLITH
    assert soil_preset("lunar_regolith") is not LUNAR_REGOLITH  # a copy: configs are mutable
    assert soil_preset("GRC-1") == GRC1 and soil_preset("grc1") == GRC1
    with pytest.raises(ConfigError, match=r"'mars'.*\['grc1', 'jsc1a', 'lunar_regolith'\]"):
        soil_preset("mars")
    # Wong's lunar soil values.
    assert (LUNAR_REGOLITH.n, LUNAR_REGOLITH.k_c, LUNAR_REGOLITH.k_phi) == (1.0, 1400.0, 820000.0)
    assert LUNAR_REGOLITH.c == 170.0 and LUNAR_REGOLITH.K == 0.018
    assert math.degrees(LUNAR_REGOLITH.phi) == pytest.approx(35.0)
    assert 1600.0 <= GRC1.density <= 1890.0  # within GRC-1's min/max densities
    assert tm.SOIL_PRESETS["grc1"] is GRC1
    assert soil_preset("JSC-1A") == tm.JSC1A and tm.SOIL_PRESETS["jsc1a"] is tm.JSC1A


# ------------------------------------------------------------ static shear patch (stiction)
def test_patch_length_and_strength_hand_computed():
    # z = 0.01 m, r = 0.25 m: cos(theta_1) = 1 - 0.01/0.25 = 0.96, sin(theta_1) = 0.28,
    # L = r sin(theta_1) = 0.07 m (no rear contact).
    L = tm.patch_length(np.array([0.01, 0.0, -0.02]), wheel=WHEEL, soil=LUNAR_REGOLITH)
    np.testing.assert_allclose(L, [0.07, 0.0, 0.0], atol=1e-15)
    # Rear contact: theta_2 = -0.5 theta_1 adds r sin(0.5 theta_1).
    rebound = SoilParams(name="rebound", rear_angle_ratio=0.5)
    th1 = math.acos(0.96)
    assert tm.patch_length(np.array([0.01]), wheel=WHEEL, soil=rebound)[0] == pytest.approx(
        0.25 * (0.28 + math.sin(0.5 * th1)), rel=1e-12
    )
    # F_max = c b L + N tan(phi) = 170 * 0.2 * 0.07 + 100 * 0.70020754 = 2.38 + 70.020754
    #       = 72.400754 N; out of contact (L = 0, N = 0): 0; a negative N counts as 0.
    fmax = tm.patch_strength(
        np.array([100.0, 0.0, -5.0]), np.array([0.07, 0.0, 0.07]), wheel=WHEEL, soil=LUNAR_REGOLITH
    )
    np.testing.assert_allclose(fmax, [72.400754, 0.0, 2.38], rtol=1e-8)


def _static(j, u=(0.0, 0.0), N=100.0, L=0.07, soil=LUNAR_REGOLITH, **kw):
    return tm.patch_static_force(
        np.atleast_2d(np.asarray(j, float)),
        slip_velocity=np.atleast_2d(np.asarray(u, float)),
        N=np.array([N]),
        length=np.array([L]),
        wheel=WHEEL,
        soil=soil,
        **kw,
    )[0]


def test_patch_static_force_matches_hand_computed_mohr_coulomb_janosi_hanamoto():
    # F_max = 72.400754 N (previous test). Janosi-Hanamoto in the displacement:
    # j_x = K = 0.018 m: F_x = -F_max (1 - e^-1) = -72.400754 * 0.63212056 = -45.766005 N.
    np.testing.assert_allclose(_static([0.018, 0.0]), [-45.766005, 0.0], rtol=1e-7, atol=1e-12)
    # j_y = -2 K_y: F_y = +F_max (1 - e^-2) = 72.400754 * 0.86466472 = 62.602377 N.
    np.testing.assert_allclose(_static([0.0, -0.036]), [0.0, 62.602377], rtol=1e-7, atol=1e-12)
    # Both axes share one envelope (K = K_y here): j = K (0.6, 0.8), |j| = K, so
    # |F| = F_max (1 - e^-1) = 45.766005 N along -(0.6, 0.8).
    np.testing.assert_allclose(
        _static([0.6 * 0.018, 0.8 * 0.018]), [-0.6 * 45.766005, -0.8 * 45.766005], rtol=1e-7
    )
    # Anisotropic moduli: K_y = 2 K, j = (K, 2 K) -> rho = sqrt(2); F = -F_max (1 -
    # e^-rho) (1, 1) / rho = -72.400754 * 0.75688326 / 1.41421356 (1, 1) = -38.748687 (1, 1).
    aniso = SoilParams(name="aniso", K_y=0.036)
    np.testing.assert_allclose(_static([0.018, 0.036], soil=aniso), [-38.748687] * 2, rtol=1e-7)
    # Bristle damping: c_x = 2 zeta sqrt(F_max / K * N / g)
    #   = 2 sqrt(72.400754 / 0.018 * 100 / 1.62) = 996.56993 N s/m; u_x = 1 mm/s -> -0.99657 N.
    np.testing.assert_allclose(_static([0.0, 0.0], u=[1e-3, 0.0]), [-0.99656993, 0.0], rtol=1e-7)
    np.testing.assert_allclose(
        _static([0.0, 0.0], u=[1e-3, 0.0], damping_ratio=0.5), [-0.49828497, 0.0], rtol=1e-7
    )
    # Coulomb cap: never more than the strength, whatever the slip velocity.
    f = _static([0.0, 0.0], u=[5.0, 5.0])
    np.testing.assert_allclose(f, [-72.400754 / math.sqrt(2)] * 2, rtol=1e-8)
    f = _static([0.05, 0.0], u=[5.0, 5.0])
    assert math.hypot(*f) == pytest.approx(72.400754, rel=1e-8) and f[0] < f[1] < 0.0
    # Out of contact (no load, no patch): nothing.
    np.testing.assert_array_equal(_static([0.01, 0.01], u=[1.0, 1.0], N=0.0, L=0.0), [0.0, 0.0])
    # At rest with no displacement: exactly zero.
    np.testing.assert_array_equal(_static([0.0, 0.0]), [0.0, 0.0])


def test_patch_update_integrates_at_rest_relaxes_when_rolling_and_saturates():
    soil, dt = LUNAR_REGOLITH, 0.01
    j0 = np.array([[0.02, -0.01]])
    u = np.array([[1e-3, 2e-3]])

    def step(j, vr, L=0.07, u=u, dt=dt):
        return tm.update_patch_displacement(
            j,
            slip_velocity=u,
            rolling_speed=np.array([vr]),
            length=np.array([L]),
            dt=dt,
            soil=soil,
        )

    # At rest: integrates the creep, j + u dt (exactly).
    np.testing.assert_array_equal(step(j0, 0.0), j0 + u * dt)
    # Rolling at 0.2 m/s over L = 0.07 m: a = v / L, exact exponential step:
    # e^(-a dt) = 0.97183288, (1 - e^(-a dt)) / a = 0.00985849 s.
    a = 0.2 / 0.07
    expected = j0 * math.exp(-a * dt) + u * (1 - math.exp(-a * dt)) / a
    np.testing.assert_allclose(step(j0, 0.2), expected, rtol=1e-12)
    np.testing.assert_allclose(step(j0, -0.2), expected, rtol=1e-12)  # either direction
    # Unconditionally stable: any step tends monotonically to u L / |v|, never overshoots.
    np.testing.assert_allclose(step(j0, 0.2, dt=1e3), u * 0.07 / 0.2, rtol=1e-12)
    j = j0.copy()
    for _ in range(2000):
        j = step(j, 0.2)
    np.testing.assert_allclose(j, u * 0.07 / 0.2, rtol=1e-9)
    # Elasto-plastic: beyond 4 moduli the displacement is projected back onto the
    # ellipse (direction kept): the patch slides.
    big = step(np.array([[0.3, 0.4]]), 0.0, u=np.zeros((1, 2)))
    np.testing.assert_allclose(big, [[0.6 * 4 * 0.018, 0.8 * 4 * 0.018]], rtol=1e-12)
    assert step(big, 0.0, u=np.array([[1.0, 0.0]]))[0, 0] <= 4 * 0.018 + 1e-15
    np.testing.assert_allclose(
        tm.update_patch_displacement(
            big,
            slip_velocity=np.zeros((1, 2)),
            rolling_speed=np.zeros(1),
            length=np.array([0.07]),
            dt=dt,
            soil=soil,
            saturation_moduli=2.0,
        ),
        [[0.6 * 2 * 0.018, 0.8 * 2 * 0.018]],
        rtol=1e-12,
    )
    # Out of contact: fresh soil.
    np.testing.assert_array_equal(step(j0, 0.0, L=0.0), [[0.0, 0.0]])


def test_patch_functions_are_vectorized_over_wheels():
    rng = np.random.default_rng(7)
    n = 6
    j = rng.normal(scale=0.03, size=(n, 2))
    u = rng.normal(scale=0.01, size=(n, 2))
    vr = rng.normal(scale=0.05, size=n)
    vr[0] = 0.0
    L = rng.uniform(0.0, 0.1, size=n)
    L[1] = 0.0
    N = rng.uniform(0.0, 150.0, size=n)
    kw = dict(wheel=WHEEL, soil=LUNAR_REGOLITH)
    J = tm.update_patch_displacement(
        j, slip_velocity=u, rolling_speed=vr, length=L, dt=0.01, soil=LUNAR_REGOLITH
    )
    F = tm.patch_static_force(j, slip_velocity=u, N=N, length=L, **kw)
    for i in range(n):
        Ji = tm.update_patch_displacement(
            j[i : i + 1],
            slip_velocity=u[i : i + 1],
            rolling_speed=vr[i : i + 1],
            length=L[i : i + 1],
            dt=0.01,
            soil=LUNAR_REGOLITH,
        )
        np.testing.assert_array_equal(J[i], Ji[0])
        Fi = tm.patch_static_force(
            j[i : i + 1], slip_velocity=u[i : i + 1], N=N[i : i + 1], length=L[i : i + 1], **kw
        )
        np.testing.assert_array_equal(F[i], Fi[0])
    np.testing.assert_array_equal(
        tm.patch_slip_velocity(
            v_x=np.array([0.1, 0.0]), v_y=np.array([0.01, -0.02]), omega_r=np.array([0.12, 0.0])
        ),
        np.array([[0.1 - 0.12, 0.01], [0.0, -0.02]]),
    )


def test_static_weight_blend_and_patch_params():
    p = tm.ShearPatchParams()
    v = np.array([0.0, 0.005, 0.01, 0.015, 0.02, 0.05, -0.005, -0.015, -0.3])
    w = tm.static_weight(v, patch=p)
    # Exactly 1 at and below 1 cm/s, exactly 0 at and above 2 cm/s, 1/2 half way.
    np.testing.assert_array_equal(w[[0, 1, 2, 6]], 1.0)
    np.testing.assert_array_equal(w[[4, 5, 8]], 0.0)
    assert w[3] == pytest.approx(0.5) and w[7] == pytest.approx(0.5)
    grid = np.linspace(0.0, 0.03, 301)
    assert np.all(np.diff(tm.static_weight(grid, patch=p)) <= 0.0)
    with pytest.raises(OutOfRangeError, match="dynamic_speed_mps"):
        tm.ShearPatchParams(static_speed_mps=0.02, dynamic_speed_mps=0.02)
    with pytest.raises(OutOfRangeError, match="damping_ratio"):
        tm.ShearPatchParams(damping_ratio=0.0)
    with pytest.raises(OutOfRangeError, match="saturation_moduli"):
        tm.ShearPatchParams(saturation_moduli=0.5)
    with pytest.raises(ConfigError, match="static_speed_mps"):
        tm.ShearPatchParams(static_speed_mps="slow")
