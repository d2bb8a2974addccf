"""Benchmark: ground stereo depth against the renderer's own depth.

    .venv/bin/python benchmarks/stereo.py --out bench_stereo.json [--images DIR]

Scenes on the default site (the ``default`` scenario's rover at its spawn point, the
mast looking 6 m ahead, cameras ``--width`` x ``--height``, 1024 x 768 by default):

* ``sunlit``: the scenario epoch, the rover turned to ``--yaws`` (0, 90, 180, 270 deg);
* ``earthshine``: the ``night`` scenario's epoch (Sun 3 deg below the horizon), no
  headlights, exposure 0.05 s and gain 4 (the night scenario's), Earthshine and the
  faint fill only.

Each stereo pair is rendered by the mission's camera (the raw 12-bit frames the rover
would downlink, PNG: lossless), matched by :func:`lunar_drake.perception.stereo.match`
with the scenario-independent default :class:`~lunar_drake.perception.stereo.
StereoConfig` and the calibration from the camera model, and compared with the
renderer's depth (m along the optical axis) over the pixels whose true depth is 2-10 m:
``median_abs_error_pct`` (of the true depth) of the valid pixels and
``valid_fraction`` (valid / in range). JSON: per scene and pose, and the medians per
scene. ``--images DIR`` writes the left preview, the disparity and the error map.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import record_speed_index
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import record_speed_index


def render_pair(scenario, site, *, yaw_deg: float, forward_m: float = 0.0):
    """(left raw, right raw, left true depth, left preview, X_WC of the left camera
    (4 x 4, truth)) two frames in, the rover spawned ``forward_m`` ahead along its
    heading."""
    from pydrake.systems.analysis import Simulator

    from lunar_drake.diagrams.mission import MakeMissionDiagram

    s = copy.deepcopy(scenario)
    s.rover.spawn_yaw_deg = yaw_deg
    s.rover.spawn_x_m += forward_m * math.cos(math.radians(yaw_deg))
    s.rover.spawn_y_m += forward_m * math.sin(math.radians(yaw_deg))
    s.sensors.camera.enabled = True
    s.flight.images.enabled = False
    s.ground.goals = []
    s.ground.route = []
    mission = MakeMissionDiagram(scenario=s, site=site)
    sim = Simulator(mission)
    # Let the gimbal settle on its 6 m look-ahead, then take the next frame.
    period = 1.0 / s.sensors.camera.rate_hz
    sim.AdvanceTo(2 * period + s.sensors.camera.delay_s + 1e-6)
    cam = mission.GetSubsystemByName("plant").GetSubsystemByName("camera")
    ctx = cam.GetMyContextFromRoot(sim.get_context())
    left, right = cam.frame(ctx, "left"), cam.frame(ctx, "right")
    mbp = mission.GetSubsystemByName("plant").GetSubsystemByName("plant")
    pctx = mbp.GetMyContextFromRoot(sim.get_context())
    X_WC = mbp.GetFrameByName("left_camera").CalcPoseInWorld(pctx).GetAsMatrix4()
    return left.raw, right.raw, left.depth, left.preview, X_WC


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--width", type=int, default=1024)
    p.add_argument("--height", type=int, default=768)
    p.add_argument("--yaws", default="0,90,180,270", help="rover headings (deg), sunlit")
    p.add_argument("--out", default=None)
    p.add_argument("--images", default=None, help="write preview/disparity/error PNGs here")
    p.add_argument("--vo-step", type=float, default=0.5,
                   help="ICP visual odometry over this forward step (m; 0: off)")  # fmt: skip
    a = p.parse_args(argv)
    if a.out:
        check_output_file(a.out, what="results JSON")

    from lunar_drake.perception.calibration import StereoCalibration
    from lunar_drake.perception.stereo import StereoConfig, depth_error, match
    from lunar_drake.scenario_files import load_scenario
    from lunar_drake.site import load_site

    yaws = [float(y) for y in a.yaws.split(",")]
    base = load_scenario(scenario_name="default")
    night = load_scenario(scenario_name="night")
    for s in (base, night):
        s.sensors.camera.width, s.sensors.camera.height = a.width, a.height
        s.sensors.camera.rate_hz = 1.0
        s.sensors.camera.validate()  # --width / --height: one-line errors naming them
    night.rover.lights = []
    site = load_site(base, progress=True)
    config = StereoConfig()
    scenes = [("sunlit", base, y) for y in yaws] + [("earthshine", night, yaws[0])]
    rows = []
    for name, scen, yaw in scenes:
        calib = StereoCalibration.from_camera(camera=scen.sensors.camera,
                                              description=scen.rover.description)  # fmt: skip
        left, right, depth, preview, X_WC = render_pair(scen, site, yaw_deg=yaw)
        t0 = time.perf_counter()
        res = match(left, right, calib=calib, config=config)
        t_match = time.perf_counter() - t0
        med, frac, n = depth_error(res, depth)
        rows.append({"scene": name, "yaw_deg": yaw, "median_abs_error_pct": med,
                     "valid_fraction": frac, "pixels_2_10_m": n, "match_s": t_match,
                     "num_disparities": res.num_disparities,
                     "median_code": float(np.median(left))})  # fmt: skip
        if a.images:
            _write_images(Path(a.images), f"{name}_{int(yaw)}", preview, res, depth)
        if name == "sunlit" and a.vo_step > 0:
            rows[-1]["vo"] = _vo(scen, site, yaw, a.vo_step, calib, config, res, X_WC)
    out = {"width": a.width, "height": a.height, "config": vars(config), "runs": rows}
    for name in ("sunlit", "earthshine"):
        r = [x for x in rows if x["scene"] == name]
        out[name] = {
            "median_abs_error_pct": float(np.nanmedian([x["median_abs_error_pct"] for x in r])),
            "valid_fraction": float(np.median([x["valid_fraction"] for x in r])),
        }
    print(f"{'scene':>11} {'yaw':>5} {'err % (2-10 m)':>15} {'valid':>7} {'px 2-10 m':>10} "
          f"{'match s':>8} {'median code':>12}")  # fmt: skip
    for r in rows:
        print(f"{r['scene']:>11} {r['yaw_deg']:5.0f} {r['median_abs_error_pct']:15.2f} "
              f"{r['valid_fraction']:7.3f} {r['pixels_2_10_m']:10d} {r['match_s']:8.2f} "
              f"{r['median_code']:12.0f}")  # fmt: skip
    for r in rows:
        if "vo" in r:
            v = r["vo"]
            print(f"VO yaw {r['yaw_deg']:.0f}: {v['step_m']:.2f} m step, error "
                  f"{100 * v['vo_error_m']:.1f} cm / {v['vo_error_deg']:.2f} deg (guess "
                  f"{100 * v['guess_error_m']:.1f} cm / {v['guess_error_deg']:.2f} deg), "
                  f"fitness {v['fitness']:.2f}, rmse {100 * v['inlier_rmse_m']:.1f} cm, "
                  f"condition {v['condition']:.3g}"
                  + (f", REJECTED: {v['reason']}" if v["rejected"] else ""))  # fmt: skip
    for name in ("sunlit", "earthshine"):
        print(
            f"{name}: median error {out[name]['median_abs_error_pct']:.2f} % of depth, "
            f"valid fraction {out[name]['valid_fraction']:.3f}"
        )
    record_speed_index(out)
    if a.out:
        atomic_write_text(a.out, json.dumps(out, indent=2) + "\n", what="results JSON")
    return 0


def _vo(scen, site, yaw, step, calib, config, res0, X_WC0) -> dict:
    """ICP between the pair at the spawn and one ``step`` m ahead with the ground's VO
    (``PerceptionConfig``: points within its ``max_range_m``, the attitude prior, the
    overlap), from the true camera motion perturbed as an on-board guess would be: 5 cm
    sideways and 0.02 deg (the star tracker's attitude; the EKF's measured error over
    vo-study's motions is 0.001-0.05 deg)."""
    from lunar_drake.perception.ground_pipeline import PerceptionConfig
    from lunar_drake.perception.stereo import match
    from lunar_drake.perception.vo import ViewFrustum, align, correction

    left, right, _, _, X_WC1 = render_pair(scen, site, yaw_deg=yaw, forward_m=step)
    res1 = match(left, right, calib=calib, config=config)
    ground = PerceptionConfig()

    def near(r):
        c, g = r.cloud(), r.cloud_intensity()
        keep = c[:, 2] <= ground.max_range_m
        return c[keep], g[keep]

    T_true = np.linalg.inv(X_WC0) @ X_WC1
    guess = T_true.copy()
    c, s_ = math.cos(math.radians(0.02)), math.sin(math.radians(0.02))
    guess[:3, :3] = guess[:3, :3] @ np.array([[c, 0, s_], [0, 1, 0], [-s_, 0, c]])
    guess[:3, 3] += [0.05, 0.0, 0.0]
    t0 = time.perf_counter()
    (p0, g0), (p1, g1) = near(res0), near(res1)
    frustum = ViewFrustum.from_calibration(calib, max_range_m=ground.max_range_m)
    al = align(p0, p1, init_T=guess, prev_intensity=g0, curr_intensity=g1, config=ground.vo,
               frustum=frustum)  # fmt: skip
    dt, dr = correction(T_true, al.T_prev_curr)
    g_dt, g_dr = correction(T_true, guess)
    return {"step_m": step, "vo_error_m": dt, "vo_error_deg": dr, "guess_error_m": g_dt,
            "guess_error_deg": g_dr, "fitness": al.fitness, "inlier_rmse_m": al.inlier_rmse_m,
            "condition": al.condition, "rejected": al.rejected, "reason": al.reason,
            "icp_s": time.perf_counter() - t0}  # fmt: skip


def _write_images(out: Path, stem: str, preview, res, depth) -> None:
    import cv2

    out.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out / f"{stem}_left.png"), np.asarray(preview))
    d = np.nan_to_num(res.disparity, nan=0.0)
    d8 = np.clip(255.0 * d / max(res.num_disparities, 1), 0, 255).astype(np.uint8)
    cv2.imwrite(str(out / f"{stem}_disparity.png"), cv2.applyColorMap(d8, cv2.COLORMAP_TURBO))
    t = np.asarray(depth, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        err = np.abs(res.depth_m - t) / t
    e8 = np.where(np.isfinite(err), np.clip(err / 0.1 * 255.0, 0, 255), 0).astype(np.uint8)
    cv2.imwrite(str(out / f"{stem}_error.png"), cv2.applyColorMap(e8, cv2.COLORMAP_INFERNO))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks import run_main

    run_main(main, "stereo.py")
