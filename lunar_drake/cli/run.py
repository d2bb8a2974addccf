"""``lunar-drake run``: simulate a mission scenario and write its run directory."""

from __future__ import annotations

import math
import time
from pathlib import Path

from lunar_drake.cli._common import add_subcommand, plural, split_scenario
from lunar_drake.errors import ConfigError, check_range

#: Simulated seconds per wall second on a 2-core machine (low, high), with the stereo
#: cameras and without: the range of whole default missions measured here
#: (`lunar-drake run`; with cameras 4.2-4.9x alone on 2026-11-29, a slow day, and
#: 7.9-8.8x on 2026-12-01, one core busy with another job or not; without cameras 8.2-11.5x
#: and 22.0-23.5x; the low end for a slow day shared with another job). Only for the
#: estimate printed before a run.
REALTIME_FACTOR = {"cameras": (2.5, 8.5), "no_cameras": (8.0, 23.0)}
#: Bytes per pixel of one camera's saved frame (16-bit raw PNG + 8-bit preview PNG of
#: the noisy 12-bit codes): 1.5-1.9 measured on default-site frames at 640 x 480.
FRAME_BYTES_PER_PX = 1.7
#: Bytes per pixel of one received stereo frame in run.mcap (the left preview as JPEG,
#: quality 85): 1.1 MB for 16 frames at 640 x 480 on the default site.
MCAP_BYTES_PER_PX = 0.23
#: Meshcat's static replay (meshcat.html): a base (the rover's meshes, the page), bytes
#: per terrain mesh vertex (``terrain_view.max_mesh_px`` squared) and per simulated
#: second of recording; fitted to the default scenario (10 s: 11.0 MB, 40 s: 14.6 MB)
#: and the small one (1 s: 2.67 MB, 11 s: 3.88 MB).
MESHCAT_BASE_BYTES = 2.3e6
MESHCAT_BYTES_PER_VERTEX = 50.0
MESHCAT_BYTES_PER_S = 1.2e5


def run_estimate(scenario, *, meshcat: bool, rate: float | None = None) -> dict:
    """What a run of ``scenario`` will cost, roughly, before it starts: ``minutes``
    (low, high) on a 2-core machine (:data:`REALTIME_FACTOR`; no less than the paced
    duration at ``rate`` x real time), ``frames_bytes`` (the saved stereo frames),
    ``mcap_bytes`` (their JPEGs in ``run.mcap``), ``meshcat_bytes`` (the static replay, 0
    without Meshcat) and ``total_bytes``. An estimate from constants measured here, not
    a promise."""
    cam = scenario.sensors.camera
    duration = float(scenario.simulation_duration)
    rtf = REALTIME_FACTOR["cameras" if cam.enabled else "no_cameras"]
    frames = mcap = 0.0
    if cam.enabled and scenario.logging.save_frames:
        n = math.floor(duration * cam.rate_hz) + 1  # t = 0 and every period
        frames = n * 2 * cam.width * cam.height * FRAME_BYTES_PER_PX
        mcap = n * cam.width * cam.height * MCAP_BYTES_PER_PX
    html = 0.0
    if meshcat:
        px = scenario.terrain_view.max_mesh_px
        html = MESHCAT_BASE_BYTES + MESHCAT_BYTES_PER_VERTEX * px * px
        html += MESHCAT_BYTES_PER_S * duration
    lo, hi = duration / rtf[1] / 60.0, duration / rtf[0] / 60.0
    if rate:
        paced = duration / rate / 60.0
        lo, hi = max(lo, paced), max(hi, paced)
    return {
        "minutes": (lo, hi),
        "frames_bytes": frames,
        "mcap_bytes": mcap,
        "meshcat_bytes": html,
        "total_bytes": frames + mcap + html,
    }


def _minutes(lo: float, hi: float) -> str:
    if hi < 1.0:
        return "under a minute"
    if lo < 1.0:
        return f"up to {math.ceil(hi)} min"
    if round(lo) >= math.ceil(hi) - 1:
        return f"about {math.ceil(hi)} min"
    return f"roughly {round(lo)}-{math.ceil(hi)} min"


