"""Pre-flight products: the ground's map (orbital by default, rocks an orbital camera
cannot resolve taken out), the flight's slip calibration (a simulant, not the plant's
soil), the two seeds, and the seam: the ground is handed the product, never the site."""

import gc
import math
import types

import numpy as np
import pytest
from scipy import ndimage

from lunar_drake import preflight
from lunar_drake.autonomy.costmap import MapConfig
from lunar_drake.autonomy.map_product import make_map_product, remove_unresolved_rocks
from lunar_drake.autonomy.slip_calibration import calibrate, calibrated_estimator
from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics import wheel_reference
from lunar_drake.errors import ConfigError
from lunar_drake.models.rover_description import krex2_rp
from lunar_drake.scenario_files import load_scenario, scenario_names
from lunar_drake.site import synth_config_from_scenario
from lunar_drake.terrain.heightfield import Heightfield

RES = 0.1


def _plane_with_rocks():
    """A tilted plane (z = 0.05 x + 0.02 y) with a 0.6 m and a 3 m wide dome rock."""
    n = 200
    y, x = np.mgrid[0:n, 0:n] * RES
    plane = 0.05 * x + 0.02 * y
    rocks = np.zeros_like(plane)
    for (cx, cy, d) in ((5.0, 5.0, 0.6), (14.0, 12.0, 3.0)):
        r = np.hypot(x - cx, y - cy)
        rocks = np.maximum(rocks, 0.4 * d * np.sqrt(np.clip(1 - (2 * r / d) ** 2, 0, None)))
    return plane, rocks


def test_unresolved_rocks_are_taken_out_and_wide_ones_kept():
    plane, rocks = _plane_with_rocks()
    z = plane + rocks
    mask = rocks > 0
    out, n = remove_unresolved_rocks(z, mask, resolution_m=RES, max_diameter_m=2.0)
    assert n == 1
    yy, xx = np.mgrid[0:200, 0:200] * RES
    small = mask & (np.hypot(xx - 5.0, yy - 5.0) < 1.0)
    # The small rock is gone: its pixels back on the plane (the surface without it).
    assert small.sum() > 20
    assert np.max(np.abs(out[small] - plane[small])) < 0.01
    assert np.max(z[small] - plane[small]) > 0.2  # it was there
    # The wide rock and the rest of the surface are untouched.
    wide = mask & ~small
    assert np.array_equal(out[wide], z[wide])
    far = ~ndimage.binary_dilation(small, iterations=2)
    assert np.array_equal(out[far], z[far])


def test_map_product_truth_is_the_oracle_and_orbital_is_not():
    plane, rocks = _plane_with_rocks()
    hf = Heightfield.from_array((plane + rocks).astype(np.float32), resolution_m=RES)
    pts = [(-9.0, -9.0), (9.0, 9.0)]
    truth = make_map_product(heightfield=hf, points_xy=pts, seed=1,
                             map_config=MapConfig(source="truth", margin_m=0.0))  # fmt: skip
    assert truth.oracle and truth.source == "truth" and truth.resolution_m == RES
    mask = rocks > 0

    def read(r0, c0, nr, nc):
        return mask[r0 : r0 + nr, c0 : c0 + nc]

    orb = make_map_product(heightfield=hf, points_xy=pts, seed=1, rock_mask=read,
                           map_config=MapConfig(source="orbital", margin_m=0.0))  # fmt: skip
    assert not orb.oracle and orb.resolution_m == pytest.approx(1.0)
    assert orb.rocks_removed == 1 and orb.resolved_rock_m == 2.0
    d = orb.describe()
    assert d["map_source"] == "orbital" and d["oracle"] is False
    # Against the same product of the bare plane (same seed, same noise): the small rock
    # left no trace; the wide one is still there.
    bare = make_map_product(heightfield=Heightfield.from_array(plane.astype(np.float32),
                                                               resolution_m=RES),
                            points_xy=pts, seed=1,
                            map_config=MapConfig(source="orbital", margin_m=0.0))  # fmt: skip
    diff = orb.z - bare.z
    assert orb.z.shape == bare.z.shape
    assert np.sort(np.abs(diff).ravel())[-10] > 0.1  # the wide rock's blocks
    with_small = make_map_product(heightfield=hf, points_xy=pts, seed=1,
                                  map_config=MapConfig(source="orbital", margin_m=0.0))
    small_blocks = np.abs(with_small.z - orb.z) > 1e-9
    assert small_blocks.any()  # where the small rock was, before it was taken out
    assert np.max(np.abs(diff[small_blocks])) < 0.01
    # Same seed, same bytes; the seed moves only the noise.
    again = make_map_product(heightfield=hf, points_xy=pts, seed=1, rock_mask=read,
                             map_config=MapConfig(source="orbital", margin_m=0.0))  # fmt: skip
    assert np.array_equal(again.z, orb.z)


