"""Tests for lunar_drake.dynamics.wheel_reference (independent Wong-Reece reference)."""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np
import pytest

from lunar_drake.dynamics import wheel_reference as wr
from lunar_drake.dynamics.terramechanics import (
    LUNAR_REGOLITH,
    ImmobilizedError,
    SoilParams,
    WheelParams,
)
from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError
from lunar_drake.moon import GRAVITY_MPS2

WHEEL = WheelParams(radius_m=0.25, width_m=0.2)
# Stress peak at the bottom (theta_m = 0), no rebound, linear pressure-sinkage.
PLAIN = dc.replace(LUNAR_REGOLITH, name="plain", c1=0.0, c2=0.0, rear_angle_ratio=0.0, n=1.0)


def _theta1(z, r=WHEEL.radius_m):
    return math.acos(1.0 - z / r)


# ------------------------------------------------------------------ closed forms by hand
def test_normal_stress_integrals_match_hand_closed_form():
    # c = phi = 0: no shear. sigma = k r (cos t - cos t1) on [0, t1], k = k_c/b + k_phi.
    # Fz = b r int sigma cos = b k r^2 [t1/2 + sin(2 t1)/4 - cos t1 sin t1]
    # DP = -b r int sigma sin = -b k r^2 [sin^2 t1 / 2 - cos t1 (1 - cos t1)]
    #    = -b k r^2 (1 - cos t1)^2 / 2 = -b k z^2 / 2  (Bekker's compaction resistance, n = 1)
    soil = dc.replace(PLAIN, c=0.0, phi=0.0)
    r, b = WHEEL.radius_m, WHEEL.width_m
    k = soil.k_c / b + soil.k_phi  # 7000 + 820000 = 827000 N/m^3
    for z in (0.002, 0.01, 0.05, 0.25):
        t1 = _theta1(z)
        f = wr.wheel_integrals(slip=0.0, sinkage_m=z, wheel=WHEEL, soil=soil)
        fz = b * k * r**2 * (t1 / 2 + math.sin(2 * t1) / 4 - math.cos(t1) * math.sin(t1))
        assert f.vertical_N == pytest.approx(fz, rel=1e-9)
        assert f.drawbar_pull_N == pytest.approx(-b * k * z * z / 2, rel=1e-9)
        assert f.torque_Nm == 0.0
        assert f.lateral_N == 0.0
    # A number: z = 1 cm, t1 = acos(0.96) = 0.283794 rad;
    # t1/2 + sin(2 t1)/4 - cos t1 sin t1 = 0.141897 + 0.134400 - 0.268800 = 0.0074973
    # Fz = 0.2 * 827000 * 0.0625 * 0.0074973 = 77.50 N
    f = wr.wheel_integrals(slip=0.0, sinkage_m=0.01, wheel=WHEEL, soil=soil)
    assert f.vertical_N == pytest.approx(77.50, abs=0.01)


def test_fully_mobilized_shear_matches_hand_integrals():
    # K -> 0: j > 0 everywhere inside the contact for any s in [0, 1) (the geometric part
    # (t1 - t) - (sin t1 - sin t) is > 0 already), so tau = c + sigma tan(phi) -- the s = 1
    # limit of the brief, reached here at s = 0.5 (s = 1 itself is outside the domain).
    # With sigma = k r (cos t - cos t1), theta_m = 0, no rebound, n = 1 and r_s = r:
    # DP = b [r c sin t1 + r k r tan(phi) A - k r^2 (1 - cos t1)^2 / 2],
    # T = r^2 b [c t1 + k r tan(phi) (sin t1 - t1 cos t1)],
    # Fz = b [k r^2 A + r c (1 - cos t1) + r k r tan(phi) B],
    # A = t1/2 + sin(2 t1)/4 - cos t1 sin t1, B = sin^2 t1 / 2 - cos t1 (1 - cos t1).
    soil = dc.replace(PLAIN, K=1e-9)
    r, b = WHEEL.radius_m, WHEEL.width_m
    k = soil.k_c / b + soil.k_phi
    tp, c = math.tan(soil.phi), soil.c
    for z in (0.005, 0.03):
        t1 = _theta1(z)
        s1, c1 = math.sin(t1), math.cos(t1)
        A = t1 / 2 + math.sin(2 * t1) / 4 - c1 * s1
        B = s1 * s1 / 2 - c1 * (1 - c1)
        f = wr.wheel_integrals(slip=0.5, sinkage_m=z, wheel=WHEEL, soil=soil)
        dp = b * (r * c * s1 + r * k * r * tp * A - k * r * r * (1 - c1) ** 2 / 2)
        assert f.drawbar_pull_N == pytest.approx(dp, rel=1e-6)
        torque = r * r * b * (c * t1 + k * r * tp * (s1 - t1 * c1))
        assert f.torque_Nm == pytest.approx(torque, rel=1e-6)
        fz = b * (k * r * r * A + r * c * (1 - c1) + r * k * r * tp * B)
        assert f.vertical_N == pytest.approx(fz, rel=1e-6)


