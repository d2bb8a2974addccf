"""Regression pins of the headline perception claims (docs/design.md, "Ground perception"),
on small seeded cases of the vo-study (studies/vo_study.py: the mission's rover, full
plant, flight software and link): after a 30 deg turn in place (the ``small`` site, 640
x 480: the mission's cameras), visual odometry is nearer the true camera motion than the
fused odometry (wheels, IMU, star tracker); on a straight drive (the default site) VO
ends under 1 % of the distance off; and a mission on the orbital map in which stereo
finds a rock the orbital map cannot show and the plan goes round it, where the same
mission without stereo drives onto it."""

import itertools
import math

import numpy as np
import pytest

from lunar_drake.studies import vo_study as vs

SMALL = dict(scenario_name="small", width=640, height=480, spawn_radius_m=2.0)


@pytest.fixture
def small_vo_site(cache):
    from lunar_drake.site import load_site

    cfg = vs.VoStudyConfig(**SMALL, angles_deg=(30.0,))
    return cfg, load_site(vs._scenario_for(cfg, 0), progress=False)


@pytest.mark.slow
def test_vo_beats_the_fused_odometry_after_a_30_degree_turn(small_vo_site):
    """Three seeded spawns and headings, each a 30 deg turn in place (lengthened by the
    turn efficiency the study measures, so the true rotation is within 1.5 deg of it):
    every alignment accepted, and VO's mean camera translation error at
    most 0.7 times the fused odometry's (measured with the symmetric stereo matching:
    0.80 cm against 2.11 cm; per seed 0.58 / 0.98 / 0.84 cm against 1.04 / 2.60 / 2.69
    cm; the single-pass matching of earlier releases gave 3.62 / 0.83 / 0.86 cm). At
    320 x 240 the same turns give 8.6 / 4.4 / 1.0 cm with the symmetric matching (1.7 /
    0.3 / 1.5 cm single-pass): too few pixels in the turn's overlap for VO to be
    reliable, so the claim is pinned at the mission's size."""
    cfg, site = small_vo_site
    rows = []
    for seed in (0, 1, 2):  # each turn lengthened by the rover's measured turn efficiency
        e = vs.turn_efficiency(config=cfg, site=site, seed=seed)
        rows.append(vs.run_rotation(config=cfg, site=site, angle_deg=30.0, seed=seed,
                                    turn_efficiency=e))  # fmt: skip
    for r in rows:
        assert abs(r["true_rotation_deg"] - 30.0) < 1.5, r
        assert not r["rejected"], r
        assert math.isfinite(r["vo_error_m"]) and r["odom_error_m"] > 0.005, r
    vo = sum(r["vo_error_m"] for r in rows) / len(rows)
    odom = sum(r["odom_error_m"] for r in rows) / len(rows)
    assert vo < 0.7 * odom, [(r["vo_error_m"], r["odom_error_m"]) for r in rows]


@pytest.mark.slow
def test_a_straight_drives_vo_error_is_under_1_percent_of_the_distance(cache):
    """A 10 m straight on the default site at 1024 x 768 (the study's size; seed 0's
    spawn and heading, the straight clear of hazards), keyframes 1 m apart: every link
    accepted, VO ends under 1 % of the distance off (measured 0.40 %) and at most half
    the fused odometry's error (3.8 %: the GRC-1 slip calibration). On the small site the
    same 5-10 m straights gave VO 0.9-2.2 % (320-1024 px wide): its terrain aligns
    worse; the claim is the default site's."""
    from lunar_drake.site import load_site

    cfg = vs.VoStudyConfig(scenario_name="default", width=1024, height=768, straight_m=10.0,
                           keyframe_m=1.0, spawn_radius_m=10.0)  # fmt: skip
    site = load_site(vs._scenario_for(cfg, 0), progress=False)
    r = vs.run_straight(config=cfg, site=site, seed=0)
    assert 9.0 < r["distance_m"] < 11.0 and r["links"] >= 8 and r["rejected"] == 0, r
    assert r["vo_error_m"] < 0.01 * r["distance_m"], r
    assert r["vo_error_m"] < 0.5 * r["odom_error_m"], r


# ---------------------------------------------------------------------------------------
# Stereo finds a rock the orbital map cannot show
# ---------------------------------------------------------------------------------------
#: The `goto` site with terrain seed 3: its tallest rock (0.34 m high, 0.45 m wide, site
#: m), narrower than the orbital product's 2 m limit, so the orbital map cannot show it;
#: the rover (0.3 m of ground clearance) starts 4.6 m south of it, facing it, and its goal
#: lies 3.2 m north of it.
ROCK_XY = (-1.3, -7.2)
SPAWN = {"spawn_x_m": -1.3, "spawn_y_m": -11.8, "spawn_yaw_deg": 90.0}
GOAL_XY = (-1.3, -4.0)


