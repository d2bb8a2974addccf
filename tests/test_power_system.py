"""The power system in the plant (lunar_drake/systems/power_system.py), checked against
hand computations that do not call the power code: a level, static rover on a flat site
with its vertical panel facing the Sun, turned 90 degrees from it, and behind a terrain
horizon that hides part of the solar disk; then power.csv and the summary's section.

Reference figures (SPICE through the ephemeris module, not the power code): at the
default site (85.4 S, 31.6 E) and epoch (2027-11-15T00:00:00) the Sun stands about 4.65
deg high at grid azimuth 344.8 deg.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lunar_drake.ephemeris.sun_earth import (
    SiteLocation,
    site_frame_rotation,
    sun_earth_enu,
    utc_to_tdb_s,
)
from lunar_drake.power.loads import LoadsConfig, load_breakdown, mean_load_breakdown
from lunar_drake.rotations import rotation_matrix_from_rpy
from lunar_drake.scenario import RouteSegment, Scenario

AU_KM = 149_597_870.7  # IAU 2012
SOLAR_CONSTANT = 1361.0  # W/m^2 at 1 au (Kopp & Lean 2011)
SUN_RADIUS_KM = 695_700.0  # IAU 2015 nominal
MOON_RADIUS_M = 1_737_400.0
DURATION_S = 3.0
RES_M, N_PX = 0.1, 500  # a 50 m x 50 m site centred on the spawn point


def _sun(scenario: Scenario, t_s: float):
    """(unit vector to the Sun in the site grid frame, distance km) at sim time t_s."""
    site = SiteLocation(scenario.site.latitude_deg, scenario.site.longitude_deg)
    se = sun_earth_enu(epoch_tdb_s=utc_to_tdb_s(scenario.site.epoch_utc) + t_s, site=site)
    s = site_frame_rotation(site).T @ np.asarray(se.sun_dir_enu)
    return s / np.linalg.norm(s), float(se.sun_distance_km)


def _az_el(s):
    return math.atan2(s[0], s[1]), math.asin(s[2])


def _scenario(*, yaw_deg: float) -> Scenario:
    s = Scenario(name="power")
    s.simulation_duration = DURATION_S
    s.sensors.camera.enabled = False
    s.rover.spawn_yaw_deg = yaw_deg
    s.ground.route = [RouteSegment(duration_s=100.0)]  # stand still (braked)
    s.comms.uplink.delay_s = s.comms.downlink.delay_s = 0.0
    return s


def _simulate(scenario: Scenario, z: np.ndarray):
    from lunar_drake.simulation import simulate
    from lunar_drake.site import SiteData
    from lunar_drake.terrain.heightfield import Heightfield

    site = SiteData.from_heightfield(Heightfield.from_array(z, resolution_m=RES_M))
    return simulate(scenario=scenario, site=site), site


def _facing_yaw_deg(scenario: Scenario) -> float:
    """The default rover's panel faces +y of the chassis (tilt and azimuth 90 deg): a
    chassis yaw of minus the Sun's azimuth (clockwise from grid north) turns it to the
    Sun's azimuth."""
    d = scenario.rover.description
    assert d.solar_panel_tilt_rad == pytest.approx(math.pi / 2)
    assert d.solar_panel_azimuth_rad == pytest.approx(math.pi / 2)
    az, _ = _az_el(_sun(scenario, 0.0)[0])
    return -math.degrees(az)


def _expected_W(scenario: Scenario, *, t_s: float, cos_i: float, fraction: float = 1.0):
    """S(d) * A * eta(T) * cos(i) * f, by hand from the config's numbers."""
    _, d_km = _sun(scenario, t_s)
    a = scenario.power.array
    desc = scenario.rover.description
    S = SOLAR_CONSTANT * (AU_KM / d_km) ** 2
    A = desc.solar_panel_width_m * desc.solar_panel_height_m
    eta = a.cell_efficiency * a.packing_factor * (
        1.0 + a.temperature_coefficient_per_K * (a.panel_temperature_K - a.reference_temperature_K)
    )
    return S * A * eta * max(cos_i, 0.0) * fraction