def test_grousers_scale_the_shear_radius():
    # Fully mobilized shear (K -> 0): tau does not depend on r_s, so T = r_s^2 b int tau
    # grows by (r_s / r)^2; grousers of 1 cm at ratio 0.5 give r_s = 0.255 m.
    soil = dc.replace(PLAIN, K=1e-9)
    g = WheelParams(radius_m=0.25, width_m=0.2, grouser_height_m=0.01, grouser_ratio=0.5)
    t0 = wr.wheel_integrals(slip=0.5, sinkage_m=0.02, wheel=WHEEL, soil=soil).torque_Nm
    t1 = wr.wheel_integrals(slip=0.5, sinkage_m=0.02, wheel=g, soil=soil).torque_Nm
    assert t1 / t0 == pytest.approx((0.255 / 0.25) ** 2, rel=1e-6)


def test_rear_region_mirrors_the_front_stress():
    # n = 1, s = 0, c = phi = 0, theta_m = 0.5 t1, rear angle 0: the rear branch maps
    # [0, t_m] onto [t_m, t1] linearly, so int_rear sigma = int_front sigma (equal lengths).
    # Then Fz is checked against a composite Simpson sum of the stated formulas.
    soil = dc.replace(PLAIN, c=0.0, phi=0.0, c1=0.5, c2=0.0)
    r, b, z = WHEEL.radius_m, WHEEL.width_m, 0.02
    k = soil.k_c / b + soil.k_phi
    t1 = _theta1(z)
    tm = 0.5 * t1
    t = np.linspace(0.0, t1, 200001)
    front = np.clip(np.cos(t) - math.cos(t1), 0, None)
    rear = np.clip(np.cos(t1 - t * (t1 - tm) / tm) - math.cos(t1), 0, None)
    sigma = k * r * np.where(t >= tm, front, rear)
    h = t[1] - t[0]
    w = np.ones_like(t)
    w[1:-1:2], w[2:-1:2] = 4, 2
    fz = b * r * float(np.sum(w * sigma * np.cos(t))) * h / 3
    f = wr.wheel_integrals(slip=0.0, sinkage_m=z, wheel=WHEEL, soil=soil)
    assert f.vertical_N == pytest.approx(fz, rel=1e-8)


def _simpson(t, y):
    w = np.ones_like(t)
    w[1:-1:2], w[2:-1:2] = 4, 2
    return float(np.sum(w * y)) * (t[1] - t[0]) / 3


