"""Wheel-regolith contact: footprint geometry, the contact LeafSystem, a rover at rest and
driving, spawn errors, the off-terrain stop, and a small slip study."""

import itertools
import math

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.math import SpatialVelocity

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics import wheel_reference
from lunar_drake.dynamics.contact_geometry import FootprintSampling, wheel_contact_geometry
from lunar_drake.errors import ConfigError, NoDataError, OutOfBoundsError, OutOfRangeError
from lunar_drake.models.rover_description import rover_preset
from lunar_drake.models.rover_sdf import level_wheel_loads
from lunar_drake.models.spawn import spawn_pose
from lunar_drake.moon import GRAVITY_MPS2
from lunar_drake.systems.wheel_regolith_contact import WHEEL_STATE_FIELDS, WheelRegolithContact
from lunar_drake.terrain.heightfield import Heightfield

R, B = 0.25, 0.2
WHEEL = tm.WheelParams(radius_m=R, width_m=B)
SOIL = tm.LUNAR_REGOLITH


def _plane(n=200, res=0.05, gx=0.0, gy=0.0, bump=None):
    yy, xx = np.mgrid[0:n, 0:n]
    x = (xx + 0.5 - n / 2) * res
    y = (n / 2 - yy - 0.5) * res
    z = gx * x + gy * y
    if bump is not None:
        bx, by, h, rad = bump
        z = z + np.where((x - bx) ** 2 + (y - by) ** 2 <= rad**2, h, 0.0)
    return Heightfield.from_array(z.astype(np.float32), resolution_m=res)


def _geom(hf, centre, axle=(0.0, 1.0, 0.0)):
    return wheel_contact_geometry(
        heightfield=hf,
        p_WWo=np.array([centre]),
        axle_W=np.array([axle]),
        radius_m=R,
        width_m=B,
        sampling=FootprintSampling(),
    )