def test_default_scenarios_plan_on_the_orbital_map_with_stereo_and_a_simulant_calibration():
    for name in ("default", "skid"):
        s = load_scenario(scenario_name=name)
        assert s.ground.map.source == "orbital", name
        assert s.sensors.camera.enabled and s.flight.images.enabled, name
        assert s.ground.perception.enabled and s.ground.perception.use_vo, name
        assert s.flight.estimator.slip_calibration == "grc1", name
        cal = preflight.slip_calibration(s)
        assert cal is not None and not cal.is_soil(s.soil), name
        assert preflight.describe(s)["slip_calibration"]["is_plant_soil"] is False


def test_every_shipped_scenario_that_plans_does_so_on_the_orbital_map_with_stereo():
    names = [n for n in scenario_names() if n not in ("Defaults", "OneOfEverything")]
    planning = [n for n in names if load_scenario(scenario_name=n).ground.goals]
    assert {"default", "skid", "prospect", "goto"} <= set(planning)
    for name in planning:
        s = load_scenario(scenario_name=name)
        assert s.ground.map.source == "orbital", name
        assert s.sensors.camera.enabled and s.flight.images.enabled, name
        assert s.ground.perception.enabled and s.ground.perception.use_vo, name
        cal = preflight.slip_calibration(s)
        if cal is not None:  # a declared pre-flight calibration, on another soil
            assert not cal.is_soil(s.soil), name
        else:  # a level prior written by hand: not the plant soil's either
            plant = calibrate(description=s.rover.description, spec="lunar_regolith")
            assert s.flight.estimator.slip_calibration == "", name
            assert abs(s.flight.estimator.slip_prior - plant.slip_prior) > 0.005, name


def test_slip_calibration_is_the_reference_wheel_on_the_simulant_not_the_plant_soil():
    d = krex2_rp()
    cal = calibrate(description=d, spec="grc1")
    plant = calibrate(description=d, spec="lunar_regolith")
    table = dict(cal.table)
    # Level and climbs: the independent wheel reference on GRC-1 at lunar gravity.
    wheel = tm.WheelParams(radius_m=d.wheel_radius_m, width_m=d.wheel_width_m)
    for deg in (0.0, 6.0):
        loads = wheel_reference.slope_wheel_loads(description=d, slope_rad=math.radians(deg))
        ref = wheel_reference.reference_slip(slope_rad=math.radians(deg), wheel_loads_N=loads,
                                             wheel=wheel, soil=tm.soil_preset("grc1"))  # fmt: skip
        assert table[deg] == pytest.approx(ref, abs=1e-4)
    assert cal.slip_prior == table[0.0]
    # Descents mirror climbs about level.
    assert table[-4.0] == pytest.approx(2 * table[0.0] - table[4.0], abs=2e-4)
    # It is not the plant's soil: the level slip differs (0.068 vs 0.077).
    assert abs(cal.slip_prior - plant.slip_prior) > 0.005
    assert cal.is_soil(tm.soil_preset("grc1")) and not cal.is_soil(tm.soil_preset("lunar_regolith"))
    s = load_scenario(scenario_name="default")
    est, got = calibrated_estimator(s.flight.estimator, description=s.rover.description)
    assert got == cal and est.slip_prior == cal.slip_prior
    assert est.slip_vs_slope == [list(r) for r in cal.table]