def test_longitudinal_integrals_match_a_second_implementation():
    # Every longitudinal term at once (n != 1, rebound, theta_m(s), finite K, grousers)
    # against the module docstring's formulas, vectorized, composite Simpson on each side
    # of theta_m.
    soil = dc.replace(LUNAR_REGOLITH, n=0.8, rear_angle_ratio=0.3, c1=0.4, c2=0.35, K=0.012)
    wheel = WheelParams(radius_m=0.2, width_m=0.15, grouser_height_m=0.01, grouser_ratio=0.6)
    r, b, s, z = wheel.radius_m, wheel.width_m, 0.35, 0.03
    rs = r + 0.6 * 0.01
    t1 = _theta1(z, r)
    t2 = -0.3 * t1
    tm = (0.4 + 0.35 * s) * t1
    k = soil.k_c / b + soil.k_phi
    fz = dp = tq = 0.0
    for lo, hi in ((t2, tm), (tm, t1)):
        t = np.linspace(lo, hi, 100001)
        if lo == tm:
            base = np.cos(t) - math.cos(t1)
        else:
            base = np.cos(t1 - (t - t2) * (t1 - tm) / (tm - t2)) - math.cos(t1)
        sigma = k * r**soil.n * np.clip(base, 0, None) ** soil.n
        j = rs * ((t1 - t) - (1 - s) * (math.sin(t1) - np.sin(t)))
        tau = (soil.c + sigma * math.tan(soil.phi)) * (1 - np.exp(-np.abs(j) / soil.K))
        tau *= np.sign(j)
        fz += b * _simpson(t, r * sigma * np.cos(t) + rs * tau * np.sin(t))
        dp += b * _simpson(t, rs * tau * np.cos(t) - r * sigma * np.sin(t))
        tq += rs**2 * b * _simpson(t, tau)
    f = wr.wheel_integrals(slip=s, sinkage_m=z, wheel=wheel, soil=soil)
    assert f.vertical_N == pytest.approx(fz, rel=1e-7)
    assert f.drawbar_pull_N == pytest.approx(dp, rel=1e-7)
    assert f.torque_Nm == pytest.approx(tq, rel=1e-7)


# ------------------------------------------------------------------------ lateral force
def _lateral_simpson(beta, *, s, z, soil, wheel=WHEEL, g=GRAVITY_MPS2, n=200001):
    """Fy from the module docstring's formulas, vectorized, composite Simpson."""
    r, b = wheel.radius_m, wheel.width_m
    t1 = _theta1(z, r)
    tm = min(max(soil.c1 + soil.c2 * s, 0), 0.99) * t1
    t = np.linspace(0.0, t1, n)
    k = soil.k_c / b + soil.k_phi
    base = np.where(
        t >= tm, np.cos(t) - math.cos(t1), np.cos(t1 - t * (t1 - tm) / tm) - math.cos(t1)
    )
    sigma = k * r**soil.n * np.clip(base, 0, None) ** soil.n
    jy = r * (1 - s) * (t1 - t) * abs(math.tan(beta))
    tau_y = (soil.c + sigma * math.tan(soil.phi)) * (1 - np.exp(-jy / soil.K_y))
    hh = np.clip(r * (np.cos(t) - math.cos(t1)), 0, None)
    xc = math.pi / 4 - soil.phi / 2
    d1 = 1 / math.tan(xc) + math.tan(xc + soil.phi)
    d2 = 1 / math.tan(xc) + math.tan(soil.phi) / math.tan(xc) ** 2
    rb = d1 * (soil.c * hh + d2 * soil.density * g * hh**2 / 2)
    w = np.ones_like(t)
    w[1:-1:2], w[2:-1:2] = 4, 2
    h = t[1] - t[0]

    def simpson(y):
        return float(np.sum(w * y)) * h / 3

    bull = abs(math.sin(beta)) * simpson(rb * (r - hh * np.cos(t)))
    return -math.copysign(r * b * simpson(tau_y) + bull, beta)


def test_lateral_force_matches_a_second_implementation():
    for beta, s in ((0.1, 0.2), (-0.3, 0.6)):
        f = wr.wheel_integrals(slip=s, sinkage_m=0.02, wheel=WHEEL, soil=LUNAR_REGOLITH,
                               slip_angle=beta)  # fmt: skip
        assert f.lateral_N == pytest.approx(
            _lateral_simpson(beta, s=s, z=0.02, soil=LUNAR_REGOLITH), rel=1e-7
        )
    assert math.copysign(1.0, f.lateral_N) == 1.0  # beta < 0 pushes to +y


