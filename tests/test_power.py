"""The power core checked against hand computations written here, not with its own code.

Issue 30's check: a level, static rover with a vertical panel facing the Sun's azimuth
charges at S cos(el) A eta within 1 %; turned 90 degrees, at 0 (direct); behind a
terrain horizon, at the visible fraction of the disk (brute-force sampled here).
"""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError
from lunar_drake.power.battery import BatteryConfig, battery_step
from lunar_drake.power.config import PowerConfig
from lunar_drake.power.loads import LoadsConfig, load_breakdown, motor_electrical_W
from lunar_drake.power.solar_array import (
    PanelMount,
    SolarArrayConfig,
    array_output,
    sun_disk_visible_fraction,
)
from lunar_drake.render.horizon import HorizonMask
from lunar_drake.terrain.heightfield import Heightfield

AU = 149_597_870.7  # km
R_SUN = 695_700.0  # km
R_MOON = 1_737_400.0  # m
RES = 0.5  # m, test raster
PANEL_XY = (0.25, 0.25)  # a pixel centre of the 128 x 128 test raster
# Panel: vertical, facing the chassis' left (+y_B), 1.0 x 0.7 m, behind and above the origin.
MOUNT = PanelMount(n_B=(0.0, 1.0, 0.0), p_BP=(-0.15, 0.0, 0.8), area_m2=0.7)
P_WB = np.array([PANEL_XY[0] + 0.15, PANEL_XY[1], 0.7])


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def sun_north(el_deg):
    """Unit vector to a Sun due grid north (+y) at elevation ``el_deg``."""
    e = math.radians(el_deg)
    return np.array([0.0, math.cos(e), math.sin(e)])


def hand_eta(cfg, temperature_K):
    return (
        cfg.cell_efficiency
        * cfg.packing_factor
        * (1.0 + cfg.temperature_coefficient_per_K * (temperature_K - cfg.reference_temperature_K))
    )


def flat_site(wall_height_m=None, wall_last_row=None):
    """128 x 128 raster at 0.5 m, level at z = 0; rows 0..wall_last_row (north) raised."""
    z = np.zeros((128, 128))
    if wall_height_m is not None:
        z[: wall_last_row + 1, :] = wall_height_m
    return Heightfield.from_array(z, resolution_m=RES)


def brute_force_fraction(sun_el, horizon_el, radius, n=1201):
    """Fraction of a uniform disk above a level line, by counting grid points."""
    u = np.linspace(-1.0, 1.0, n)
    X, Y = np.meshgrid(u, u)
    inside = X * X + Y * Y <= 1.0
    above = sun_el + Y * radius > horizon_el
    return float((inside & above).sum() / inside.sum())


# ------------------------------------------------------------------------------------------
# (a), (b): incidence on a level, static rover
def test_level_rover_vertical_panel_facing_sun_gives_S_cos_el_A_eta():
    cfg = SolarArrayConfig()
    el, d_km = 4.0, 1.012 * AU
    out = array_output(config=cfg, mount=MOUNT, R_WB=np.eye(3), p_WB=P_WB,
                       sun_direction_W=sun_north(el), sun_distance_km=d_km,
                       heightfield=flat_site())  # fmt: skip
    S = 1361.0 / 1.012**2
    expected = S * math.cos(math.radians(el)) * 0.7 * hand_eta(cfg, 300.0)
    assert out.power_W == pytest.approx(expected, rel=0.01)
    assert out.power_W == pytest.approx(expected, rel=1e-9)  # nothing hides the Sun here
    assert out.visible_fraction == 1.0
    assert out.incidence_deg == pytest.approx(el, abs=1e-9)
    assert out.sun_azimuth_deg == pytest.approx(0.0, abs=1e-9)


def test_rover_turned_90_degrees_gets_no_direct_power():
    for yaw_deg in (90.0, -90.0, 180.0):
        out = array_output(config=SolarArrayConfig(), mount=MOUNT,
                           R_WB=rot_z(math.radians(yaw_deg)), p_WB=P_WB,
                           sun_direction_W=sun_north(4.0), sun_distance_km=AU,
                           heightfield=flat_site())  # fmt: skip
        assert abs(out.power_W) < 1e-9
    side = array_output(
        config=SolarArrayConfig(),
        mount=MOUNT,
        R_WB=rot_z(math.pi / 2),
        p_WB=P_WB,
        sun_direction_W=sun_north(0.0),
        sun_distance_km=AU,
    )
    assert side.incidence_deg == pytest.approx(90.0, abs=1e-9)


