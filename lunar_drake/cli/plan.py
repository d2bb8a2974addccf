"""`lunar-drake plan`: the ground's hazard costmap of a scenario's site and the
least-cost path from the rover's start to a goal (plan.png, path.csv, plan.json)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lunar_drake.cli._common import add_subcommand, load_named_scenario
from lunar_drake.files import atomic_path, atomic_write_text, ensure_output_dir


def run_plan(*, scenario, site, goal_xy, start_xy=None, out_dir) -> dict:
    """Plans on the scenario's ground map (``ground.map``, ``ground.hazards``) from
    ``start_xy`` (default: the rover's spawn point) to ``goal_xy`` (site m) and writes
    ``plan.png`` (costmap, lethal cells, path), ``path.csv`` (``x_m,y_m`` waypoints) and
    ``plan.json`` (``length_m``: along the planning grid's cells; ``waypoint_length_m``:
    the waypoints the rover follows; ``unconfirmed_fraction``: the orbital map's steep
    cells, lethal until stereo sees them); returns the plan.json dict. Raises ``OutOfBoundsError`` /
    ``PlanningError`` (one line) for goals off the map, in a hazard or unreachable."""
    import copy

    from matplotlib.figure import Figure

    from lunar_drake.autonomy.costmap import RoverEnvelope
    from lunar_drake.autonomy.planner import plan_path, plot_plan
    from lunar_drake.diagrams.ground import ground_costmap
    from lunar_drake.preflight import ground_map_product
    from lunar_drake.scenario import Goal

    start = (scenario.rover.spawn_x_m, scenario.rover.spawn_y_m) if start_xy is None else start_xy
    # The mission's own map product (whole site, or the window round start and goal).
    s = copy.deepcopy(scenario)
    s.rover.spawn_x_m, s.rover.spawn_y_m = float(start[0]), float(start[1])
    s.ground.goals, s.ground.actions = [Goal(x_m=goal_xy[0], y_m=goal_xy[1])], []
    cm = ground_costmap(s, ground_map_product(s, site))
    rover = RoverEnvelope.of(scenario.rover.description)
    path = plan_path(costmap=cm, start_xy=start, goal_xy=goal_xy)
    out = ensure_output_dir(out_dir, what="--out directory")
    lines = ["x_m,y_m"] + [f"{x:.4f},{y:.4f}" for x, y in path.waypoints_xy]
    atomic_write_text(out / "path.csv", "\n".join(lines) + "\n", what="path table")
    lethal = ~np.isfinite(cm.cost)
    wp = np.asarray(path.waypoints_xy)
    unconfirmed = 0.0 if cm.unconfirmed is None else float(np.mean(cm.unconfirmed))
    doc = {
        "scenario": scenario.name,
        "map": scenario.ground.map.source,
        "start_xy_m": [float(v) for v in start],
        "goal_xy_m": [float(v) for v in goal_xy],
        "length_m": round(path.length_m, 3),
        "waypoint_length_m": round(float(np.sum(np.hypot(*np.diff(wp, axis=0).T))), 3),
        "straight_line_m": round(float(np.hypot(*(np.subtract(goal_xy, start)))), 3),
        "cost": round(path.cost, 3),
        "waypoints": len(path.waypoints_xy),
        "grid": {"shape": list(cm.shape), "resolution_m": cm.resolution_m},
        "lethal_fraction": round(float(lethal.mean()), 4),
        "unconfirmed_fraction": round(unconfirmed, 4),
        "confirm_slope_deg": (
            scenario.ground.map.confirm_slope_deg
            if scenario.ground.map.source == "orbital"
            else None
        ),
        "footprint_radius_m": round(rover.footprint_radius_m, 3),
    }
    atomic_write_text(out / "plan.json", json.dumps(doc, indent=2) + "\n", what="plan summary")
    fig = Figure(figsize=(7, 7))
    ax = fig.subplots()
    key = "red: hazards, inflated"
    if unconfirmed > 0.0:
        key += (f";\npurple: steeper than {doc['confirm_slope_deg']:g} deg, lethal until "
                "stereo sees it")  # fmt: skip
    plot_plan(cm, path, ax=ax, title=f"{scenario.name}: {doc['map']} map, "
              f"{doc['waypoint_length_m']:.1f} m path ({key})")  # fmt: skip
    fig.tight_layout()
    with atomic_path(Path(out) / "plan.png", what="plot") as tmp:
        fig.savefig(tmp, dpi=110)
    return doc


def command(args) -> int:
    from lunar_drake.scenario_files import apply_overrides
    from lunar_drake.site import load_site

    scenario, _ = load_named_scenario(args)
    if args.map is not None:
        scenario = apply_overrides(scenario, f"{{ground: {{map: {{source: {args.map}}}}}}}")
    site = load_site(scenario, progress=not args.no_progress)
    doc = run_plan(
        scenario=scenario, site=site, goal_xy=args.goal, start_xy=args.start, out_dir=args.out
    )
    unconfirmed = ""
    if doc["unconfirmed_fraction"]:
        unconfirmed = (f" ({100 * doc['unconfirmed_fraction']:.1f}% unconfirmed: steeper than "
                       f"{doc['confirm_slope_deg']:g} deg on the orbital map)")  # fmt: skip
    print(
        f"Path on the {doc['map']} map: {doc['waypoint_length_m']:.1f} m (straight line "
        f"{doc['straight_line_m']:.1f} m), {doc['waypoints']} waypoints; "
        f"{100 * doc['lethal_fraction']:.1f}% of the map is hazard{unconfirmed}"
    )
    print(f"Outputs: {Path(args.out).resolve()} (plan.png, path.csv, plan.json)")
    return 0


def add_parser(sub) -> None:
    pn = add_subcommand(sub, "plan", help="plan a hazard-free path on the ground's map of a site")
    pn.add_argument("--scenario", default="default", help="scenario name or FILE.yaml[:NAME]")
    pn.add_argument("--scenario-text", default="{}", help="YAML overrides")
    pn.add_argument("--goal", type=float, nargs=2, required=True, metavar=("X", "Y"),
                    help="goal in the site frame (m)")  # fmt: skip
    pn.add_argument("--start", type=float, nargs=2, default=None, metavar=("X", "Y"),
                    help="start (m; default: the rover's spawn point)")  # fmt: skip
    pn.add_argument("--map", choices=["truth", "orbital"], default=None,
                    help="the a-priori map (default: scenario ground.map.source)")  # fmt: skip
    pn.add_argument("--out", required=True, help="output directory")
    pn.add_argument("--no-progress", action="store_true")
    pn.set_defaults(func=command)
