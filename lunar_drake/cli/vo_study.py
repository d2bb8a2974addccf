"""``lunar-drake vo-study``: stereo ICP visual odometry vs fused odometry (paper
Fig. 21)."""

from __future__ import annotations

from pathlib import Path

from lunar_drake.cli._common import add_subcommand, positive_float, positive_int


def command(args) -> int:
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
        baseline_m=args.baseline,
        mast_height_m=args.mast_height,
        max_range_m=args.max_range,
        calibrate_turns=not args.commanded_turns,
        images=args.images,
    )
    out = run_vo_study(config=config, out_dir=args.out, progress=not args.no_progress,
                       workers=args.workers, scheduler=args.scheduler)  # fmt: skip
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


def add_parser(sub) -> None:
    vs = add_subcommand(
        sub, "vo-study", help="stereo ICP visual odometry vs fused odometry (paper Fig. 21)"
    )
    vs.add_argument("--scenario", default="default", help="the scenario's site, rover, sensors")
    vs.add_argument("--angles", default="0:60:10", help="A:B:STEP in degrees, or a comma list")
    vs.add_argument("--seeds", type=positive_int, default=3)
    vs.add_argument("--straight", type=positive_float, default=None, metavar="DIST_M",
                    help="drive straight this far instead (writes straight.json)")  # fmt: skip
    vs.add_argument("--lights", action="store_true",
                    help="in shadow, with the night scenario's headlights")  # fmt: skip
    vs.add_argument("--width", type=positive_int, default=1024)
    vs.add_argument("--height", type=positive_int, default=768)
    vs.add_argument("--turn-rate", type=positive_float, default=5.0, help="deg/s of the turns")
    vs.add_argument("--spawn-radius", type=float, default=10.0,
                    help="seeds move the spawn this far from the scenario's (m)")  # fmt: skip
    vs.add_argument("--keyframe", type=positive_float, default=1.0,
                    help="VO keyframe spacing on the straight drive (m)")  # fmt: skip
    vs.add_argument("--fov", type=positive_float, default=None, metavar="DEG",
                    help="the mast cameras' vertical field of view (deg; default: the "
                         "scenario's), for the lens trade")  # fmt: skip
    vs.add_argument("--baseline", type=positive_float, default=None, metavar="M",
                    help="the stereo baseline (m; default: the rover's), for the placement "
                         "trade")  # fmt: skip
    vs.add_argument("--mast-height", type=positive_float, default=None, metavar="M",
                    help="the gimbal's height over the chassis (m; default: the rover's)")
    vs.add_argument("--max-range", type=positive_float, default=None, metavar="M",
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
    vs.add_argument("--workers", type=positive_int, default=1,
                    help="parallel processes (dask.distributed, as lunar-drake trade)")
    vs.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="an existing dask scheduler (tcp://HOST:PORT) for the runs")
    vs.add_argument("--out", required=True)
    vs.add_argument("--no-progress", action="store_true")
    vs.set_defaults(func=command)