def test_rolled_rover_tilts_the_panel_normal_towards_the_sun():
    # Rolling about x_B by phi turns +y_B to (0, cos phi, sin phi): incidence |el - phi|.
    phi, el = 10.0, 4.0
    out = array_output(
        config=SolarArrayConfig(),
        mount=MOUNT,
        R_WB=rot_x(math.radians(phi)),
        p_WB=P_WB,
        sun_direction_W=sun_north(el),
        sun_distance_km=AU,
    )
    assert out.incidence_deg == pytest.approx(phi - el, abs=1e-9)
    level = array_output(
        config=SolarArrayConfig(),
        mount=MOUNT,
        R_WB=np.eye(3),
        p_WB=P_WB,
        sun_direction_W=sun_north(el),
        sun_distance_km=AU,
    )
    ratio = math.cos(math.radians(phi - el)) / math.cos(math.radians(el))
    assert out.power_W / level.power_W == pytest.approx(ratio, rel=1e-9)


def test_temperature_derates_efficiency_and_distance_scales_as_inverse_square():
    cfg = SolarArrayConfig()
    kw = dict(config=cfg, mount=MOUNT, R_WB=np.eye(3), p_WB=P_WB, sun_direction_W=sun_north(2.0))
    hot = array_output(**kw, sun_distance_km=AU, panel_temperature_K=360.0)
    ref = array_output(**kw, sun_distance_km=AU, panel_temperature_K=301.15)
    far = array_output(**kw, sun_distance_km=1.02 * AU, panel_temperature_K=301.15)
    assert hot.power_W / ref.power_W == pytest.approx(1.0 - 0.0025 * (360.0 - 301.15), rel=1e-12)
    assert far.power_W / ref.power_W == pytest.approx(1.0 / 1.02**2, rel=1e-12)


# ------------------------------------------------------------------------------------------
# (c): a terrain horizon across the solar disk
@pytest.mark.parametrize("offset", [-1.3, -0.8, -0.35, 0.0, 0.2, 0.6, 0.95, 1.4])
def test_circular_segment_fraction_matches_brute_force_disk_sampling(offset):
    r = math.asin(R_SUN / AU)
    e = math.radians(3.0)
    h = e - offset * r
    exact = sun_disk_visible_fraction(sun_elevation_rad=e, horizon_elevation_rad=h,
                                      sun_radius_rad=r)  # fmt: skip
    assert exact == pytest.approx(brute_force_fraction(e, h, r), abs=2e-3)


def test_terrain_horizon_from_panel_height_cuts_the_disk():
    el = 3.0
    r = math.asin(R_SUN / AU)
    e = math.radians(el)
    h = e - 0.35 * r  # the horizon a third of a radius below the disk's centre
    z_panel = P_WB[2] + 0.8
    D = 20.0  # m: the wall's first pixel centre due north of the panel (row 23)
    wall = z_panel + D * math.tan(h) + D * D / (2.0 * R_MOON)
    site = flat_site(wall_height_m=wall, wall_last_row=23)
    assert site.height(PANEL_XY[0], PANEL_XY[1] + D) == pytest.approx(wall)
    kw = dict(config=SolarArrayConfig(), mount=MOUNT, R_WB=np.eye(3), p_WB=P_WB,
              sun_direction_W=sun_north(el), sun_distance_km=AU)  # fmt: skip
    hidden = array_output(**kw, heightfield=site)
    clear = array_output(**kw, heightfield=flat_site())
    frac = brute_force_fraction(e, h, r)
    assert 0.3 < frac < 0.9
    assert hidden.horizon_elevation_deg == pytest.approx(math.degrees(h), abs=1e-9)
    assert hidden.visible_fraction == pytest.approx(frac, abs=2e-3)
    assert hidden.power_W == pytest.approx(frac * clear.power_W, rel=0.01)
    # The same wall 1 m higher hides the whole disk: no direct power.
    dark = array_output(**kw, heightfield=flat_site(wall_height_m=wall + 1.0, wall_last_row=23))
    assert dark.power_W == 0.0 and dark.visible_fraction == 0.0