def describe_estimate(scenario, *, meshcat: bool, out: Path, rate: float | None = None) -> str:
    """What is printed before a run: simulated time, cameras, the estimated wall time
    (paced at ``rate`` x real time when given) and disk use, and, for a long or large
    run, a second line on where to start instead."""
    e = run_estimate(scenario, meshcat=meshcat, rate=rate)
    cam = scenario.sensors.camera.enabled
    parts = []
    if e["meshcat_bytes"]:
        parts.append(f"meshcat.html ~{e['meshcat_bytes'] / 1e6:.0f} MB")
    if e["frames_bytes"]:
        parts.append(f"frames/ ~{e['frames_bytes'] / 1e6:.0f} MB")
        parts.append(f"run.mcap ~{e['mcap_bytes'] / 1e6:.0f} MB")
    size = f"about {e['total_bytes'] / 1e6:.0f} MB" if parts else "a few MB"
    detail = f" ({', '.join(parts)})" if parts else ""
    text = (
        f"This run simulates {scenario.simulation_duration:g} s "
        f"{'with' if cam else 'without'} the stereo cameras: {_minutes(*e['minutes'])} on "
        f"2 cores, and writes {size}{detail} to {out}."
    )
    if (e["minutes"][1] > 3.0 or e["total_bytes"] > 50e6) and scenario.name != "goto":
        text += (
            "\nFor a first look: --scenario goto --no-meshcat (a minute or two); --no-cameras "
            "and --no-meshcat make any run faster and smaller."
        )
    return text


def kernels_cached() -> bool:
    """True if numba's on-disk cache holds the mission's compiled kernels for this source
    and numba version (judged by the wheel-soil contact's step, which every mission runs;
    wherever numba keeps its cache); True when that cannot be told."""
    try:
        from lunar_drake.dynamics import contact_kernels

        return bool(contact_kernels.step_kinematics._cache._cache_file._load_index())
    except Exception:  # numba internals moved or an unreadable index: say nothing
        return True


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
    ``scenario.yaml`` says everything). With ``ground.goals`` the route is unused and
    is emptied, so ``scenario.yaml`` shows only what drives the rover."""
    import yaml

    from lunar_drake.scenario import MAX_DURATION_S
    from lunar_drake.scenario_files import apply_overrides, load_scenario

    filename, name = split_scenario(args.scenario)
    scenario = load_scenario(
        filename=filename, scenario_name=name, scenario_text=args.scenario_text
    )
    flags: dict = {}
    if args.duration is not None:
        check_range("--duration", float(args.duration), 0.0, MAX_DURATION_S, unit=" s")
        flags["simulation_duration"] = float(args.duration)
    if args.no_cameras:
        flags["sensors"] = {"camera": {"enabled": False}}
    if args.soil is not None:
        flags.update(_soil_override(args.soil))
    if flags:
        scenario = apply_overrides(
            scenario, yaml.safe_dump(flags, default_flow_style=True), source="command-line flags"
        )
    if scenario.ground.goals:
        scenario.ground.route = []
    return scenario, name


def describe_goals(goals: list) -> str:
    """The console's goal line from ``summary.json``'s ``goals`` (scored on truth): how
    many were reached and, when not all, the first goal not reached and how close the
    rover came to it."""
    got = sum(g["reached"] for g in goals)
    head = f"Goals: {got} of {len(goals)} reached (truth"
    missed = [(k, g) for k, g in enumerate(goals) if not g["reached"]]
    if not missed:
        last = goals[-1]["final_distance_m"]
        return f"{head}; at the end the rover was {last:.2f} m from the last)"
    k, g = missed[0]
    x, y = g["goal_xy_m"]
    more = f"; {len(missed) - 1} more not reached" if len(missed) > 1 else ""
    return (f"{head}); goal {k + 1} at ({x:g}, {y:g}) m not reached: the rover came within "
            f"{g['closest_m']:.2f} m of it{more}")  # fmt: skip


def map_line(scenario) -> str | None:
    """The console line of the ground's a-priori map when it is the oracle (``truth``)."""
    if scenario.ground.map.source != "truth":
        return None
    return ("Ground: planning on the TRUE map (oracle): ground.map.source is truth; a real "
            "mission has only the orbital map")  # fmt: skip


def calibration_line(scenario) -> str | None:
    """The console line of the flight's slip calibration when it is the plant's own soil
    (an oracle)."""
    from lunar_drake.preflight import slip_calibration

    cal = slip_calibration(scenario)
    if cal is None or not cal.is_soil(scenario.soil):
        return None
    return (f"Flight: slip calibrated on the TRUE soil (oracle): "
            f"flight.estimator.slip_calibration {cal.spec!r} is the plant's soil; a real "
            "mission calibrates on a simulant before launch")  # fmt: skip