def _rock_mission(*, stereo: bool, source: str = "orbital"):
    from lunar_drake.scenario_files import load_scenario

    on = "true" if stereo else "false"
    return load_scenario(scenario_name="goto", scenario_text=(
        f"{{site: {{seed: 3}}, simulation_duration: 120.0, rover: {SPAWN},"
        f" sensors: {{camera: {{enabled: {on}, width: 320, height: 240, rate_hz: 1.0}}}},"
        f" flight: {{images: {{enabled: {on}}}}},"
        f" ground: {{map: {{source: {source}}}, perception: {{enabled: {on}}},"
        f" goals: [{{x_m: {GOAL_XY[0]}, y_m: {GOAL_XY[1]}}}]}}}}"))  # fmt: skip


def _distance_to_segment(p, a, b) -> float:
    p, a, b = (np.asarray(v, float) for v in (p, a, b))
    t = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * (b - a))))


def test_the_orbital_plan_runs_over_the_rock_the_true_map_goes_round(cache):
    """The case below, on the maps alone: the true DEM has the rock (lethal), the orbital
    product does not (its cell is not a hazard), and the plan on the orbital map
    runs straight over it while the plan on the true map keeps the rover clear."""
    from lunar_drake import preflight
    from lunar_drake.autonomy.costmap import RoverEnvelope, costmap_of_product
    from lunar_drake.autonomy.planner import plan_path
    from lunar_drake.site import load_site

    plans = {}
    for source in ("orbital", "truth"):
        s = _rock_mission(stereo=False, source=source)
        site = load_site(s, progress=False)
        product = preflight.ground_map_product(s, site)
        assert product.source == source
        cm = costmap_of_product(product, rover=RoverEnvelope.of(s.rover.description),
                                hazards=s.ground.hazards)  # fmt: skip
        rows, cols = np.nonzero(cm.lethal_raw)
        x, y = cm.centre_of(rows, cols)
        on_rock = np.hypot(x - ROCK_XY[0], y - ROCK_XY[1]) < 0.5 * cm.resolution_m + 0.25
        assert on_rock.any() == (source == "truth"), source
        start = (SPAWN["spawn_x_m"], SPAWN["spawn_y_m"])
        plans[source] = plan_path(costmap=cm, start_xy=start, goal_xy=GOAL_XY).waypoints_xy

    def clearance(wps):
        return min(_distance_to_segment(ROCK_XY, a, b) for a, b in itertools.pairwise(wps))

    assert clearance(plans["orbital"]) < 0.1  # straight over it
    assert clearance(plans["truth"]) > 0.8


@pytest.mark.slow
def test_stereo_finds_the_rock_the_orbital_map_cannot_show_and_the_plan_avoids_it(cache):
    """The same mission on the orbital map, with stereo off and on (320 x 240 pairs at
    1 Hz down the link, the ground's stereo, VO and hazard mapping). Stereo off: the
    rover drives onto the rock (belly strikes scored on truth) and the ground, judging
    on the estimate, never replans. Stereo on: the ground maps the rock from the
    downlinked pairs before the rover gets there, replans round it ("a new hazard on
    the path"), and the rover reaches the goal without a strike, its chassis never
    within 0.6 m of the rock's centre."""
    from lunar_drake import metrics
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    out = {}
    for stereo in (False, True):
        s = _rock_mission(stereo=stereo)
        site = load_site(s, progress=False)
        logs = simulate(scenario=s, site=site, progress=False, stop_after_goals_s=2.0)
        summary = metrics.summarize(scenario=s, site=site, logs=logs)
        xy = logs.vectors["truth.pose"].data[:, :2]
        closest = float(np.min(np.hypot(xy[:, 0] - ROCK_XY[0], xy[:, 1] - ROCK_XY[1])))
        out[stereo] = (summary, closest, logs.ground_events)
    blind, closest_blind, events_blind = out[False]
    assert blind["ground"]["map_source"] == "orbital"
    assert blind["hazards"]["belly"] >= 1, blind["hazards"]
    assert closest_blind < 0.3
    assert not any(e.kind == "plan" and "replan" in e.detail for e in events_blind)
    seen, closest_seen, events_seen = out[True]
    assert seen["hazards"]["strikes"] == 0 and seen["modes"]["safings"] == {}, seen["hazards"]
    assert seen["perception"]["lethal_cells_added"] > 0
    assert any(e.kind == "plan" and "new hazard" in e.detail for e in events_seen)
    assert seen["goals"][0]["reached"], seen["goals"]
    assert closest_seen > 0.6