def test_outside_horizon_mask_at_the_suns_elevation_hides_half_the_disk():
    out = array_output(config=SolarArrayConfig(), mount=MOUNT, R_WB=np.eye(3), p_WB=P_WB,
                       sun_direction_W=sun_north(2.0), sun_distance_km=AU,
                       heightfield=flat_site(), horizon_mask=HorizonMask.level(2.0))  # fmt: skip
    assert out.visible_fraction == pytest.approx(0.5, abs=1e-9)


def test_panel_mount_from_a_rover_description():
    d = SimpleNamespace(solar_panel_tilt_rad=math.pi / 2, solar_panel_azimuth_rad=math.pi / 2,
                        solar_panel_x_m=-0.15, solar_panel_y_m=0.0, chassis_height_m=0.4,
                        solar_panel_mount_height_m=0.45, solar_panel_width_m=1.0,
                        solar_panel_height_m=0.7)  # fmt: skip
    m = PanelMount.from_description(d)
    assert np.allclose(m.n_B, (0.0, 1.0, 0.0), atol=1e-15)
    assert np.allclose(m.p_BP, (-0.15, 0.0, 0.65))
    assert m.area_m2 == pytest.approx(0.7)


# ------------------------------------------------------------------------------------------
# (d): battery bookkeeping and loads
def test_battery_charge_and_discharge_efficiencies():
    cfg = BatteryConfig(capacity_Wh=1000.0, charge_efficiency=0.9, discharge_efficiency=0.8)
    up = battery_step(config=cfg, soc=0.5, net_power_W=100.0, dt_s=3600.0)
    assert up.soc == pytest.approx(0.5 + 90.0 / 1000.0)
    assert up.stored_Wh == pytest.approx(90.0) and up.shunted_Wh == 0.0 and up.unmet_Wh == 0.0
    down = battery_step(config=cfg, soc=0.5, net_power_W=-100.0, dt_s=3600.0)
    assert down.soc == pytest.approx(0.5 - 125.0 / 1000.0)
    assert down.stored_Wh == pytest.approx(-125.0) and down.unmet_Wh == 0.0
    # Round trip: 100 Wh in at the bus gives back 0.9 * 0.8 = 72 Wh.
    back = battery_step(config=cfg, soc=up.soc, net_power_W=-72.0, dt_s=3600.0)
    assert back.soc == pytest.approx(0.5)


def test_battery_clamps_at_full_and_empty():
    cfg = BatteryConfig(capacity_Wh=1000.0, charge_efficiency=0.9, discharge_efficiency=0.8)
    full = battery_step(config=cfg, soc=0.95, net_power_W=100.0, dt_s=3600.0)
    assert full.soc == 1.0
    assert full.stored_Wh == pytest.approx(50.0)
    assert full.shunted_Wh == pytest.approx(100.0 - 50.0 / 0.9)
    empty = battery_step(config=cfg, soc=0.05, net_power_W=-100.0, dt_s=3600.0)
    assert empty.soc == 0.0
    assert empty.stored_Wh == pytest.approx(-50.0)
    assert empty.unmet_Wh == pytest.approx(100.0 - 50.0 * 0.8)
    assert battery_step(config=cfg, soc=1.0, net_power_W=50.0, dt_s=60.0).soc == 1.0
    assert battery_step(config=cfg, soc=0.0, net_power_W=-50.0, dt_s=60.0).soc == 0.0
    assert battery_step(config=cfg, soc=0.3, net_power_W=0.0, dt_s=60.0).soc == 0.3


def test_loads_motor_power_over_efficiency_holding_and_constant_draws():
    cfg = LoadsConfig(drive_efficiency=0.5, steer_efficiency=0.25, holding_W=8.0)
    # Four drive wheels: 10 N*m at 2 rad/s each, one braking (-10 N*m at 2 rad/s: nothing).
    drive = motor_electrical_W(torque_Nm=[10.0, 10.0, 10.0, -10.0], speed_rad_s=[2.0] * 4,
                               efficiency=0.5)  # fmt: skip
    assert drive == pytest.approx(3 * 20.0 / 0.5)
    loads = load_breakdown(config=cfg, drive_torque_Nm=[10.0] * 4, drive_speed_rad_s=[2.0] * 4,
                           steer_torque_Nm=[1.0], steer_speed_rad_s=[0.5])  # fmt: skip
    constant = 45.0 + 10.0 + 25.0 + 20.0 + 20.0
    assert loads.total_W == pytest.approx(80.0 / 0.5 + 0.5 / 0.25 + constant)
    parked = load_breakdown(config=cfg, braked=True)
    assert parked.total_W == pytest.approx(8.0 + constant)