def test_slip_calibration_bad_input_names_the_key():
    with pytest.raises(ConfigError, match=r"flight\.estimator\.slip_calibration: soil 'mud'"):
        load_scenario(scenario_name="default",
                      scenario_text="{flight: {estimator: {slip_calibration: mud}}}")  # fmt: skip
    with pytest.raises(ConfigError, match="both given"):
        load_scenario(scenario_name="default", scenario_text=(
            "{flight: {estimator: {slip_vs_slope: [[0.0, 0.1], [5.0, 0.2]]}}}"))  # fmt: skip


def test_random_seed_does_not_move_the_ground():
    a = load_scenario(scenario_name="default")
    b = load_scenario(scenario_name="default", scenario_text="{random_seed: 5}")
    c = load_scenario(scenario_name="default", scenario_text="{site: {seed: 5}}")
    key = synth_config_from_scenario
    assert key(a).content_key() == key(b).content_key()
    assert key(a).content_key() != key(c).content_key()


def test_random_seed_leaves_the_site_and_the_ground_map_product_unchanged(cache):
    from lunar_drake.site import load_site

    a = load_scenario(scenario_name="goto")
    b = load_scenario(scenario_name="goto", scenario_text="{random_seed: 5}")
    c = load_scenario(scenario_name="goto", scenario_text="{site: {seed: 5}}")
    sa, sb, sc = (load_site(s, progress=False) for s in (a, b, c))
    za, zb, zc = (np.asarray(x.heightfield.read_window(0, 0, *x.heightfield.shape))
                  for x in (sa, sb, sc))  # fmt: skip
    assert np.array_equal(za, zb) and not np.array_equal(za, zc)
    pa, pb, pc = (preflight.ground_map_product(s, x) for s, x in ((a, sa), (b, sb), (c, sc)))
    # The orbital map's noise is the site's (its seed), not the run's.
    assert pa.noise_m > 0 and np.array_equal(pa.z, pb.z)
    assert pa.z.shape == pc.z.shape and not np.array_equal(pa.z, pc.z)


def _reachable(roots, limit=500_000):
    """Every Python object reachable from ``roots`` through attributes, containers and
    closures: not through functions' module globals, nor Drake's own objects (ports,
    diagrams and builders, and the peers pydrake keeps to tie their lifetimes, would
    reach the whole mission)."""
    seen, out, todo = set(), [], list(roots)
    while todo and len(out) < limit:
        o = todo.pop()
        if id(o) in seen or isinstance(o, (types.ModuleType, type)):
            continue
        seen.add(id(o))
        if type(o).__module__.startswith("pydrake") and o not in roots:
            continue
        out.append(o)
        if isinstance(o, types.FunctionType):
            todo += [c.cell_contents for c in (o.__closure__ or ()) if _filled(c)]
            todo += list(o.__defaults__ or ()) + list((o.__kwdefaults__ or {}).values())
            continue
        if hasattr(o, "__dict__"):
            todo += [v for k, v in vars(o).items() if k != _PEERS]
        todo += [r for r in gc.get_referents(o)
                 if not (isinstance(r, dict) and _PEERS in r)]  # fmt: skip
    return out


_PEERS = "_pydrake_internal_ref_cycle_peers"


def _filled(cell) -> bool:
    try:
        cell.cell_contents  # noqa: B018
    except ValueError:
        return False
    return True


def _holds_window_of(a, z, *, min_side=4) -> bool:
    """Whether 2-D array ``a`` is a window of the raster ``z`` (any offset; float32 or
    float64, or a cast of either): its corner value located in ``z`` at the same
    precision, then the whole window compared there."""
    if a.ndim != 2 or min(a.shape) < min_side or a.shape[0] > z.shape[0] \
            or a.shape[1] > z.shape[1] or not np.issubdtype(a.dtype, np.floating):
        return False
    zz = z.astype(a.dtype)
    h, w = a.shape
    for r, c in np.argwhere(zz == a[0, 0])[:1000]:
        if r + h <= z.shape[0] and c + w <= z.shape[1] and np.array_equal(zz[r:r + h, c:c + w], a):
            return True
    return False