def test_bulldozing_zero_at_zero_slip_angle_and_odd_in_beta():
    kw = dict(slip=0.3, sinkage_m=0.03, wheel=WHEEL, soil=LUNAR_REGOLITH)
    assert wr.wheel_integrals(slip_angle=0.0, **kw).lateral_N == 0.0
    for beta in (0.05, 0.4, 1.2):
        plus = wr.wheel_integrals(slip_angle=beta, **kw).lateral_N
        minus = wr.wheel_integrals(slip_angle=-beta, **kw).lateral_N
        assert plus < 0.0
        assert minus == -plus
    # Bulldozing: with c = 0 only its density term depends on gravity, linearly:
    # dFy/dg = -|sin beta| D1 D2 rho / 2 int h^2 (r - h cos t) dt, with (phi = 35 deg,
    # X_c = 27.5 deg) cot X_c = tan 62.5 deg = 1.920982, D1 = 3.841964,
    # D2 = 1.920982 + 1.920982^2 tan 35 deg = 1.920982 + 3.690172 * 0.700208 = 4.504869.
    soil = dc.replace(LUNAR_REGOLITH, c=0.0)
    kw = dict(slip=0.0, sinkage_m=0.05, wheel=WHEEL, soil=soil, slip_angle=0.2)
    f1, f2, f3 = (wr.wheel_integrals(gravity_mps2=k * GRAVITY_MPS2, **kw).lateral_N
                  for k in (1, 2, 3))  # fmt: skip
    assert f3 - f2 == pytest.approx(f2 - f1, rel=1e-8)
    r, t1 = WHEEL.radius_m, _theta1(0.05)
    t = np.linspace(0.0, t1, 100001)
    h = r * (np.cos(t) - math.cos(t1))
    y = h**2 * (r - h * np.cos(t))
    integral = float(np.sum((y[1:] + y[:-1]) / 2) * (t[1] - t[0]))
    slope = -math.sin(0.2) * 3.841964 * 4.504869 * soil.density / 2 * integral
    assert (f2 - f1) / GRAVITY_MPS2 == pytest.approx(slope, rel=1e-6)


# ------------------------------------------------------------------ steady-state behaviour
def test_vertical_load_increases_with_sinkage_and_equilibrium_inverts_it():
    zs = np.linspace(0.001, 0.25, 25)
    fz = [wr.wheel_integrals(slip=0.3, sinkage_m=z, wheel=WHEEL, soil=LUNAR_REGOLITH).vertical_N
          for z in zs]  # fmt: skip
    assert np.all(np.diff(fz) > 0.0)
    z = wr.equilibrium_sinkage(slip=0.3, load_N=120.0, wheel=WHEEL, soil=LUNAR_REGOLITH)
    back = wr.wheel_integrals(slip=0.3, sinkage_m=z, wheel=WHEEL, soil=LUNAR_REGOLITH)
    assert back.vertical_N == pytest.approx(120.0, rel=1e-10)
    st = wr.steady_wheel(slip=0.3, load_N=120.0, wheel=WHEEL, soil=LUNAR_REGOLITH)
    assert st.sinkage_m == z
    assert st.drawbar_pull_N == back.drawbar_pull_N
    assert 0.005 < z < 0.03  # about a centimetre for 120 N on lunar soil


def test_drawbar_pull_and_torque_increase_with_slip_at_fixed_load():
    slips = np.linspace(0.0, 0.9, 10)
    st = [wr.steady_wheel(slip=s, load_N=120.0, wheel=WHEEL, soil=LUNAR_REGOLITH) for s in slips]
    dp = np.array([w.drawbar_pull_N for w in st])
    assert np.all(np.diff(dp) > 0.0)
    assert dp[0] < 0.0 < dp[-1]  # rolling resistance at s = 0, net pull when slipping
    assert np.all(np.diff([w.torque_Nm for w in st]) > 0.0)