def test_footprint_geometry_flat_slope_and_rock():
    flat = _plane()
    g = _geom(flat, (0.0, 0.0, R - 0.02))
    assert g.sinkage[0] == pytest.approx(0.02, abs=1e-6)
    np.testing.assert_allclose(g.n_W[0], [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(g.forward_W[0], [1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(g.p_WC[0], [0, 0, -0.02], atol=1e-6)  # rim bottom, in the soil
    # Above the ground: negative sinkage (no contact).
    assert _geom(flat, (0.0, 0.0, R + 0.05)).sinkage[0] == pytest.approx(-0.05, abs=1e-6)
    # A 20 % slope along x: the normal tilts back by atan(0.2).
    g = _geom(_plane(gx=0.2), (0.0, 0.0, R))
    np.testing.assert_allclose(g.n_W[0], np.array([-0.2, 0, 1]) / math.hypot(0.2, 1), atol=1e-6)
    # A 5 cm rock under the front of the tread raises the sinkage by about its height.
    g0 = _geom(flat, (0.0, 0.0, R))
    g1 = _geom(_plane(bump=(0.05, 0.0, 0.05, 0.06)), (0.0, 0.0, R))
    assert g1.sinkage[0] - g0.sinkage[0] > 0.035
    # Off the raster: flagged, never an exception.
    assert _geom(flat, (4.99, 0.0, R)).off_terrain[0]


def test_compiled_geometry_matches_the_lookup_path(monkeypatch):
    """The one-call geometry and belly lookups of in-memory rasters give the same bits as
    the general path (``Heightfield.heights_within``), off the raster and on nodata too."""
    from lunar_drake.dynamics.contact_geometry import belly_penetration

    rng = np.random.default_rng(4)
    z = rng.normal(0.0, 0.05, (120, 120)).astype(np.float32)
    z[40:44, 60:70] = np.nan
    hf = Heightfield.from_array(z, resolution_m=0.05)
    p = np.c_[rng.uniform(-3.2, 3.2, (300, 2)), rng.uniform(-0.1, 0.3, 300)]
    axle = rng.normal(size=(300, 3)) * [0.2, 1.0, 0.2]
    axle /= np.linalg.norm(axle, axis=1)[:, None]
    args = dict(heightfield=hf, p_WWo=p, axle_W=axle, radius_m=R, width_m=B,
                sampling=FootprintSampling())  # fmt: skip
    fast, fast_belly = wheel_contact_geometry(**args), belly_penetration(heightfield=hf, p_WP=p)
    monkeypatch.setattr(Heightfield, "within_kernel_args", lambda self, **_: None)
    slow, slow_belly = wheel_contact_geometry(**args), belly_penetration(heightfield=hf, p_WP=p)
    for name in ("sinkage", "n_W", "forward_W", "lateral_W", "p_WC", "off_terrain"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
    for a, b in zip(fast_belly, slow_belly, strict=True):
        np.testing.assert_array_equal(a, b)
    assert 0 < fast.off_terrain.sum() < 300 and (fast_belly[0] > 0).any()


def test_one_call_contact_step_matches_the_step_by_step_path(monkeypatch):
    """The system's fused stage 1 (``contact_kernels.step_kinematics``, in-memory rasters)
    gives the same bits as the function-by-function path it takes for file-backed
    rasters: wheels on, partly and wholly off the raster, belly points above and below
    the ground, off the raster, and next to nodata (the same error both ways)."""
    rng = np.random.default_rng(11)
    z = rng.normal(0.0, 0.04, (120, 120)).astype(np.float32)
    z[50:54, 60:70] = np.nan
    hf = Heightfield.from_array(z, resolution_m=0.05)
    belly_pts = np.array([[0.3, 0.2, -0.1], [-0.3, 0.2, -0.1], [0.0, -0.25, -0.12]])
    contact = WheelRegolithContact(
        wheel_bodies=[1, 2, 3], wheel=WHEEL, soil=SOIL, belly_body=0, belly_points_B=belly_pts
    )

    def outputs(poses, vels, j):
        ctx = contact.CreateDefaultContext()
        contact.set_patch_displacement(ctx, j)
        contact.body_poses_input.FixValue(ctx, poses)
        contact.body_spatial_velocities_input.FixValue(ctx, vels)
        contact.heightfield_input.FixValue(ctx, hf)
        try:
            forces = contact.spatial_forces_output.Eval(ctx)
        except NoDataError as e:
            return str(e)
        return (
            np.array([np.r_[f.F_Bq_W.rotational(), f.F_Bq_W.translational()] for f in forces]),
            contact.wheel_state_output.Eval(ctx).copy(),
            contact.off_terrain_output.Eval(ctx).copy(),
        )

    cases = []
    for k in range(60):
        centre = rng.uniform(-2.4, 2.4, 2) if k % 8 else np.array([2.9, 0.0])  # some off
        rpy = RollPitchYaw(rng.normal(0, 0.1), rng.normal(0, 0.1), rng.uniform(-3.1, 3.1))
        chassis = RigidTransform(rpy, np.r_[centre, rng.uniform(0.0, 0.3)])
        poses = [chassis] + [
            chassis.multiply(RigidTransform(np.r_[rng.normal(0, 0.4, 2), -0.1])) for _ in range(3)
        ]
        vels = [SpatialVelocity(rng.normal(0, 0.3, 3), rng.normal(0, 0.3, 3)) for _ in range(4)]
        cases.append((poses, vels, rng.normal(0.0, 1e-3, (3, 2))))
    fast = [outputs(*c) for c in cases]
    monkeypatch.setattr(Heightfield, "within_kernel_args", lambda self, **_: None)
    slow = [outputs(*c) for c in cases]
    for a, b in zip(fast, slow, strict=True):
        assert type(a) is type(b)
        if isinstance(a, str):
            assert a == b
            continue
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)
    done = [f for f in fast if not isinstance(f, str)]
    # the cases reach every branch: a belly force, wheels in and out of contact, off
    assert any(f[0].shape[0] == 4 for f in done)
    sinkage = np.array([f[1][0 :: len(WHEEL_STATE_FIELDS)] for f in done])
    assert (sinkage > 0).any() and (sinkage <= 0).any()
    assert 0 < sum(f[2][0] for f in done) < len(done)


def _contact_forces(hf, *, p, v, w_spin):
    """Evaluates WheelRegolithContact for one wheel (body 1)."""
    sys = WheelRegolithContact(wheel_bodies=[1], wheel=WHEEL, soil=SOIL)
    ctx = sys.CreateDefaultContext()
    sys.body_poses_input.FixValue(ctx, [RigidTransform(), RigidTransform(p)])
    sys.body_spatial_velocities_input.FixValue(
        ctx,
        [
            SpatialVelocity(np.zeros(3), np.zeros(3)),
            SpatialVelocity(np.array([0.0, w_spin, 0.0]), np.asarray(v, float)),
        ],
    )
    sys.heightfield_input.FixValue(ctx, hf)
    forces = sys.spatial_forces_output.Eval(ctx)
    state = sys.wheel_state_output.Eval(ctx)
    return forces[0].F_Bq_W, dict(zip(WHEEL_STATE_FIELDS, state, strict=True))


def test_zero_slip_on_flat_ground_gives_the_wong_reece_forces():
    hf = _plane()
    v = 0.1
    F, st = _contact_forces(hf, p=[0, 0, R - 0.012], v=[v, 0, 0], w_spin=v / R)
    assert st["slip"] == pytest.approx(0.0, abs=1e-12)
    assert st["normal_force_N"] > 50
    # A freely rolling wheel: the Wong-Reece drawbar pull at s = 0 (rolling resistance
    # net of the small thrust of the geometric shear term), and its vertical load.
    f = tm.wheel_forces(slip=0.0, slip_angle=0.0, z=st["sinkage_m"], wheel=WHEEL, soil=SOIL)
    assert float(f.drawbar_pull) < 0.0
    assert F.translational()[0] == pytest.approx(float(f.drawbar_pull), rel=1e-6)
    assert F.translational()[2] == pytest.approx(float(f.vertical), rel=1e-6)
    assert st["normal_force_N"] == pytest.approx(float(f.vertical), rel=1e-6)
    assert F.translational()[1] == pytest.approx(0.0, abs=1e-9)
    # Driving (wheel faster than the hub): forward traction.
    F2, st2 = _contact_forces(hf, p=[0, 0, R - 0.012], v=[v, 0, 0], w_spin=1.3 * v / R)
    assert st2["slip"] > 0.2 and F2.translational()[0] > 0.1 * st2["normal_force_N"]
    # Sliding sideways to the left: the side force pushes right.
    F3, _ = _contact_forces(hf, p=[0, 0, R - 0.012], v=[v, 0.05, 0], w_spin=v / R)
    assert F3.translational()[1] < -1.0


def test_normal_force_is_continuous_at_contact_onset():
    hf = _plane()
    heights = R + np.array([1e-3, 1e-6, 0.0, -1e-6, -1e-4, -1e-3])
    n = [
        _contact_forces(hf, p=[0, 0, z], v=[0, 0, 0], w_spin=0)[1]["normal_force_N"]
        for z in heights
    ]
    assert n[0] == 0.0 and n[1] == 0.0
    assert n[3] < 0.05 and n[4] < n[5]
    assert all(b >= a for a, b in itertools.pairwise(n))
    # The wheel's soil moment about the axle equals the Wong-Reece torque; at rest it is 0.
    F, _ = _contact_forces(hf, p=[0, 0, R - 0.01], v=[0, 0, 0], w_spin=0)
    assert abs(F.rotational()[1]) < 1e-9


def _rover_sim(*, preset="krex2_rp", hf=None, twist=(0.0, 0.0, 0.0), dt=0.01, x0=-2.0, t=3.0):
    """The mission (plant, flight, ground, zero-delay link) on a plane: 1 s standing,
    then ``twist``; returns the logs (truth pose and wheel state, encoders)."""
    from lunar_drake.scenario import RouteSegment, Scenario
    from lunar_drake.simulation import simulate
    from lunar_drake.site import SiteData

    s = Scenario(name="plane")
    s.simulation_duration = t
    s.random_seed = 3
    s.rover.description = rover_preset(preset)
    s.rover.spawn_x_m = x0
    s.ground.route = [RouteSegment(duration_s=1.0), RouteSegment(100.0, *twist)]
    s.comms.uplink.delay_s = s.comms.downlink.delay_s = 0.0
    s.logging.period_s = 0.05
    s.plant_config.time_step = dt
    logs = simulate(scenario=s, site=SiteData.from_heightfield(hf or _plane(n=240, res=0.05)))
    return logs, s.rover.description


def test_rover_rests_in_static_equilibrium():
    logs, desc = _rover_sim(t=3.0)
    pose = logs.vectors["truth.pose"].data
    ws = logs.vectors["truth.wheel_state"].data
    nf = len(WHEEL_STATE_FIELDS)
    total_n = ws[-1, 1::nf].sum()
    mass = (
        sum(getattr(desc, f) for f in ("chassis_mass_kg", "mast_mass_kg", "gimbal_mass_kg"))
        + desc.solar_panel_mass_kg
    )
    assert mass > 0
    assert total_n == pytest.approx(desc.total_mass_kg() * GRAVITY_MPS2, rel=0.01)
    # At rest: no drift, level, wheels at their static sinkage.
    assert np.abs(pose[-1, 6:9]).max() < 1e-3
    assert np.abs(pose[-1, 0] - pose[0, 0]) < 5e-3
    loads = np.asarray(level_wheel_loads(desc))
    z_static = tm.equilibrium_sinkage(loads, wheel=_wheel(desc), soil=SOIL)
    np.testing.assert_allclose(ws[-1, 0::nf], z_static, rtol=0.05)


def _wheel(desc):
    return tm.WheelParams(radius_m=desc.wheel_radius_m, width_m=desc.wheel_width_m)


@pytest.mark.parametrize("preset", ["krex2_rp", "husky_rp"])
def test_rover_drives_straight_with_reference_slip_on_flat_ground(preset):
    logs, desc = _rover_sim(preset=preset, twist=(0.15, 0.0, 0.0), t=12.0)
    t = logs.vectors["truth.pose"].times
    pose = logs.vectors["truth.pose"].data
    enc = logs.vectors["rover.wheel_encoders"].data
    i0, i1 = np.searchsorted(t, 4.0), len(t) - 1
    gt = np.linalg.norm(pose[i1, :3] - pose[i0, :3])
    dr = np.mean(enc[i1] - enc[i0]) * desc.wheel_radius_m
    slip = 1 - gt / dr
    ref = wheel_reference.reference_slip(
        slope_rad=0.0, wheel_loads_N=level_wheel_loads(desc), wheel=_wheel(desc), soil=SOIL
    )
    assert slip == pytest.approx(ref, abs=0.01)
    assert abs(pose[i1, 1]) < 0.02 and abs(pose[i1, 5]) < math.radians(1.0)


def test_point_turn_and_crab_on_explicit_rover():
    logs, _ = _rover_sim(twist=(0.0, 0.0, 0.1), t=8.0)
    pose = logs.vectors["truth.pose"].data
    assert pose[-1, 5] > 0.3  # turned left in place
    assert np.hypot(pose[-1, 0] - pose[0, 0], pose[-1, 1] - pose[0, 1]) < 0.1
    logs, _ = _rover_sim(twist=(0.0, 0.1, 0.0), t=8.0)
    pose = logs.vectors["truth.pose"].data
    assert pose[-1, 1] - pose[0, 1] > 0.3  # crabbed left
    # Some yaw while the wheels swing to 90 deg (they drive as they steer).
    assert abs(pose[-1, 5]) < math.radians(5)


def test_spawn_errors_are_clear():
    hf = _plane(n=100)
    from lunar_drake.models.rover_sdf import add_rover

    plant = __import__("pydrake.multibody.plant", fromlist=["MultibodyPlant"]).MultibodyPlant(0.01)
    rover = add_rover(plant, description=rover_preset("krex2_rp"))
    plant.Finalize()
    with pytest.raises(OutOfBoundsError, match="rover spawn at"):
        spawn_pose(heightfield=hf, rover=rover, x_m=10.0, y_m=0.0, yaw_rad=0.0, soil=SOIL)
    z = np.zeros((100, 100), np.float32)
    z[10:90, 10:90] = np.nan
    holes = Heightfield.from_array(z, resolution_m=0.05)
    with pytest.raises(NoDataError, match="nodata"):
        spawn_pose(heightfield=holes, rover=rover, x_m=0.0, y_m=0.0, yaw_rad=0.0, soil=SOIL)


def test_bad_rover_and_soil_values_are_rejected():
    from lunar_drake.scenario_files import load_scenario

    with pytest.raises(ConfigError, match=r"unknown key 'rover\.soil'"):
        load_scenario(scenario_name="small", scenario_text="{rover: {soil: sand}}")
    with pytest.raises(OutOfRangeError, match=r"soil\.k_phi = -5 is out of range"):
        load_scenario(scenario_name="small", scenario_text="{soil: {k_phi: -5}}")
    with pytest.raises(ConfigError, match="steering"):
        load_scenario(
            scenario_name="small", scenario_text="{rover: {description: {steering: tracked}}}"
        )
    with pytest.raises(OutOfRangeError, match="wheel_radius_m"):
        load_scenario(
            scenario_name="small", scenario_text="{rover: {description: {wheel_radius_m: -1}}}"
        )
    with pytest.raises(OutOfRangeError):
        tm.SoilParams(k_phi=-5.0)
    from lunar_drake.studies.slip_study import SlipCase

    with pytest.raises(ConfigError, match="'tank'"):
        SlipCase(rover="tank", slope_deg=0.0, seed=0)


def test_skid_scenario_matches_the_husky_preset():
    import dataclasses as dc

    from lunar_drake.scenario_files import load_scenario

    assert dc.asdict(load_scenario(scenario_name="skid").rover.description) == dc.asdict(
        rover_preset("husky_rp")
    )


def test_driving_off_the_raster_ends_the_run_cleanly(small_site):
    from lunar_drake.scenario_files import apply_overrides
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    s = apply_overrides(
        scenario,
        "{simulation_duration: 40.0, rover: {spawn_x_m: 9.0}, sensors: {camera: {enabled: false}},"
        " ground: {route: [{duration_s: 1.0}, {duration_s: 60, vx_mps: 0.5}]}}",
    )
    logs = simulate(scenario=s, site=site)
    assert "left the terrain" in logs.stop_reason
    assert logs.simulated_s < 40.0
    assert len(logs.vectors["truth.pose"].times) > 10


def test_slip_study_matches_the_independent_reference_and_is_deterministic(tmp_path):
    """The explicit rover on planar ramps: the simulated steady-state slip within 3 pp of
    the independent steady-state wheel (wheel_reference: its own quadrature and root
    finding) where it can climb, sliding back where the reference says it cannot;
    monotone; byte-repeatable. (The full 0-20 deg sweep of both rovers is in the
    README/note: ``lunar-drake slip-study --rover skid,explicit --slopes 0:20:2``.)"""
    import json

    from lunar_drake.studies.slip_study import run_slip_case, run_slip_study

    rows = run_slip_study(
        rovers=["explicit"],
        slopes_deg=[0.0, 12.0, 22.0],
        distance_m=1.0,
        seeds=1,
        out_dir=tmp_path,
        progress=False,
    )
    by = {r["slope_deg"]: r for r in rows}
    for slope in (0.0, 12.0):
        assert not by[slope]["immobilized"]
        assert abs(by[slope]["slip"] - by[slope]["reference_slip"]) < 0.03
    assert by[12.0]["slip"] > by[0.0]["slip"] + 0.1  # slip rises with slope
    assert by[22.0]["immobilized"] and by[22.0]["slip"] > 1.0  # it slides back
    text = (tmp_path / "slip.csv").read_text().splitlines()
    assert text[0].split(",")[:6] == [
        "rover", "slope_deg", "seed", "slip", "reference_slip", "immobilized"
    ]  # fmt: skip
    assert text[-1].split(",")[5] == "true"
    assert (tmp_path / "slip.png").stat().st_size > 1000
    params = json.loads((tmp_path / "params.json").read_text())
    assert params["rovers"]["explicit"]["wheel_radius_m"] == 0.25
    assert len(params["rovers"]["explicit"]["static_wheel_load_level_N"]) == 4
    loads = {d["slope_deg"]: d["static_wheel_load_on_slope_N"] for d in params["slope_loads"]}
    assert loads[12.0][2] > loads[12.0][0]  # load moves to the rear wheels upslope
    # Byte-repeatable: the same case again gives the same row.
    from lunar_drake.studies.slip_study import SlipCase

    again = run_slip_case(SlipCase(rover="explicit", slope_deg=12.0, seed=0, distance_m=1.0))
    assert again["row"] == by[12.0]


def test_slip_study_roughness_makes_seeds_differ():
    from lunar_drake.studies.slip_study import ramp_heightfield

    a = ramp_heightfield(slope_deg=10.0, length_m=2.0, roughness_m=0.02, seed=0)
    b = ramp_heightfield(slope_deg=10.0, length_m=2.0, roughness_m=0.02, seed=1)
    flat = ramp_heightfield(slope_deg=10.0, length_m=2.0)
    za, zb, z0 = (h.read_window(0, 0, *h.shape).astype(float) for h in (a, b, flat))
    assert not np.array_equal(za, zb)
    c = ramp_heightfield(slope_deg=10.0, length_m=2.0, roughness_m=0.02, seed=0)
    np.testing.assert_array_equal(za, c.read_window(0, 0, *c.shape))
    # RMS deviation at a 1 m baseline (20 px at 5 cm) of the added roughness: ~2 cm.
    d = (za - z0)[:, 20:] - (za - z0)[:, :-20]
    assert 0.01 < math.sqrt(np.mean(d * d)) < 0.04


def test_rolling_wheel_has_no_slip():
    hf = _plane()
    v = 0.1
    # Pure rolling: hub speed v, absolute spin v / R about the axle.
    _, st = _contact_forces(hf, p=[0, 0, R - 0.012], v=[v, 0, 0], w_spin=v / R)
    assert st["slip"] == pytest.approx(0.0, abs=1e-12)


def test_scenario_rejects_bad_epoch():
    from lunar_drake.scenario_files import load_scenario

    with pytest.raises(ConfigError, match="epoch_utc"):
        load_scenario(scenario_name="small", scenario_text="{site: {epoch_utc: yesterday}}")