def command(args) -> int:
    from lunar_drake import outputs
    from lunar_drake.files import check_replaceable

    scenario, name = resolve_run_scenario(args)
    out = Path(args.out) if args.out else Path("runs") / (scenario.name or name)
    check_replaceable(out, allowed=outputs.RUN_DIR_NAMES, what="run directory")
    rate = check_rate(args.rate, serve=args.serve)
    server = observer = None
    if args.serve:
        from lunar_drake.mission_control.live import LiveObserver
        from lunar_drake.mission_control.process import ServerProcess

        check_port(args.port)
        if args.foxglove_port < -1:
            raise ConfigError(f"--foxglove-port {args.foxglove_port} must be -1 (none) or in "
                              "[0, 65535]")  # fmt: skip
        foxglove = None if args.foxglove_port == -1 else check_port(args.foxglove_port)
        server = ServerProcess(host=args.host or "127.0.0.1", port=args.port,
                               allow_remote=args.host is not None,
                               foxglove_port=foxglove)  # fmt: skip
        observer = LiveObserver(outbox=server.outbox, inbox=server.inbox,
                                alive=server.process.is_alive,
                                instructor=args.instructor)  # fmt: skip
        print(f"Mission control: {server.url} (the run is paced to {rate:g}x real time; "
              "the page's End button ends it early and writes it)", flush=True)  # fmt: skip
        if foxglove is not None:
            where = f"port {foxglove}" if foxglove else "a free port"
            print(f"Foxglove: a live WebSocket server on {where} once the site is built "
                  f"({server.url}api/info says where; Foxglove: Open connection > Foxglove "
                  "WebSocket)", flush=True)  # fmt: skip
    try:
        return _run(args, scenario=scenario, name=name, out=out, rate=rate, server=server,
                    observer=observer)  # fmt: skip
    finally:
        if server is not None:
            server.close()


#: A live mission's observers run this long after each ground tick (s): they publish what
#: that tick took in at once, and a command they queue goes up at the next tick.
OBSERVE_AFTER_TICK_S = 0.001


def check_rate(rate: float | None, *, serve: bool) -> float | None:
    """``--rate``: None (as fast as possible; 1 with ``--serve``) or a finite rate >= 0."""
    if rate is None:
        return 1.0 if serve else None
    if not (math.isfinite(rate) and rate >= 0.0):
        raise ConfigError(f"--rate {rate!r} must be >= 0 (x real time; 0: as fast as possible)")
    return float(rate)


def check_port(port: int) -> int:
    """``--port``: 0 (any free port) to 65535."""
    if not 0 <= port <= 65535:
        raise ConfigError(f"--port {port} must be in [0, 65535]")
    return port


def with_actions(scenario, actions: list):
    """``scenario`` with ``actions`` (commands sent live) appended to
    ``ground.actions``, so the run's ``scenario.yaml`` reproduces them."""
    import copy

    out = copy.deepcopy(scenario)
    if not actions:
        return out
    out.ground.actions = [*out.ground.actions, *actions]
    return out