# ------------------------------------------------------------------------------------------
# (e): configuration errors name the field
def test_defaults_validate():
    PowerConfig().validate()


@pytest.mark.parametrize(
    "config, key, allowed",
    [
        (PowerConfig(array=SolarArrayConfig(cell_efficiency=1.5)), "array.cell_efficiency",
         "(0, 1]"),
        (PowerConfig(array=SolarArrayConfig(temperature_coefficient_per_K=0.01)),
         "array.temperature_coefficient_per_K", "[-0.02, 0]"),
        (PowerConfig(battery=BatteryConfig(capacity_Wh=0.0)), "battery.capacity_Wh",
         "(0, 1e+06] Wh"),
        (PowerConfig(battery=BatteryConfig(initial_soc=1.2)), "battery.initial_soc", "[0, 1]"),
        (PowerConfig(loads=LoadsConfig(radio_W=-1.0)), "loads.radio_W", "[0, 10000] W"),
        (PowerConfig(loads=LoadsConfig(drive_efficiency=float("nan"))),
         "loads.drive_efficiency", "(0, 1]"),
    ],
)  # fmt: skip
def test_config_errors_name_the_field_and_range(config, key, allowed):
    with pytest.raises(OutOfRangeError) as err:
        config.validate()
    msg = str(err.value)
    assert msg.startswith(f"{key} = ") and allowed in msg
    assert isinstance(err.value, ValueError) and isinstance(err.value, LunarDrakeError)


def test_unknown_limb_and_bad_inputs_are_refused():
    with pytest.raises(ConfigError, match=r"^array\.limb = 'flat' is unknown"):
        PowerConfig(array=SolarArrayConfig(limb="flat")).validate()
    kw = dict(config=SolarArrayConfig(), mount=MOUNT, R_WB=np.eye(3), p_WB=P_WB)
    with pytest.raises(OutOfRangeError, match="sun_direction_W"):
        array_output(**kw, sun_direction_W=[0.0, 0.0, 0.0], sun_distance_km=AU)
    with pytest.raises(OutOfRangeError, match="sun_distance_km"):
        array_output(**kw, sun_direction_W=sun_north(1.0), sun_distance_km=-1.0)
    with pytest.raises(ConfigError, match=r"PanelMount\.n_B"):
        PanelMount(n_B=(0.0, 0.0, 0.0), p_BP=(0.0, 0.0, 0.0), area_m2=1.0)


def test_panel_mount_agrees_with_the_rover_models_panel():
    from lunar_drake.models.rover_description import husky_rp, krex2_rp

    for d in (krex2_rp(), husky_rp()):
        m = PanelMount.from_description(d)
        assert np.allclose(m.n_B, d.solar_panel_normal_C(), atol=1e-12)
        top = d.chassis_height_m / 2
        assert m.p_BP[2] == pytest.approx(top + d.solar_panel_mount_height_m)
        assert m.area_m2 == pytest.approx(d.solar_panel_width_m * d.solar_panel_height_m)


def test_without_terrain_a_level_plain_hides_a_sun_below_the_horizontal():
    kw = dict(config=SolarArrayConfig(), mount=MOUNT, R_WB=np.eye(3), p_WB=P_WB)
    assert array_output(**kw, sun_direction_W=sun_north(-1.0), sun_distance_km=AU).power_W == 0.0
    half = array_output(**kw, sun_direction_W=sun_north(0.0), sun_distance_km=AU)
    assert half.visible_fraction == pytest.approx(0.5, abs=1e-12)


def test_power_config_loads_from_yaml():
    from pydrake.common.yaml import yaml_load_typed

    cfg = yaml_load_typed(
        schema=PowerConfig,
        data="array: {cell_efficiency: 0.3, limb: darkened}\nbattery: {capacity_Wh: 2000}\n"
        "loads: {radio_W: 40}\n",
    )
    cfg.validate()
    assert cfg.array.cell_efficiency == 0.3 and cfg.array.limb == "darkened"
    assert cfg.battery.capacity_Wh == 2000.0 and cfg.loads.radio_W == 40.0
    assert cfg.loads.avionics_W == LoadsConfig().avionics_W