def test_reference_slip_monotone_in_slope_and_immobilized_when_steep():
    loads = np.full(4, 75.0)
    slopes = np.radians([0.0, 4.0, 8.0, 12.0, 16.0])
    s = wr.reference_curve(slopes_rad=slopes, wheel_loads_fn=lambda a: loads * math.cos(a),
                           wheel=WHEEL, soil=LUNAR_REGOLITH)  # fmt: skip
    assert np.all(np.isfinite(s))
    assert np.all(np.diff(s) > 0.0)
    assert 0.0 < s[0] < 0.2
    # The root balances: total pull = sum N tan(slope).
    a = slopes[2]
    st = wr.steady_wheel(slip=s[2], load_N=75.0 * math.cos(a), wheel=WHEEL, soil=LUNAR_REGOLITH)
    assert 4 * st.drawbar_pull_N == pytest.approx(4 * 75.0 * math.sin(a), rel=1e-8)
    with pytest.raises(ImmobilizedError, match=r"cannot climb .*downslope weight") as e:
        wr.reference_slip(slope_rad=math.radians(30.0), wheel_loads_N=loads * math.cos(0.52),
                          wheel=WHEEL, soil=LUNAR_REGOLITH)  # fmt: skip
    assert "\n" not in str(e.value)
    steep = wr.reference_curve(slopes_rad=[0.0, math.radians(30.0)],
                               wheel_loads_fn=lambda a: loads * math.cos(a), wheel=WHEEL,
                               soil=LUNAR_REGOLITH)  # fmt: skip
    assert np.isfinite(steep[0]) and np.isnan(steep[1])


def test_weaker_soil_slips_more():
    loads = np.full(4, 75.0)
    weak = dc.replace(LUNAR_REGOLITH, phi=math.radians(30.0), K=0.025, K_y=0.025)
    a = math.radians(8.0)
    kw = dict(slope_rad=a, wheel_loads_N=loads * math.cos(a), wheel=WHEEL)
    assert wr.reference_slip(soil=weak, **kw) > wr.reference_slip(soil=LUNAR_REGOLITH, **kw)


def test_equal_loads_give_the_same_slip_as_one_wheel():
    a = math.radians(6.0)
    one = wr.reference_slip(slope_rad=a, wheel_loads_N=[80.0], wheel=WHEEL, soil=LUNAR_REGOLITH)
    four = wr.reference_slip(slope_rad=a, wheel_loads_N=[80.0] * 4, wheel=WHEEL,
                             soil=LUNAR_REGOLITH)  # fmt: skip
    assert four == pytest.approx(one, abs=1e-10)


# ------------------------------------------------------------------------- slope loads
@pytest.mark.parametrize("preset", ["husky_rp", "krex2_rp"])
def test_slope_loads_match_drake_level_loads_and_balance(preset):
    from lunar_drake.models.rover_description import rover_preset
    from lunar_drake.models.rover_sdf import level_wheel_loads

    d = rover_preset(preset)
    level = wr.slope_wheel_loads(description=d, slope_rad=0.0)
    np.testing.assert_allclose(level, level_wheel_loads(d), rtol=1e-9)
    mass, _ = wr.rover_mass_properties(description=d)
    assert mass == pytest.approx(d.total_mass_kg())
    a = math.radians(10.0)
    loads = wr.slope_wheel_loads(description=d, slope_rad=a)
    assert loads.sum() == pytest.approx(mass * GRAVITY_MPS2 * math.cos(a))
    assert loads[0] == loads[1] and loads[2] == loads[3]
    assert loads[2] > loads[0]  # weight shifts to the downhill (rear) wheels
    # Moment about the contact line: sum x N = W (x_cm cos - h sin).
    _, com = wr.rover_mass_properties(description=d)
    h = d.nominal_chassis_height_m() + com[2]
    x = d.wheel_centres_C()[:, 0]
    w = mass * GRAVITY_MPS2
    assert float(x @ loads) == pytest.approx(w * (com[0] * math.cos(a) - h * math.sin(a)))


