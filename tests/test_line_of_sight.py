"""Line of sight to Earth over the terrain: core geometry, the system, the links."""

import math

import numpy as np
import pytest
from pydrake.systems.framework import BasicVector

from lunar_drake.comms import link as core
from lunar_drake.comms.line_of_sight import earth_margin_deg, terrain_horizon_deg
from lunar_drake.comms.messages import Message
from lunar_drake.errors import OutOfRangeError
from lunar_drake.systems.earth_line_of_sight import EarthLineOfSight
from lunar_drake.terrain.heightfield import Heightfield

RES = 0.5


def _wall_site(*, wall_x_m=20.0, wall_h_m=5.0):
    """A 100 m x 100 m flat site (origin at the centre) with a 2 m thick wall of height
    ``wall_h_m`` at x = ``wall_x_m`` (east of the centre)."""
    n = 200
    z = np.zeros((n, n))
    x = (np.arange(n) + 0.5 - n / 2) * RES
    z[:, (x >= wall_x_m) & (x < wall_x_m + 2.0)] = wall_h_m
    return Heightfield.from_array(z, resolution_m=RES)


def test_horizon_of_a_wall_and_of_a_flat_site_against_closed_forms():
    hf = _wall_site()
    # Antenna 1 m above the ground at the centre; the wall's top edge (5 m) nearest at
    # x = 20 m (bilinear: full height from the first sample inside the wall, x = 20.25).
    h = terrain_horizon_deg(
        heightfield=hf, p_W=[0.0, 0.0, 1.0], azimuth_rad=math.pi / 2, step_m=0.05
    )
    d = 20.25
    expected = math.degrees(math.atan((4.0 - d * d / (2 * 1737.4e3)) / d))
    assert h == pytest.approx(expected, abs=0.05)
    # Looking west: flat ground 1 m below, the farthest sample (~49.75 m) sets the
    # horizon: atan(-1 / d) is largest (least negative) at the largest d.
    west = terrain_horizon_deg(heightfield=hf, p_W=[0.0, 0.0, 1.0], azimuth_rad=-math.pi / 2)
    assert west == pytest.approx(math.degrees(math.atan(-1.0 / 49.5)), abs=0.02)
    with pytest.raises(OutOfRangeError, match="off the site raster"):
        terrain_horizon_deg(heightfield=hf, p_W=[80.0, 0.0, 1.0], azimuth_rad=0.0)


def test_earth_margin_behind_the_wall_and_in_the_open():
    hf = _wall_site()
    el = math.radians(5.0)
    east = [math.cos(el), 0.0, math.sin(el)]  # x is grid east: azimuth 90 deg
    north = [0.0, math.cos(el), math.sin(el)]
    behind = earth_margin_deg(heightfield=hf, p_W=[0.0, 0.0, 1.0], earth_direction_W=east)
    # Sampled every 0.5 m (the raster resolution): within 0.2 deg of the exact edge.
    assert behind == pytest.approx(5.0 - math.degrees(math.atan(4.0 / 20.25)), abs=0.2)
    assert behind < 0
    assert earth_margin_deg(heightfield=hf, p_W=[0.0, 0.0, 1.0], earth_direction_W=north) > 4.9


def test_system_holds_visibility_and_margin():
    hf = _wall_site()
    sys = EarthLineOfSight(heightfield=hf, period_s=1.0, antenna_height_m=1.0)
    ctx = sys.CreateDefaultContext()
    el = math.radians(5.0)
    pose = np.zeros(12)
    for direction, visible in (([math.cos(el), 0, math.sin(el)], 0.0), ([0, 1, 0.1], 1.0)):
        sys.earth_direction_input.FixValue(ctx, direction)
        sys.pose_input.FixValue(ctx, pose)
        state = sys.EvalUniquePeriodicDiscreteUpdate(ctx)
        ctx.SetDiscreteState(state.get_vector(0).value())
        assert sys.earth_visible_output.Eval(ctx)[0] == visible
        assert (sys.earth_margin_output.Eval(ctx)[0] > 0) == bool(visible)
    assert isinstance(sys.earth_visible_output.Allocate().get_value(), BasicVector)