def test_the_window_check_finds_crops_and_float32_copies_of_a_raster():
    z = np.random.default_rng(3).normal(size=(60, 50))
    assert _holds_window_of(z, z) and _holds_window_of(z[10:30, 5:40].copy(), z)
    assert _holds_window_of(z[7:20, 3:9].astype(np.float32), z)
    assert not _holds_window_of(z[10:30, 5:40] + 1e-9, z)
    assert not _holds_window_of(z[::2, ::2].copy(), z)  # decimated: another product


@pytest.mark.parametrize("source", ["orbital", "truth"])
def test_the_ground_never_holds_the_true_dem_unless_it_asks_for_the_oracle(cache, source):
    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.site import load_site

    text = f"{{ground: {{map: {{source: {source}}}}}}}"
    s = load_scenario(scenario_name="goto", scenario_text=text)
    site = load_site(s, progress=False)
    mission = MakeMissionDiagram(scenario=s, site=site)
    ground = mission.GetSubsystemByName("ground")
    objs = _reachable(list(ground.GetSystems()))
    hf = site.heightfield
    true_z = np.asarray(hf.read_window(0, 0, *hf.shape), np.float64)
    assert not any(o is hf or o is site for o in objs)
    arrays = [o for o in objs if isinstance(o, np.ndarray)]
    holds_truth = any(_holds_window_of(a, true_z) for a in arrays)
    assert holds_truth == (source == "truth")
    # The flight is handed no terrain at all.
    flight_objs = _reachable(list(mission.GetSubsystemByName("flight").GetSystems()))
    assert not any(o is hf or o is site for o in flight_objs)
    assert not any(isinstance(o, np.ndarray) and o.shape == true_z.shape for o in flight_objs)


def test_the_summary_names_the_map_and_the_calibration(small_site):
    from lunar_drake import metrics
    from lunar_drake.scenario_files import apply_overrides
    from lunar_drake.simulation import simulate

    scenario, site = small_site
    s = apply_overrides(scenario, "{simulation_duration: 0.2, random_seed: 9, flight: {estimator: "
                                  "{slip_calibration: lunar_regolith}}}")  # fmt: skip
    logs = simulate(scenario=s, site=site, progress=False)
    summary = metrics.summarize(scenario=s, site=site, logs=logs)
    assert summary["random_seed"] == 9 and summary["site_seed"] == scenario.site.seed == 7
    g = summary["ground"]
    assert g["map_source"] == "orbital" and g["map"]["oracle"] is False
    assert g["map"]["resolved_rock_m"] == 2.0 and g["map"]["rocks_removed"] > 0
    cal = summary["flight"]["slip_calibration"]
    # The plant's own soil named as the calibration: the summary says it is the oracle.
    assert cal["slip_calibration"] == "lunar_regolith" and cal["is_plant_soil"] is True
    assert cal["slip_vs_slope"][0] == [-8.0, pytest.approx(-0.0678, abs=2e-4)]


def test_the_operator_judges_goals_with_the_perceptions_sigma(cache):
    """With stereo and VO on (goto), the ground's perception hands the operator its
    position sigma beside the correction; with VO off it hands neither."""
    from lunar_drake.diagrams.mission import MakeMissionDiagram
    from lunar_drake.site import load_site

    for use_vo in (True, False):
        text = f"{{ground: {{perception: {{use_vo: {str(use_vo).lower()}}}}}}}"
        s = load_scenario(scenario_name="goto", scenario_text=text)
        mission = MakeMissionDiagram(scenario=s, site=load_site(s, progress=False))
        ground = mission.GetSubsystemByName("ground")
        perception = ground.GetSubsystemByName("ground.perception")
        operator = ground.GetSubsystemByName("ground.operator")
        links = {
            (dst.get_name(), dst_port): (src.get_name(), src_port)
            for (dst, dst_port), (src, src_port) in ground.connection_map().items()
        }
        sigma = links.get(("ground.operator", operator.pose_sigma_input.get_index()))
        correction = links.get(("ground.operator", operator.pose_correction_input.get_index()))
        if use_vo:
            assert sigma == ("ground.perception", perception.pose_sigma_output.get_index())
            assert correction == (
                "ground.perception", perception.pose_correction_output.get_index()
            )
        else:
            assert sigma is None and correction is None