@pytest.mark.parametrize("preset", ["husky_rp", "krex2_rp"])
def test_centre_of_mass_matches_the_parsed_model(preset):
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    from lunar_drake.models.rover_description import rover_preset
    from lunar_drake.models.rover_sdf import rover_sdf

    d = rover_preset(preset)
    plant = MultibodyPlant(0.0)
    (inst,) = Parser(plant).AddModelsFromString(rover_sdf(d), "sdf")
    plant.Finalize()
    ctx = plant.CreateDefaultContext()
    mass, com = wr.rover_mass_properties(description=d)
    assert mass == pytest.approx(plant.CalcTotalMass(ctx, [inst]))
    np.testing.assert_allclose(com, plant.CalcCenterOfMassPositionInWorld(ctx, [inst]),
                               atol=1e-12)  # fmt: skip


def test_slope_loads_refuse_a_tipping_slope():
    from lunar_drake.models.rover_description import rover_preset

    with pytest.raises(OutOfRangeError, match=r"front wheels .* lift off"):
        wr.slope_wheel_loads(description=rover_preset("krex2_rp"), slope_rad=1.2)


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        (dict(slip=1.0), OutOfRangeError, r"slip = 1 is out of range; allowed \[0, 1\)"),
        (dict(slip=-0.1), OutOfRangeError, r"slip = -0.1 is out of range"),
        (dict(slip=float("nan")), OutOfRangeError, "slip = nan"),
        (dict(slip=True), ConfigError, "slip = True must be a real number"),
        (dict(sinkage_m=0.0), OutOfRangeError, r"sinkage_m = 0 is out of range"),
        (dict(sinkage_m=0.3), OutOfRangeError, r"sinkage_m = 0.3 is out of range"),
        (dict(slip_angle=math.pi / 2), OutOfRangeError, "slip_angle"),
        (dict(gravity_mps2=0.0), OutOfRangeError, "gravity_mps2"),
        (dict(wheel="big"), ConfigError, "wheel must be a WheelParams"),
        (dict(soil={"phi": 0.5}), ConfigError, "soil must be a SoilParams"),
    ],
)
def test_wheel_integrals_bad_input(kwargs, exc, match):
    kw = dict(slip=0.2, sinkage_m=0.02, wheel=WHEEL, soil=LUNAR_REGOLITH) | kwargs
    with pytest.raises(exc, match=match) as e:
        wr.wheel_integrals(**kw)
    assert "\n" not in str(e.value)


def test_bad_loads_slopes_and_soils():
    with pytest.raises(ImmobilizedError, match=r"load_N = 1e\+06 N cannot be carried") as e:
        wr.equilibrium_sinkage(slip=0.1, load_N=1e6, wheel=WHEEL, soil=LUNAR_REGOLITH)
    assert "\n" not in str(e.value)
    for load in (0.0, -5.0, float("inf"), float("nan")):
        with pytest.raises(OutOfRangeError, match="load_N"):
            wr.equilibrium_sinkage(slip=0.1, load_N=load, wheel=WHEEL, soil=LUNAR_REGOLITH)
    kw = dict(wheel=WHEEL, soil=LUNAR_REGOLITH)
    with pytest.raises(OutOfRangeError, match=r"slope_rad = -0\.1"):
        wr.reference_slip(slope_rad=-0.1, wheel_loads_N=[50.0], **kw)
    for loads in ([], [50.0, 0.0], [float("nan")], "heavy"):
        with pytest.raises(OutOfRangeError, match="wheel_loads_N"):
            wr.reference_slip(slope_rad=0.1, wheel_loads_N=loads, **kw)
    bad = SoilParams.__new__(SoilParams)  # skips __post_init__, like a YAML loader
    bad.__dict__.update(dc.asdict(LUNAR_REGOLITH) | {"K": -1.0})
    with pytest.raises(OutOfRangeError, match="K = -1"):
        wr.wheel_integrals(slip=0.1, sinkage_m=0.01, wheel=WHEEL, soil=bad)
    assert issubclass(ImmobilizedError, LunarDrakeError)