def _panel_centre_W(scenario: Scenario, pose_row) -> np.ndarray:
    """The panel centre in W from a truth.pose row, by hand from the description."""
    d = scenario.rover.description
    p_BP = np.array([d.solar_panel_x_m, d.solar_panel_y_m,
                     d.chassis_height_m / 2 + d.solar_panel_mount_height_m])  # fmt: skip
    return pose_row[:3] + rotation_matrix_from_rpy(pose_row[3:6]) @ p_BP


@pytest.fixture(scope="module")
def facing(tmp_path_factory):
    """The level, static rover with its panel facing the Sun's azimuth, on a flat site."""
    s = _scenario(yaw_deg=0.0)
    s.rover.spawn_yaw_deg = _facing_yaw_deg(s)
    logs, site = _simulate(s, np.zeros((N_PX, N_PX), np.float32))
    return s, logs, site


def _last(logs, column: str) -> float:
    return float(logs.vectors["truth.power"].column(column)[-1])


def test_vertical_panel_facing_the_sun_charges_at_S_cos_el_A_eta(facing):
    scenario, logs, _ = facing
    pose = logs.vectors["truth.pose"].data
    assert np.abs(pose[-1, 3:5]).max() < math.radians(0.1)  # level
    assert np.abs(pose[-1, 6:9]).max() < 1e-3  # static
    # The array was last evaluated at the update at t = DURATION_S - 1 (held since).
    _, el = _az_el(_sun(scenario, DURATION_S - 1.0)[0])
    expected = _expected_W(scenario, t_s=DURATION_S - 1.0, cos_i=math.cos(el))
    simulated = _last(logs, "array_W")
    print(f"facing the Sun: expected {expected:.4f} W, simulated {simulated:.4f} W")
    assert simulated == pytest.approx(expected, rel=0.01)
    assert _last(logs, "sun_incidence_deg") == pytest.approx(math.degrees(el), abs=0.2)
    assert _last(logs, "visible_fraction") == 1.0
    # Loads: the constant draws plus the holding draw (braked at a standstill).
    cfg = scenario.power.loads
    constants = cfg.avionics_W + cfg.cameras_W + cfg.radio_W + cfg.instruments_W + cfg.heaters_W
    assert _last(logs, "load_W") == pytest.approx(constants + cfg.holding_W, abs=0.05)
    assert _last(logs, "soc") == 1.0  # full, the surplus shunted


def test_panel_turned_90_degrees_gets_no_direct_sun_and_the_battery_drains():
    s = _scenario(yaw_deg=0.0)
    s.rover.spawn_yaw_deg = _facing_yaw_deg(s) + 90.0
    logs, _ = _simulate(s, np.zeros((N_PX, N_PX), np.float32))
    facing_W = _expected_W(s, t_s=DURATION_S - 1.0, cos_i=1.0)
    array_W = logs.vectors["truth.power"].column("array_W")
    print(f"turned 90 deg: expected 0 W, simulated {array_W.max():.3g} W (max over the run)")
    assert np.abs(array_W).max() < 1e-3 * facing_W
    assert _last(logs, "sun_incidence_deg") == pytest.approx(90.0, abs=0.1)
    # Each battery update (every 1 s) takes 1 s of the constant draws plus the holding
    # draw from the battery through its discharge efficiency. A log sample at the time
    # of an update precedes it (Drake publishes before the step's discrete updates), so
    # the samples in (1, 2] s show one update and those in (2, 3] s two.
    cfg, bat = s.power.loads, s.power.battery
    load = cfg.avionics_W + cfg.cameras_W + cfg.radio_W + cfg.instruments_W + cfg.heaters_W
    load += cfg.holding_W
    one = load * 1.0 / 3600.0 / bat.discharge_efficiency / bat.capacity_Wh
    log = logs.vectors["truth.power"]
    soc = log.column("soc")
    for t, n in ((1.0, 0), (1.5, 1), (2.0, 1), (2.5, 2), (3.0, 2)):
        k = int(np.argmin(np.abs(log.times - t)))
        assert soc[k] == pytest.approx(bat.initial_soc - n * one, abs=1e-9), t
    assert np.all(np.diff(soc) <= 0.0)
    assert log.column("load_W")[-1] == pytest.approx(load, abs=1e-3)