def test_link_loses_everything_out_of_sight_and_nothing_in_sight():
    msgs = [Message(topic="telemetry", seq=k, t_sent_s=0.1 * k, payload=None, size_bytes=50)
            for k in range(10)]  # fmt: skip
    cfg = core.LinkConfig(delay_s=1.3)
    s = core.accept(core.LinkState(), msgs[:5], config=cfg, now_s=0.5, earth_visible=False)
    s = core.accept(s, msgs[5:], config=cfg, now_s=1.0, earth_visible=True)
    rows = core.records(s, 10.0, direction="downlink")
    assert [r.reason for r in rows if r.dropped] == ["no_line_of_sight"] * 5
    assert sorted(r.seq for r in rows if not r.dropped) == [5, 6, 7, 8, 9]


def test_mission_out_of_sight_of_earth_hears_nothing(small_site):
    """With the Earth never counted visible (margin above 89 deg required), both links
    lose every message: the ground hears nothing and the rover never gets its route."""
    from lunar_drake.scenario_files import apply_overrides
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    blind = apply_overrides(
        scenario,
        "{simulation_duration: 3.0, sensors: {camera: {enabled: false}},"
        " comms: {line_of_sight: {min_margin_deg: 89.0}}}",
    )
    logs = simulate(scenario=blind, site=site, progress=False)
    assert logs.link and all(r.dropped and r.reason == "no_line_of_sight" for r in logs.link)
    assert len(logs.telemetry.seq) == 0
    pose = logs.vectors["truth.pose"].data
    assert np.linalg.norm(pose[-1, :2] - pose[0, :2]) < 0.05  # no command arrived
    margin = logs.vectors["truth.earth_margin_deg"].data[:, 0] if (
        "truth.earth_margin_deg" in logs.vectors) else None  # fmt: skip
    if margin is not None:
        assert np.all(margin < 89.0)


def test_default_delay_is_the_light_time_from_the_ephemeris_plus_ground_processing():
    """delay_s unset: the one-way delay is the SPICE light time at the epoch plus
    ground_processing_s; checked against the Earth-Moon distance range (356 400 -
    406 700 km: 1.19 - 1.36 s) and the ephemeris distance at two epochs."""
    from lunar_drake.comms.light_time import SPEED_OF_LIGHT_MPS, light_time_s
    from lunar_drake.ephemeris.sun_earth import SiteLocation, sun_earth_enu

    site = SiteLocation(-85.4, 31.6)
    a = light_time_s(site=site, epoch_utc="2027-11-15T00:00:00")
    b = light_time_s(site=site, epoch_utc="2028-01-01T00:00:00")
    assert 1.19 < a < 1.36 and 1.19 < b < 1.36 and abs(a - b) > 0.05
    d = sun_earth_enu(utc="2027-11-15T00:00:00", site=site).earth_distance_km
    assert a == pytest.approx(d * 1e3 / SPEED_OF_LIGHT_MPS, rel=1e-12)
    cfg = core.LinkConfig(ground_processing_s=0.07)
    assert cfg.one_way_delay_s("telemetry", light_time_s=a) == pytest.approx(a + 0.07)
    assert core.LinkConfig(delay_s=2.0).one_way_delay_s("x", light_time_s=a) == 2.0
    with pytest.raises(Exception, match="no light time"):
        cfg.one_way_delay_s("telemetry", light_time_s=None)


def test_mission_link_uses_the_light_time_by_default(small_site):
    from lunar_drake.comms.light_time import light_time_s
    from lunar_drake.ephemeris.sun_earth import SiteLocation
    from lunar_drake.scenario_files import apply_overrides
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    s = apply_overrides(
        scenario,
        "{simulation_duration: 4.0, sensors: {camera: {enabled: false}},"
        " comms: {downlink: {ground_processing_s: 0.1}}}",
    )
    s.comms.downlink.delay_s = None  # small sets 0; back to the default
    logs = simulate(scenario=s, site=site, progress=False)
    lt = light_time_s(
        site=SiteLocation(s.site.latitude_deg, s.site.longitude_deg), epoch_utc=s.site.epoch_utc
    )
    got = [r for r in logs.link if r.direction == "downlink" and math.isfinite(r.t_received)]
    assert got and all(r.t_received - r.t_sent == pytest.approx(lt + 0.1, abs=1e-9) for r in got)