def _run(args, *, scenario, name: str, out: Path, rate, server, observer) -> int:
    from lunar_drake import metrics, outputs
    from lunar_drake.files import staged_directory
    from lunar_drake.science.world import needs_world, run_world
    from lunar_drake.simulation import simulate
    from lunar_drake.site import load_site

    print(describe_estimate(scenario, meshcat=not args.no_meshcat, out=out, rate=rate),
          flush=True)  # fmt: skip
    for line in (map_line(scenario), calibration_line(scenario)):
        if line:
            print(line, flush=True)
    meshcat = None
    if not args.no_meshcat:
        from pydrake.geometry import Meshcat, MeshcatParams

        meshcat = Meshcat(MeshcatParams(host=args.meshcat_host))
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
    print(
        f"Scenario {scenario.name or name!r} (seed {scenario.random_seed}); building the site...",
        flush=True,
    )
    if not kernels_cached():
        print("First run here: numba compiles the simulator's kernels once (about two "
              "minutes on 2 cores); later runs start at once.", flush=True)  # fmt: skip
    observers = [observer] if observer is not None else []
    if observer is not None and meshcat is not None:
        from lunar_drake.mission_control.meshcat_controls import MeshcatControls

        observers.append(MeshcatControls(meshcat))
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
            realtime_rate=rate,
            observers=tuple(observers),
            observe_period_s=1.0 / scenario.ground.rate_hz,
            observe_offset_s=OBSERVE_AFTER_TICK_S,
        )
        if observers:
            scenario = with_actions(scenario, sorted(
                (a for o in observers for a in o.actions), key=lambda a: a.t_s))
            if observer.ended_s is not None:  # ended from the page: the run's length
                scenario.simulation_duration = float(observer.ended_s)
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
    _report(summary, timing=timing, t_site=t_site, scenario=scenario, out=out,
            meshcat=meshcat)  # fmt: skip
    if observer is not None:
        observer.finish(simulated_s=summary["simulated_s"])
        print(f"Mission control: {server.url} (the finished run)"
              + ("" if args.wait else "; closing (--wait keeps it open)"), flush=True)
    if meshcat is not None:
        print(f"Meshcat: {meshcat.web_url()} (static replay: {out / 'meshcat.html'})")
    if args.wait and (meshcat is not None or server is not None):
        print("Serving; press Ctrl-C to stop.", flush=True)
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
    return 0


def _report(summary: dict, *, timing: dict, t_site: float, scenario, out: Path, meshcat):
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
    pw = summary.get("power")
    if pw:
        per_m = f", {pw['Wh_per_m']:.3f} Wh/m" if pw["Wh_per_m"] is not None else ""
        print(
            f"Power: array {pw['energy_generated_Wh']:.2f} Wh, loads {pw['energy_used_Wh']:.2f} Wh"
            f"{per_m}; SOC {100 * pw['final_soc']:.1f}% at the end (min "
            f"{100 * pw['min_soc']:.1f}%); {pw['shadow_s']:.0f} s without direct sun on the panel"
        )
    loc = summary["localization"]
    if loc:
        print(
            f"On-board estimate at the end: {loc['final_position_error_m']:.2f} m off, "
            f"heading {loc['final_heading_error_deg']:.2f} deg off; ground received "
            f"{plural(summary['telemetry_received'], 'telemetry packet')}"
        )
    if summary.get("goals"):
        print(describe_goals(summary["goals"]))
    gr = summary["ground"]
    if gr["goals"]:
        on_ground = sum(g["status"] == "reached" for g in gr["goals"])
        hz = summary["hazards"]
        print(
            f"Ground: {on_ground} of {len(gr['goals'])} goals reached on its estimate, "
            f"{plural(gr['plans'], 'plan')} ({gr['replans']} replans); "
            f"hazard strikes {hz['strikes']}"
        )
    md = summary["modes"]
    safings = ", ".join(f"{n} {k}" for k, n in md["safings"].items()) or "none"
    print(f"Modes: {plural(md['count'], 'mode change')} on board; safings: {safings}")
    if summary.get("images_received"):
        print(
            f"Images: the ground received {plural(summary['images_received'], 'stereo frame')}"
            f" ({summary['images_bytes_received'] / 1e6:.1f} MB)"
        )
    per = summary.get("perception") or {}
    if per.get("keyframes"):
        vo = ", ".join(f"{n} {k}" for k, n in per["vo"].items())
        sigma = per.get("final_sigma_m")
        drift = f"; the ground's position sigma {sigma:.2f} m" if sigma is not None else ""
        print(f"Perception: {plural(per['keyframes'], 'stereo keyframe')} (VO: {vo}); "
              f"{per['lethal_cells_added']} lethal cells added to the ground's map"
              f"{drift}")  # fmt: skip
    sci = summary.get("science") or {}
    if "nirvss_records" in sci:
        rmse = sci.get("lcs_world_rmse_K")
        lcs = f"; LCS map {rmse:.2f} K RMS from the world's cells" if rmse is not None else ""
        drill = f"; {sci['drill_samples']} drill samples" if "drill_samples" in sci else ""
        print(
            f"Science: the ground received "
            f"{plural(sci['nirvss_records'], 'NIRVSS record')}{lcs}{drill}"
        )
    if "nss_records" in sci:
        r, rf = sci.get("nss_world_r"), sci.get("nss_footprint_r")
        score = (f"; map against the world r = {r:.2f} over {sci['nss_world_cells']} cells of"
                 f" 2 m" if r else "") + (f" (instrument: r = {rf:.2f})" if rf else "")  # fmt: skip
        print(f"Science: the ground received {plural(sci['nss_records'], 'NSS record')}"
              + (f", mean hydrogen {sci['weh_est_mean_wt_pct']:.2f} wt% WEH (truth "
                 f"{sci['weh_truth_mean_wt_pct']:.2f})" if sci["nss_records"] else "")
              + score)  # fmt: skip
    from lunar_drake import outputs

    files = [name for name in outputs.run_files() if (out / name).exists()]
    for name in outputs.SCIENCE_FILES:
        if (out / name).exists():
            files.append(name)
    if per.get("keyframes"):
        files.append("keyframes.csv")
    if (out / "keyframe_points.npy").exists():
        files.append("keyframe_points.npy")
    if (out / "ground_map.png").exists():
        files.append("ground_map.png")
    if scenario.sensors.camera.enabled:
        files.append("calibration.yaml")
    if summary["camera_frames"]:
        files.append(f"frames/ ({plural(summary['camera_frames'], 'stereo frame')})")
    if meshcat is not None:
        files.append("meshcat.html")
    print(f"Outputs: {out.resolve()} ({', '.join(files)})")