def test_panel_behind_a_terrain_horizon_gets_the_visible_part_of_the_disk(facing):
    """Beyond 15 m along the Sun's azimuth the ground rises as a plane of slope tan h0
    passing 2 cm above the panel's height at the panel (seen from the panel, its
    elevation falls slowly with distance: the horizon is its near edge), aimed at a
    twentieth of the Sun's radius above the Sun's centre; in front, the flat site."""
    scenario, flat_logs, _ = facing
    s = _scenario(yaw_deg=scenario.rover.spawn_yaw_deg)
    sun0, d_km = _sun(s, 0.0)
    az, el = _az_el(sun0)
    r = math.asin(SUN_RADIUS_KM / d_km)
    u0, u1, margin = 14.0, 15.0, 0.02
    # Aim the horizon a twentieth of the radius above the Sun's centre.
    h0 = math.atan(math.tan(el + 0.05 * r) - margin / u1)
    p_P = _panel_centre_W(s, flat_logs.vectors["truth.pose"].data[-1])
    # The site: u = distance along the Sun's azimuth from the panel.
    c = (np.arange(N_PX) + 0.5 - N_PX / 2) * RES_M
    x, y = np.meshgrid(c, -c)  # row 0 north
    u = (x - p_P[0]) * math.sin(az) + (y - p_P[1]) * math.cos(az)
    plane = p_P[2] + margin + u * math.tan(h0)
    z = np.where(u >= u1, plane, np.where(u > u0, (u - u0) / (u1 - u0) * plane, 0.0))
    logs, _ = _simulate(s, z.astype(np.float32))

    pose = logs.vectors["truth.pose"].data[-1]
    p = _panel_centre_W(s, pose)
    du = (p[0] - p_P[0]) * math.sin(az) + (p[1] - p_P[1]) * math.cos(az)
    # The plane seen from the panel: tan(elevation) at distance d is tan h0 + dz / d -
    # d / (2 R) (the Moon's curvature), dz its height above the panel at the panel;
    # largest at the plane's near edge, d = u1 - du (the raster march samples it a step
    # of 0.1 m further at most: 9e-6 rad lower, 0.2 % of the Sun's radius).
    dz = p_P[2] + margin + du * math.tan(h0) - p[2]
    d = u1 - du
    h = math.atan(math.tan(h0) + dz / d - d / (2 * MOON_RADIUS_M))
    t = DURATION_S - 1.0
    sun_t, _ = _sun(s, t)
    _, el_t = _az_el(sun_t)
    v = (el_t - h) / r  # the Sun's centre above the horizon, in radii (a level line)
    segment_below = math.acos(v) - v * math.sqrt(1 - v * v)  # area / r^2
    fraction = 1.0 - segment_below / math.pi
    assert 0.3 < fraction < 0.6
    expected = _expected_W(s, t_s=t, cos_i=math.cos(el_t), fraction=fraction)
    simulated = _last(logs, "array_W")
    print(f"behind the horizon: visible fraction expected {fraction:.4f}, simulated "
          f"{_last(logs, 'visible_fraction'):.4f}; array expected {expected:.3f} W, "
          f"simulated {simulated:.3f} W")  # fmt: skip
    assert _last(logs, "visible_fraction") == pytest.approx(fraction, abs=0.01)
    assert simulated == pytest.approx(expected, rel=0.01)


