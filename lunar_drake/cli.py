"""The ``lunar-drake`` command.

lunar-drake run [--scenario NAME|FILE[:NAME]|RUN/scenario.yaml] [--scenario-text YAML]
                [--duration S] [--no-cameras] [--soil NAME|FILE] [--out DIR]
                [--no-meshcat] [--meshcat-host HOST] [--wait] [--no-progress]
lunar-drake terrain synth --size N --resolution M --seed S --out DIR [...]
lunar-drake scenarios [FILE]
lunar-drake slip-fit DATA.csv --rover {skid,explicit} --out DIR [--base-soil NAME|FILE]
lunar-drake vo-study --angles A:B:STEP --seeds N [--lights] [--straight DIST_M] --out DIR
lunar-drake world build SITE_DIR --out DIR [--utc TIME] [--config FILE.yaml]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from lunar_drake.errors import ConfigError, LunarDrakeError


def _split_scenario(arg: str):
    """'default' -> (None, 'default'); 'f.yaml' -> (f.yaml, 'default'); 'f.yaml:x' -> (f, x)."""
    if arg.endswith((".yaml", ".yml")):
        return arg, "default"
    if ":" in arg and arg.split(":", 1)[0].endswith((".yaml", ".yml")):
        f, name = arg.rsplit(":", 1)
        return f, name
    return None, arg


def _soil_override(arg: str) -> dict:
    """``--soil NAME`` (a preset) or ``--soil FILE.yaml`` (a soil section) as overrides."""
    import dataclasses as dc

    import yaml

    from lunar_drake.dynamics import terramechanics as tm

    if arg.endswith((".yaml", ".yml")):
        path = Path(arg)
        if not path.is_file():
            raise ConfigError(f"--soil {arg!r} does not exist")
        try:
            data = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise ConfigError(f"--soil {arg!r} is not valid YAML: {exc}") from None
        if isinstance(data, dict) and set(data) == {"soil"}:
            data = data["soil"]
        if not isinstance(data, dict):
            raise ConfigError(f"--soil {arg!r} must hold a mapping of soil parameters")
        return {"soil": data}
    try:
        return {"soil": dc.asdict(tm.soil_preset(arg))}
    except ConfigError as exc:
        raise ConfigError(f"--soil: {exc}") from None


def resolve_run_scenario(args):
    """The scenario of ``lunar-drake run``: the named or given scenario, then
    ``--scenario-text``, then the flags as overrides of scenario fields (so the run's
    ``scenario.yaml`` says everything)."""
    import yaml

    from lunar_drake.scenario_files import apply_overrides, load_scenario

    filename, name = _split_scenario(args.scenario)
    scenario = load_scenario(
        filename=filename, scenario_name=name, scenario_text=args.scenario_text
    )
    flags: dict = {}
    if args.duration is not None:
        flags["simulation_duration"] = float(args.duration)
    if args.no_cameras:
        flags["sensors"] = {"camera": {"enabled": False}}
    if args.soil is not None:
        flags.update(_soil_override(args.soil))
    if flags:
        scenario = apply_overrides(
            scenario, yaml.safe_dump(flags, default_flow_style=True), source="command-line flags"
        )
    return scenario, name


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _cmd_run(args) -> int:
    from lunar_drake import metrics, outputs
    from lunar_drake.files import check_replaceable, staged_directory
    from lunar_drake.science.world import needs_world, run_world
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    scenario, name = resolve_run_scenario(args)
    out = Path(args.out) if args.out else Path("runs") / (scenario.name or name)
    check_replaceable(out, allowed=outputs.RUN_DIR_NAMES, what="run directory")
    meshcat = None
    if not args.no_meshcat:
        from pydrake.geometry import Meshcat, MeshcatParams

        meshcat = Meshcat(MeshcatParams(host=args.meshcat_host))
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
    print(
        f"Scenario {scenario.name or name!r} (seed {scenario.random_seed}); building the site...",
        flush=True,
    )
    with staged_directory(out, what="run directory") as tmp:
        t0 = time.perf_counter()
        site = load_site(scenario, progress=not args.no_progress)
        t_site = time.perf_counter() - t0
        if needs_world(scenario):
            print("Building the world model (science sensors)...", flush=True)
            t0 = time.perf_counter()
            world_dir, cached = run_world(scenario=scenario, site=site,
                                          progress=not args.no_progress)  # fmt: skip
            print(f"World model: {'cached' if cached else 'built'} in "
                  f"{time.perf_counter() - t0:.1f} s ({world_dir})", flush=True)  # fmt: skip
        logs = simulate(
            scenario=scenario,
            site=site,
            meshcat=meshcat,
            progress=not args.no_progress,
            frames_dir=tmp / "frames" if scenario.logging.save_frames else None,
        )
        summary = metrics.summarize(scenario=scenario, site=site, logs=logs)
        timing = {
            "site_s": t_site,
            "site_cached": bool(site.site.cached) if site.site else False,
            "site_dir": str(site.site.directory or site.site.dem) if site.site else "",
            **logs.wall,
        }
        outputs.write_run(
            tmp,
            scenario=scenario,
            logs=logs,
            summary=summary,
            timing=timing,
            meshcat_html=meshcat.StaticHtml() if meshcat is not None else None,
            site=site,
        )
    s = summary["site"]
    print(
        f"Site: {s['shape_px'][0]}x{s['shape_px'][1]} px at {s['resolution_m']:g} m"
        + (f", {s['craters']} craters, {s['rocks']} rocks" if "craters" in s else "")
        + f" ({'cached' if timing['site_cached'] else 'built'} in {t_site:.1f} s; "
        f"{timing['site_dir']})"
    )
    rtf = timing["realtime_factor"]
    print(
        f"Simulated {summary['simulated_s']:.2f} s in {timing['simulate_s']:.2f} s "
        + (f"({rtf:.1f}x real time; " if rtf else "(")
        + f"diagram built in {timing['build_s']:.2f} s); stop: {summary['stop_reason']}"
    )
    rv = summary["rover"]
    print(
        f"Rover: drove {rv['distance_m']:.1f} m, mean slip {100 * rv['mean_slip_moving']:.1f}%, "
        f"max sinkage {100 * rv['max_sinkage_m']:.1f} cm, max tilt {rv['max_tilt_deg']:.1f} deg, "
        f"drive energy {rv['energy_J']:.0f} J"
    )
    loc = summary["localization"]
    if loc:
        print(
            f"On-board estimate at the end: {loc['final_position_error_m']:.2f} m off, "
            f"heading {loc['final_heading_error_deg']:.2f} deg off; ground received "
            f"{_plural(summary['telemetry_received'], 'telemetry packet')}"
        )
    if summary.get("goals"):
        got = sum(g["reached"] for g in summary["goals"])
        final = summary["goals"][-1]["final_distance_m"]
        print(
            f"Goals: {got} of {len(summary['goals'])} reached (truth; the last one "
            f"{final:.2f} m away at the end)"
        )
    gr = summary["ground"]
    if gr["goals"]:
        on_ground = sum(g["status"] == "reached" for g in gr["goals"])
        hz = summary["hazards"]
        print(
            f"Ground: {on_ground} of {len(gr['goals'])} goals reached on its estimate, "
            f"{_plural(gr['plans'], 'plan')} ({gr['replans']} replans); "
            f"hazard strikes {hz['strikes']}"
        )
    md = summary["modes"]
    safings = ", ".join(f"{n} {k}" for k, n in md["safings"].items()) or "none"
    print(f"Modes: {_plural(md['count'], 'mode change')} on board; safings: {safings}")
    if summary.get("images_received"):
        print(
            f"Images: the ground received {_plural(summary['images_received'], 'stereo frame')}"
            f" ({summary['images_bytes_received'] / 1e6:.1f} MB)"
        )
    per = summary.get("perception") or {}
    if per.get("keyframes"):
        vo = ", ".join(f"{n} {k}" for k, n in per["vo"].items())
        sigma = per.get("final_sigma_m")
        drift = f"; the ground's position sigma {sigma:.2f} m" if sigma is not None else ""
        print(f"Perception: {_plural(per['keyframes'], 'stereo keyframe')} (VO: {vo}); "
              f"{per['lethal_cells_added']} lethal cells added to the ground's map"
              f"{drift}")  # fmt: skip
    sci = summary.get("science") or {}
    if "nirvss_records" in sci:
        rmse = sci.get("lcs_rmse_K")
        lcs = f"; LCS {rmse:.2f} K RMS from the truth" if rmse is not None else ""
        drill = f"; {sci['drill_samples']} drill samples" if "drill_samples" in sci else ""
        print(f"Science: the ground received "
              f"{_plural(sci['nirvss_records'], 'NIRVSS record')}{lcs}{drill}")
    if "nss_records" in sci:
        r = sci.get("nss_truth_r")
        score = f"; against truth r = {r:.2f} over {sci['nss_cells']} cells of 2 m" if r else ""
        print(f"Science: the ground received {_plural(sci['nss_records'], 'NSS record')}"
              + (f", mean hydrogen {sci['weh_est_mean_wt_pct']:.2f} wt% WEH (truth "
                 f"{sci['weh_truth_mean_wt_pct']:.2f})" if sci["nss_records"] else "")
              + score)  # fmt: skip
    files = outputs.run_files()
    for name in ("nss.csv", "nss_map.png", "nss_map.tif", "nirvss.csv", "nirvss_map.png",
                 "nirvss_map.tif", "lcs.csv", "lcs_map.png", "lcs_map.tif", "drill.csv"):
        if (out / name).exists():
            files.append(name)
    if per.get("keyframes"):
        files.append("keyframes.csv")
    if (out / "ground_map.png").exists():
        files.append("ground_map.png")
    if scenario.sensors.camera.enabled:
        files.append("calibration.yaml")
    if summary["camera_frames"]:
        files.append(f"frames/ ({_plural(summary['camera_frames'], 'stereo frame')})")
    if meshcat is not None:
        files.append("meshcat.html")
    print(f"Outputs: {out.resolve()} ({', '.join(files)})")
    if meshcat is not None:
        print(f"Meshcat: {meshcat.web_url()} (static replay: {out / 'meshcat.html'})")
        if args.wait:
            print("Serving Meshcat; press Ctrl-C to stop.", flush=True)
            try:
                while True:
                    time.sleep(1.0)
            except KeyboardInterrupt:
                pass
    return 0


def _cmd_scenarios(args) -> int:
    from lunar_drake.scenario_files import default_scenario_file, scenario_names

    f = args.file or default_scenario_file()
    for n in scenario_names(filename=f):
        print(n)
    return 0


def _cmd_synth(args) -> int:
    from lunar_drake.terrain.sfd import CraterSFD
    from lunar_drake.terrain.synth import SynthConfig, synthesize_site

    if args.from_dem and not Path(args.from_dem).exists():
        from lunar_drake.errors import RasterNotFoundError

        raise RasterNotFoundError(f"--from-dem {args.from_dem!r} does not exist")
    if args.sfd == "powerlaw":
        sfd = CraterSFD(
            law="powerlaw", coefficient=args.powerlaw_coefficient, exponent=args.powerlaw_exponent
        )
    else:
        sfd = CraterSFD(law=args.sfd)
    if args.from_dem is None and args.size % args.factor:
        raise ConfigError(f"--size {args.size} must be a multiple of --factor {args.factor}")
    config = SynthConfig(
        size_px=args.size,
        resolution_m=args.resolution,
        factor=args.factor,
        seed=args.seed,
        crater_sfd=sfd,
        min_crater_m=args.min_crater_m,
        max_crater_m=args.max_crater_m,
        rock_abundance=args.rock_abundance,
        ejecta_rock_abundance=args.ejecta_rock_abundance,
        min_rock_m=args.min_rock_m,
        from_dem=args.from_dem,
        center_lat_deg=args.lat,
        center_lon_deg=args.lon,
        tile_px=args.tile,
        workers=args.workers,
    )
    t0 = time.perf_counter()
    products = synthesize_site(config=config, out_dir=args.out, progress=not args.no_progress)
    st = products.stats
    print(
        f"Site {st['size_px'][0]}x{st['size_px'][1]} px at {st['resolution_m']:g} m: "
        f"{st['craters']} craters, {st['rocks']} rocks ({st['ejecta_rocks']} ejecta), "
        f"z {st['z_min_m']:.2f}..{st['z_max_m']:.2f} m, {time.perf_counter() - t0:.1f} s"
    )
    print(f"Outputs: {Path(args.out).resolve()}")
    return 0


def _cmd_plan(args) -> int:
    from lunar_drake.plan_cli import run_plan
    from lunar_drake.scenario_files import apply_overrides, load_scenario
    from lunar_drake.site import load_site

    filename, name = _split_scenario(args.scenario)
    scenario = load_scenario(
        filename=filename, scenario_name=name, scenario_text=args.scenario_text
    )
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


def _cmd_world_build(args) -> int:
    from lunar_drake.science.config import WorldConfig
    from lunar_drake.science.world import build_world

    config = WorldConfig()
    where = "the default world configuration"
    if args.config:
        import yaml
        from pydrake.common.yaml import yaml_load_typed

        if not Path(args.config).is_file():
            raise ConfigError(f"--config {args.config!r} does not exist")
        where = f"--config {args.config!r}"
        try:
            raw = yaml.safe_load(Path(args.config).read_text())
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            what = getattr(exc, "problem", None) or type(exc).__name__
            mark = getattr(exc, "problem_mark", None)
            at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            raise ConfigError(f"{where} is not valid YAML: {what}{at}") from None
        if raw is not None and not isinstance(raw, dict):
            raise ConfigError(
                f"{where} holds a {type(raw).__name__}; it must be a mapping of sections "
                "(the shape of world.json's 'config')"
            )
        if raw:  # an empty file: the defaults
            from lunar_drake.scenario_files import check_yaml_schema

            check_yaml_schema(Path(args.config).read_text(), WorldConfig, source=where)
            try:
                config = yaml_load_typed(schema=WorldConfig, filename=args.config)
            except Exception as exc:  # Drake raises RuntimeError/TypeError on a bad value
                raise ConfigError(f"{where}: {str(exc).splitlines()[0]}") from None
    if args.workers is not None:
        config.workers = args.workers
        where = f"{where} with --workers {args.workers}" if args.config else "--workers"
    try:
        config.validate()
    except LunarDrakeError as exc:
        raise type(exc)(f"{where}: {exc}") from None
    if args.seed is not None and not 0 <= args.seed < 2**63:
        raise ConfigError(f"--seed {args.seed} is out of range; allowed [0, 2^63 - 1]")
    if args.utc is not None and not args.utc.strip():
        raise ConfigError("--utc '' is empty; give a UTC time such as 2027-11-15T00:00:00")
    from lunar_drake.files import check_replaceable, staged_directory
    from lunar_drake.science.world import WORLD_FILES

    # Built whole under a temporary name; an earlier world there is replaced only when
    # this one is complete, and a directory holding anything else is refused.
    check_replaceable(args.out, allowed=WORLD_FILES, what="world directory")
    with staged_directory(args.out, what="world directory") as tmp:
        doc = build_world(site_dir=args.site_dir, out_dir=tmp, utc=args.utc, config=config,
                          seed=args.seed, progress=not args.no_progress)  # fmt: skip
    layers = doc["layers"]
    print(
        f"World model of {args.site_dir} at {doc['utc']} ({doc['shape'][0]} x {doc['shape'][1]} "
        f"px, {doc['seconds']:.1f} s): permanent shadow {100 * doc['psr_fraction']:.2f} % "
        f"(Sun up to {doc['sun_envelope']['max_elevation_deg']:.2f} deg over the year); "
        f"temperature {layers['temperature_K']['min']:.0f}-{layers['temperature_K']['max']:.0f}"
        f" K; ice up to {layers['ice_wt_pct']['max']:.2f} wt%"
    )
    print(f"Outputs: {Path(args.out).resolve()} (<layer>.tif, <layer>.png, world.json)")
    return 0


def _cmd_render(args) -> int:
    from lunar_drake.render_cli import render_stereo
    from lunar_drake.scenario_files import load_scenario

    filename, name = _split_scenario(args.scenario)
    scenario = load_scenario(
        filename=filename, scenario_name=name, scenario_text=args.scenario_text
    )
    paths = render_stereo(
        scenario=scenario, time_s=args.time, out_dir=args.out, progress=not args.no_progress
    )
    for p in paths:
        print(p)
    return 0


def _cmd_slip_study(args) -> int:
    from lunar_drake.studies.slip_study import parse_slopes, run_slip_study, summarize

    slopes = parse_slopes(args.slopes)
    rovers = [r.strip() for r in args.rover.split(",")]
    data = None
    if args.data is not None:
        from lunar_drake.studies.slip_fit import read_slip_data

        d = read_slip_data(args.data)
        data = (d.slope_deg, d.slip)
    rows = run_slip_study(
        rovers=rovers,
        slopes_deg=slopes,
        distance_m=args.distance,
        seeds=args.seeds,
        out_dir=args.out,
        soil=args.soil,
        speed_mps=args.speed,
        roughness_m=args.roughness,
        data=data,
        workers=args.workers,
        progress=not args.no_progress,
    )
    print(
        f"{'rover':<9} {'slope':>6} {'mean slip':>10} {'std':>7} {'min':>7} {'max':>7} "
        f"{'reference':>10}"
    )
    for r in summarize(rows):
        ref = "cannot climb" if r["immobilized"] else f"{100 * r['reference']:>9.2f}%"
        print(
            f"{r['rover']:<9} {r['slope_deg']:>6.1f} {100 * r['mean']:>9.2f}% "
            f"{100 * r['std']:>6.2f}% {100 * r['min']:>6.2f}% {100 * r['max']:>6.2f}% {ref:>10}"
        )
    print(f"Outputs: {Path(args.out).resolve()} (slip.csv, slip.png, params.json)")
    return 0


def _cmd_vo_study(args) -> int:
    from lunar_drake.studies.vo_study import VoStudyConfig, parse_angles, run_vo_study

    config = VoStudyConfig(
        scenario_name=args.scenario,
        angles_deg=parse_angles(args.angles) if args.straight is None else (),
        seeds=args.seeds,
        straight_m=args.straight,
        lights=args.lights,
        width=args.width,
        height=args.height,
        turn_rate_dps=args.turn_rate,
        keyframe_m=args.keyframe,
        spawn_radius_m=args.spawn_radius,
        fov_y_deg=args.fov,
        max_range_m=args.max_range,
        calibrate_turns=not args.commanded_turns,
        images=args.images,
    )
    out = run_vo_study(config=config, out_dir=args.out, progress=not args.no_progress)
    if args.straight is not None:
        print(f"{'distance m':>10} {'VO error m':>11} {'odom error m':>13} {'VO %':>6} "
              f"{'odom %':>7} {'rejected':>9}")  # fmt: skip
        for r in out["runs"]:
            print(f"{r['distance_m']:10.2f} {r['vo_error_m']:11.3f} {r['odom_error_m']:13.3f} "
                  f"{100 * r['vo_error_m'] / r['distance_m']:6.2f} "
                  f"{100 * r['odom_error_m'] / r['distance_m']:7.2f} "
                  f"{r['rejected']:>4}/{r['links']:<4}")  # fmt: skip
        print(f"Outputs: {Path(args.out).resolve()} (straight.json, params.json)")
        return 0
    print(f"{'angle':>6} {'turned':>7} {'runs':>5} {'VO cm':>8} {'VO acc. cm':>11} "
          f"{'VO used cm':>11} {'odom cm':>8} {'rejected':>9} {'bad':>4} "
          f"{'bad kept':>9}")  # fmt: skip
    for r in out["summary"]:
        print(f"{r['angle_deg']:6.1f} {r['true_rotation_deg']:7.1f} {r['runs']:5d} "
              f"{100 * r['vo_error_m']:8.2f} {100 * r['vo_accepted_error_m']:11.2f} "
              f"{100 * r['used_error_m']:11.2f} {100 * r['odom_error_m']:8.2f} "
              f"{r['rejected']:9d} {r['bad']:4d} {r['bad_accepted']:9d}")  # fmt: skip
    print(f"Outputs: {Path(args.out).resolve()} (vo.csv, vo.png, params.json)")
    return 0


def _cmd_slip_fit(args) -> int:
    from lunar_drake.studies.slip_fit import describe, run_slip_fit

    print(f"Fitting phi and K to {args.data} ({args.rover} rover)...", flush=True)
    fit = run_slip_fit(
        data_path=args.data, rover=args.rover, out_dir=args.out, base_soil=args.base_soil
    )
    for line in describe(fit):
        print(line)
    print(f"Outputs: {Path(args.out).resolve()} (soil.yaml, fit.csv, fit.png)")
    return 0


def _positive_int(s: str) -> int:
    v = int(s)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"{s!r} must be a positive integer")
    return v


def _positive_float(s: str) -> float:
    v = float(s)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"{s!r} must be a positive number")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="lunar-drake", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="run a mission scenario (the main job)")
    r.add_argument(
        "--scenario",
        default="default",
        help="scenario name in the packaged file, or FILE.yaml[:NAME]",
    )
    r.add_argument("--scenario-text", default="{}", help="YAML overrides, e.g. '{random_seed: 3}'")
    r.add_argument(
        "--duration", type=float, default=None, help="simulated seconds (sets simulation_duration)"
    )
    r.add_argument("--out", default=None, help="run directory (default runs/<scenario>)")
    r.add_argument("--no-meshcat", action="store_true", help="headless, no Meshcat server")
    r.add_argument(
        "--meshcat-host",
        default="127.0.0.1",
        help="interface Meshcat listens on (default 127.0.0.1; '*' opens it to the network)",
    )
    r.add_argument(
        "--no-cameras",
        action="store_true",
        help="skip the Hapke stereo cameras (sets sensors.camera.enabled: false)",
    )
    r.add_argument(
        "--soil", default=None, help="soil preset (lunar_regolith, grc1, jsc1a) or a soil YAML file"
    )
    r.add_argument("--wait", action="store_true", help="keep serving Meshcat after the run")
    r.add_argument("--no-progress", action="store_true", help="no progress bars")
    r.set_defaults(func=_cmd_run)

    sc = sub.add_parser("scenarios", help="list the named scenarios in a file")
    sc.add_argument("file", nargs="?", default=None)
    sc.set_defaults(func=_cmd_scenarios)

    ss = sub.add_parser("slip-study", help="slip vs slope on planar ramps (paper Figs. 22-24)")
    ss.add_argument(
        "--rover", default="explicit", help="skid, explicit, or a comma list (e.g. skid,explicit)"
    )
    ss.add_argument("--slopes", default="0:20:5", help="A:B:STEP in degrees, or a comma list")
    ss.add_argument("--distance", type=_positive_float, default=5.0, help="metres upslope")
    ss.add_argument("--seeds", type=_positive_int, default=3)
    ss.add_argument(
        "--soil",
        default="lunar_regolith",
        help="a soil preset (lunar_regolith, grc1, jsc1a) or a soil YAML (e.g. slip-fit's)",
    )
    ss.add_argument(
        "--roughness",
        type=float,
        default=0.0,
        metavar="RMS_M",
        help="seeded fractal ramp roughness: RMS height deviation at 1 m (m; 0 = planar)",
    )
    ss.add_argument(
        "--data", default=None, help="measured slope_deg,slip CSV to draw on slip.png (optional)"
    )
    ss.add_argument("--speed", type=_positive_float, default=0.1, help="commanded m/s")
    ss.add_argument("--workers", type=_positive_int, default=1, help="parallel processes")
    ss.add_argument("--out", required=True)
    ss.add_argument("--no-progress", action="store_true")
    ss.set_defaults(func=_cmd_slip_study)

    vs = sub.add_parser(
        "vo-study", help="stereo ICP visual odometry vs fused odometry (paper Fig. 21)"
    )
    vs.add_argument("--scenario", default="default", help="the scenario's site, rover, sensors")
    vs.add_argument("--angles", default="0:60:10", help="A:B:STEP in degrees, or a comma list")
    vs.add_argument("--seeds", type=_positive_int, default=3)
    vs.add_argument("--straight", type=_positive_float, default=None, metavar="DIST_M",
                    help="drive straight this far instead (writes straight.json)")  # fmt: skip
    vs.add_argument("--lights", action="store_true",
                    help="in shadow, with the night scenario's headlights")  # fmt: skip
    vs.add_argument("--width", type=_positive_int, default=1024)
    vs.add_argument("--height", type=_positive_int, default=768)
    vs.add_argument("--turn-rate", type=_positive_float, default=5.0, help="deg/s of the turns")
    vs.add_argument("--spawn-radius", type=float, default=10.0,
                    help="seeds move the spawn this far from the scenario's (m)")  # fmt: skip
    vs.add_argument("--keyframe", type=_positive_float, default=1.0,
                    help="VO keyframe spacing on the straight drive (m)")  # fmt: skip
    vs.add_argument("--fov", type=_positive_float, default=None, metavar="DEG",
                    help="the mast cameras' vertical field of view (deg; default: the "
                         "scenario's), for the lens trade")  # fmt: skip
    vs.add_argument("--max-range", type=_positive_float, default=None, metavar="M",
                    help="stereo points aligned out to this depth (m; default: the "
                         "scenario's ground.perception.max_range_m)")  # fmt: skip
    vs.add_argument(
        "--images",
        action="store_true",
        help="write each turn's two stereo pairs (left + disparity) to DIR/images",
    )
    vs.add_argument(
        "--commanded-turns",
        action="store_true",
        help="turn by the commanded angle, not lengthened to the angle asked for",
    )
    vs.add_argument("--out", required=True)
    vs.add_argument("--no-progress", action="store_true")
    vs.set_defaults(func=_cmd_vo_study)

    sf = sub.add_parser(
        "slip-fit", help="fit soil phi and K to measured slip vs slope (Wong-Reece reference)"
    )
    sf.add_argument("data", help="CSV with columns slope_deg,slip (slip a fraction)")
    sf.add_argument("--rover", choices=["skid", "explicit"], default="explicit")
    sf.add_argument(
        "--base-soil",
        default="lunar_regolith",
        help="soil whose other parameters are kept: lunar_regolith, grc1, jsc1a or a YAML file",
    )
    sf.add_argument("--out", required=True, help="output directory (soil.yaml, fit.csv, fit.png)")
    sf.set_defaults(func=_cmd_slip_fit)

    from lunar_drake.ephemeris import cli as ephemeris_cli

    pe = sub.add_parser("ephemeris", help="Sun and Earth in a lunar site's sky (SPICE)")
    ephemeris_cli.add_arguments(pe)
    pe.set_defaults(func=ephemeris_cli.run_cli)

    from lunar_drake.render import lightmap as lightmap_cli

    pl = sub.add_parser("lightmap", help="bake a terrain lightmap (visible solar disk fraction)")
    lightmap_cli.add_arguments(pl)
    pl.set_defaults(func=lightmap_cli.run_cli)

    rd = sub.add_parser("render", help="render the mast stereo pair of a scenario")
    rd.add_argument(
        "--scenario",
        default="default",
        help="scenario name in the packaged file, or FILE.yaml[:NAME]",
    )
    rd.add_argument("--scenario-text", default="{}", help="YAML overrides")
    rd.add_argument("--time", type=float, default=0.0, help="sim time of the frame (s)")
    rd.add_argument("--out", required=True, help="output directory")
    rd.add_argument("--no-progress", action="store_true")
    rd.set_defaults(func=_cmd_render)

    pn = sub.add_parser("plan", help="plan a hazard-free path on the ground's map of a site")
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
    pn.set_defaults(func=_cmd_plan)

    w = sub.add_parser("world", help="the science world model of a site")
    wsub = w.add_subparsers(dest="world_command", required=True)
    wb = wsub.add_parser("build", help="build every layer of a site's world model")
    wb.add_argument("site_dir", help="a site directory (from 'terrain synth')")
    wb.add_argument("--out", required=True, help="output directory")
    wb.add_argument("--utc", default=None,
                    help="epoch of the temperature and OH layers (default: the default "
                         "scenario's)")  # fmt: skip
    wb.add_argument("--config", default=None,
                    help="a WorldConfig YAML file (shaped as world.json's 'config')")  # fmt: skip
    wb.add_argument("--seed", type=int, default=None,
                    help="noise seed (default: the site.json's; 0 without one)")
    wb.add_argument("--workers", type=_positive_int, default=None,
                    help="threads (default: the config's, 2)")  # fmt: skip
    wb.add_argument("--no-progress", action="store_true")
    wb.set_defaults(func=_cmd_world_build)

    t = sub.add_parser("terrain", help="terrain tools")
    tsub = t.add_subparsers(dest="terrain_command", required=True)
    s = tsub.add_parser("synth", help="synthesize a site (paper section 4)")
    s.add_argument("--size", type=_positive_int, default=1024, help="pixels a side")
    s.add_argument("--resolution", type=_positive_float, default=0.1, help="metres per pixel")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--tile", type=_positive_int, default=1024, help="tile side (px)")
    s.add_argument("--workers", type=_positive_int, default=2, help="worker threads")
    s.add_argument(
        "--factor", type=_positive_int, default=32, help="fractal upscaling factor (power of two)"
    )
    s.add_argument("--min-crater-m", type=_positive_float, default=0.5)
    s.add_argument("--max-crater-m", type=_positive_float, default=None)
    s.add_argument("--sfd", choices=["trask", "viper", "powerlaw"], default="trask")
    s.add_argument(
        "--powerlaw-coefficient",
        type=_positive_float,
        default=0.08,
        help="c in N(>=D) = c D^e per m^2 (with --sfd powerlaw)",
    )
    s.add_argument(
        "--powerlaw-exponent",
        type=float,
        default=-2.0,
        help="e in N(>=D) = c D^e per m^2 (with --sfd powerlaw)",
    )
    s.add_argument(
        "--rock-abundance",
        type=float,
        default=0.005,
        help="Golombek-Rapp cumulative fractional area k, in [0, 1)",
    )
    s.add_argument(
        "--ejecta-rock-abundance",
        type=float,
        default=0.05,
        help="Golombek-Rapp k of ejecta rocks on a fresh crater rim, in [0, 1)",
    )
    s.add_argument("--min-rock-m", type=_positive_float, default=0.1)
    s.add_argument("--lat", type=float, default=-90.0, help="site centre latitude (deg)")
    s.add_argument("--lon", type=float, default=0.0, help="site centre longitude (deg east)")
    s.add_argument("--from-dem", default=None, help="upscale this GeoTIFF DEM by --factor")
    s.add_argument("--no-progress", action="store_true")
    s.set_defaults(func=_cmd_synth)
    return p


def main(argv: list[str] | None = None) -> int:
    """Runs one command; returns the exit status (0, 2 for bad input, 130 interrupted,
    143 terminated: under :func:`run`, SIGTERM is taken as Ctrl-C is, partial outputs
    removed)."""
    from lunar_drake import interrupts

    parser = build_parser()
    args = parser.parse_args(argv)
    sigint = interrupts.LatchedSigint()
    try:
        return args.func(args)
    except LunarDrakeError as exc:
        if interrupts.requested():  # Ctrl-C that a library turned into another error
            return _interrupted(interrupts.terminated())
        print(f"lunar-drake: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return _interrupted(interrupts.terminated())
    except Exception:
        # Ctrl-C during an import (pydrake's, Open3D's) surfaces as another error
        # ("ImportError: initialization failed"): it was the interrupt all the same.
        if interrupts.requested():
            return _interrupted(interrupts.terminated())
        raise
    finally:
        sigint.restore()


def _interrupted(terminated: bool = False) -> int:
    """Reports an interrupt: 130 after Ctrl-C, 143 after SIGTERM (128 + the signal)."""
    what = "terminated" if terminated else "interrupted"
    print(f"lunar-drake: {what}; partial outputs removed", file=sys.stderr)
    return 143 if terminated else 130


def run() -> None:
    """The ``lunar-drake`` program: :func:`main`, then exit with its status. After Ctrl-C
    or SIGTERM it exits at once (streams flushed) instead of finalizing the interpreter: an
    extension interrupted mid-import (Open3D) can otherwise fail at exit and turn 130
    into 1, or re-raise the interrupt."""
    from lunar_drake import interrupts

    sigterm = interrupts.TermAsInterrupt()  # the program's only: main() from Python keeps
    try:  # the default SIGTERM
        code = main()
        if interrupts.terminated() and code not in (130, 143):  # the interrupt was lost
            print("lunar-drake: terminated", file=sys.stderr)
            code = 143
        sys.stdout.flush()
    except KeyboardInterrupt:  # one that came just after main() returned
        code = _interrupted(interrupts.terminated())
    except BrokenPipeError:  # the reader went away (``| head``): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        code = 141  # 128 + SIGPIPE, as a shell reports it
    finally:
        sigterm.restore()
    if code in (130, 143):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    run()