def add_parser(sub) -> None:
    r = add_subcommand(
        sub, "run", help="run a mission scenario (the main job)",
        epilog="The default scenario simulates 700 s with the stereo cameras: minutes on "
               "2 cores and a few hundred MB of frames and Meshcat replay. For a first "
               "look: lunar-drake run --scenario goto (a minute or two). List the scenarios with "
               "lunar-drake scenarios.",
    )  # fmt: skip
    r.add_argument(
        "--scenario",
        default="default",
        help="scenario name in the packaged file (lunar-drake scenarios lists them), "
        "FILE.yaml[:NAME], or a run's scenario.yaml to repeat it",
    )
    r.add_argument("--scenario-text", default="{}", help="YAML overrides, e.g. '{random_seed: 3}'")
    r.add_argument("--duration", type=float, default=None,
                   help="simulated seconds (sets simulation_duration; default: the "
                        "scenario's)")  # fmt: skip
    r.add_argument("--out", default=None, help="run directory (default: runs/<scenario>)")
    r.add_argument("--no-meshcat", action="store_true",
                   help="headless: no Meshcat server and no meshcat.html")  # fmt: skip
    r.add_argument(
        "--meshcat-host",
        default="127.0.0.1",
        help="interface Meshcat listens on ('*' opens it to the network)",
    )
    r.add_argument(
        "--no-cameras",
        action="store_true",
        help="skip the Hapke stereo cameras (sets sensors.camera.enabled: false): much "
        "faster, no frames; the ground then has no stereo",
    )
    r.add_argument("--soil", default=None,
                   help="soil preset (lunar_regolith, grc1, jsc1a) or a soil YAML file "
                        "(default: the scenario's soil)")  # fmt: skip
    r.add_argument("--wait", action="store_true",
                   help="keep serving Meshcat (and mission control) after the run")  # fmt: skip
    r.add_argument("--serve", action="store_true",
                   help="live mission: serve the mission-control page (Open MCT) while the "
                        "run goes, paced to --rate, and take commands from it")  # fmt: skip
    r.add_argument("--port", type=int, default=8080,
                   help="mission control's port (default 8080; 0: any free port)")
    r.add_argument("--host", default=None,
                   help="interface mission control listens on (default 127.0.0.1; giving "
                        "another opens it to the network)")  # fmt: skip
    r.add_argument("--foxglove-port", type=int, default=8765,
                   help="with --serve, the foxglove-sdk live WebSocket server's port "
                        "(default 8765; -1: none)")  # fmt: skip
    r.add_argument("--instructor", action="store_true",
                   help="with --serve, add the instructor overlay: the rover's TRUE track "
                        "on the site map, marked as truth (off by default: the page shows "
                        "only what the ground received)")  # fmt: skip
    r.add_argument("--rate", type=float, default=None,
                   help="pace the run to this multiple of real time (default: 1 with "
                        "--serve, else as fast as it can; 0: as fast as it can)")  # fmt: skip
    r.add_argument("--no-progress", action="store_true", help="no progress bars")
    r.set_defaults(func=command)