def test_power_csv_and_the_summary_power_section(facing, tmp_path):
    from lunar_drake import metrics, outputs

    scenario, logs, site = facing
    summary = metrics.summarize(scenario=scenario, site=site, logs=logs)
    outputs.write_run(tmp_path, scenario=scenario, logs=logs, summary=summary, timing={})
    lines = (tmp_path / "power.csv").read_text().splitlines()
    assert lines[0] == "t_s,sun_incidence_deg,visible_fraction,array_W,load_W,soc"
    table = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    t, incidence, fraction, array_W, load_W, soc = table.T
    assert np.all(incidence < 90.0) and np.all(fraction == 1.0)
    assert t[0] == 0.0 and t[-1] == pytest.approx(DURATION_S)
    power = summary["power"]
    # Each sample held until the next.
    assert power["energy_generated_Wh"] == pytest.approx(
        np.sum(array_W[:-1] * np.diff(t)) / 3600.0, abs=1e-6  # the summary rounds to 6 decimals
    )
    assert power["energy_generated_Wh"] == pytest.approx(array_W[0] * DURATION_S / 3600, rel=1e-3)
    assert power["energy_used_Wh"] == pytest.approx(
        np.sum(load_W[:-1] * np.diff(t)) / 3600.0, abs=1e-6  # the summary rounds to 6 decimals
    )
    assert power["min_soc"] == soc.min() and power["final_soc"] == soc[-1]
    assert power["shadow_s"] == 0.0
    # a static rover creeps a few mm: the per-metre figures are None under 1 m of traverse
    assert summary["rover"]["distance_m"] < metrics.MIN_RATE_DISTANCE_M
    assert power["Wh_per_m"] is None
    assert summary["localization"]["error_per_distance"] is None
    json_text = (tmp_path / "summary.json").read_text()
    assert '"power": {' in json_text


def test_plant_exports_the_power_sensor_beside_truth_and_power_can_be_off():
    """``rover.power`` (SOC, array W, load W) reports what ``truth.power`` holds (an ideal
    sensor); with ``power.enabled`` false neither port exists and no power.csv is due."""
    from pydrake.systems.analysis import Simulator

    from lunar_drake.diagrams.plant import MakePlantDiagram
    from lunar_drake.site import SiteData
    from lunar_drake.terrain.heightfield import Heightfield

    site = SiteData.from_heightfield(
        Heightfield.from_array(np.zeros((200, 200), np.float32), resolution_m=RES_M)
    )
    s = _scenario(yaw_deg=0.0)
    s.power.battery.capacity_Wh = 10.0  # drains visibly in a second
    plant = MakePlantDiagram(scenario=s, site=site)
    sim = Simulator(plant)
    ctx = sim.get_mutable_context()
    for k in range(plant.num_input_ports()):
        port = plant.get_input_port(k)
        value = np.ones(port.size()) if port.get_name() == "rover.brake_command" else None
        port.FixValue(ctx, np.zeros(port.size()) if value is None else value)
    sim.AdvanceTo(1.5)
    truth = plant.GetOutputPort("truth.power").Eval(ctx)
    sensor = plant.GetOutputPort("rover.power").Eval(ctx)
    np.testing.assert_array_equal(sensor, truth[[4, 2, 3]])
    assert truth[4] < 1.0 or truth[2] > truth[3]  # drained, unless the array covers the loads
    s.power.enabled = False
    off = MakePlantDiagram(scenario=s, site=site)
    assert not off.HasOutputPort("truth.power") and not off.HasOutputPort("rover.power")


def test_mean_loads_over_a_period_equal_the_instantaneous_loads_at_constant_torque():
    cfg = LoadsConfig()
    tau, w, dt = np.array([10.0, 12.0, -3.0, 8.0]), np.array([2.0, 2.0, 2.0, -1.0]), 0.7
    work = float(np.sum(np.maximum(tau * w, 0.0))) * dt  # 44 W for 0.7 s
    steer_work = 3.0 * 0.5 * dt
    a = mean_load_breakdown(config=cfg, dt_s=dt, drive_work_J=work, steer_work_J=steer_work,
                            braked=True)  # fmt: skip
    b = load_breakdown(config=cfg, drive_torque_Nm=tau, drive_speed_rad_s=w,
                       steer_torque_Nm=[3.0], steer_speed_rad_s=[0.5], braked=True)  # fmt: skip
    assert a.drive_W == pytest.approx(44.0 / 0.6)
    assert a.steer_W == pytest.approx(1.5 / 0.5) and a.holding_W == cfg.holding_W
    for name in ("drive_W", "steer_W", "holding_W", "avionics_W", "heaters_W"):
        assert getattr(a, name) == pytest.approx(getattr(b, name)), name
    assert a.total_W == pytest.approx(b.total_W)
