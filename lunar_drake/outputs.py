"""Writing a run directory from a simulation's logs and summary.

A run directory holds ``scenario.yaml`` (the resolved scenario: ``lunar-drake run
--scenario RUN/scenario.yaml`` reproduces the run), ``summary.json`` (deterministic),
``timing.json`` (wall-clock figures), the CSV logs in :data:`LOG_FILES` (``power.csv``:
the solar array, loads and battery, with ``power.enabled``),
``telemetry.csv`` (what the ground received), ``link.csv`` (every message over the
link), ``modes.csv`` (every on-board mode change), ``ground_events.csv`` (what the
ground did and saw: goals, plans, safings, resumes), ``images.csv`` (the stereo frames
the ground received, compressed), ``keyframes.csv`` (the ground's stereo / VO /
mapping keyframes; with ground perception), ``keyframe_points.npy`` (the points the
ground mapped from each keyframe, in its own site frame: :data:`KEYFRAME_POINTS_DTYPE`;
with ground perception and ``cloud_voxel_m`` > 0), ``nss.csv`` and ``nss_map.png`` (the
neutron spectrometer's records as the ground received them and its hydrogen map; with
``sensors.nss``), ``nirvss.csv`` and ``lcs.csv`` (NIRVSS band depths and the LCS
temperature as received; with ``sensors.nirvss``), ``drill.csv`` (drill samples read
by NIRVSS; with ``sensors.drill``), ``ground_map.png`` (the ground's final
costmap round the traverse: :mod:`lunar_drake.ground_map`), ``calibration.yaml`` (the
stereo rig, OpenCV style; with the cameras on), ``run.mcap`` (the run for Foxglove:
:mod:`lunar_drake.mission_control.recording`), ``frames/`` (written during the
simulation) and ``meshcat.html`` (with Meshcat).
The CLI builds it in a temporary sibling directory and swaps it in when complete
(:func:`lunar_drake.files.staged_directory`).
"""

from __future__ import annotations

import dataclasses as dc
import json
import math
from pathlib import Path

import numpy as np

from lunar_drake.comms.link import LINK_RECORD_FIELDS
from lunar_drake.files import atomic_path, atomic_write_text
from lunar_drake.scenario import Scenario
from lunar_drake.scenario_files import dump_scenario
from lunar_drake.simulation import SimulationLogs

#: Logged port -> CSV file (columns: ``t_s`` then the port's columns; a port the run did
#: not log -- ``truth.power`` with ``power.enabled`` false -- writes no file).
LOG_FILES = {
    "truth.pose": "truth.csv",
    "truth.wheel_state": "wheels.csv",
    "truth.drive_energy": "energy.csv",
    "truth.imu_bias": "imu_bias.csv",
    "truth.power": "power.csv",
    "rover.imu": "imu.csv",
    "rover.star_tracker": "star_tracker.csv",
    "rover.wheel_encoders": "encoders.csv",
    "flight.twist_command": "twist_command.csv",
    "flight.brake_command": "brakes.csv",
    "flight.status": "flight_status.csv",
    "flight.pose_estimate": "pose_estimate.csv",
    "flight.pose_covariance": "pose_covariance.csv",
    "flight.bumper": "bumper.csv",
    "ground.pose_estimate": "ground_pose.csv",
}


#: Everything a run directory may hold (a rerun may replace a directory holding only these).
#: The science files a run writes when its instruments are on.
SCIENCE_FILES = (
    "nss.csv", "nss_map.png", "nss_map.tif", "nirvss.csv", "nirvss_map.png", "nirvss_map.tif",
    "lcs.csv", "lcs_map.png", "lcs_map.tif", "drill.csv",
)

RUN_DIR_NAMES = frozenset(
    [
        "scenario.yaml",
        "summary.json",
        "timing.json",
        *LOG_FILES.values(),
        "telemetry.csv",
        "link.csv",
        "modes.csv",
        "ground_events.csv",
        "images.csv",
        "keyframes.csv",
        "keyframe_points.npy",
        *SCIENCE_FILES,
        "ground_map.png",
        "calibration.yaml",
        "run.mcap",
        "frames",
        "meshcat.html",
    ]
)


#: ``keyframe_points.npy`` (a NumPy ``.npy`` file of one structured array, keyframe after
#: keyframe): the keyframe's ``frame_index`` and one point the ground mapped from it
#: (``x``, ``y``, ``z``; m, float32, the site frame placed with the ground's estimate
#: ``X_WC_ground``, never truth; one per ``ground.perception.cloud_voxel_m`` voxel).
KEYFRAME_POINTS_DTYPE = np.dtype([("frame_index", "<i4"), ("x", "<f4"), ("y", "<f4"),
                                  ("z", "<f4")])  # fmt: skip


def write_keyframe_points(path: str | Path, *, clouds) -> Path:
    """Writes ``clouds`` (:class:`~lunar_drake.perception.ground_pipeline.KeyframeCloud`
    each) to ``path`` atomically as :data:`KEYFRAME_POINTS_DTYPE` rows (``.npy``: no
    timestamps, the same clouds give the same bytes); returns ``path``."""
    rows = np.empty(sum(len(c.points_W) for c in clouds), KEYFRAME_POINTS_DTYPE)
    i = 0
    for c in clouds:
        p = np.asarray(c.points_W, np.float32).reshape(-1, 3)
        rows["frame_index"][i : i + len(p)] = int(c.frame_index)
        for k, name in enumerate("xyz"):
            rows[name][i : i + len(p)] = p[:, k]
        i += len(p)
    with atomic_path(path, what="keyframe points") as tmp, open(tmp, "wb") as f:
        np.save(f, rows, allow_pickle=False)
    return Path(path)


def _fmt(v) -> str:
    return f"{v:.9g}"


def write_csv(path: Path, header, rows) -> None:
    """Writes a CSV atomically: ``header`` (names) then ``rows`` (lists of strings)."""
    with atomic_path(path, what="log") as tmp, open(tmp, "w") as f:
        f.write(",".join(header) + "\n")
        for row in rows:
            f.write(",".join(row) + "\n")


def _quote(text: str) -> str:
    """A CSV field: quoted (doubling quotes) when it holds a comma or a quote."""
    if "," in text or '"' in text:
        return '"' + text.replace('"', '""') + '"'
    return text


#: ``nss.csv`` columns: reception and sample times (s), the sample index, epithermal and
#: thermal counts over ``integration_s`` (s), the on-board pose estimate at the sample
#: (m, m, rad) and the ground's water-equivalent hydrogen from the epithermal counts
#: (wt%; :func:`lunar_drake.science.nss.weh_from_epithermal`).
NSS_COLUMNS = ["t_received_s", "t_sample_s", "index", "epithermal_counts", "thermal_counts",
               "integration_s", "x_est_m", "y_est_m", "yaw_est_rad", "weh_est_wt_pct"]  # fmt: skip


#: ``nirvss.csv`` columns: times (s), index, the band depths (-) of
#: :data:`lunar_drake.science.nirvss.BANDS`, the on-board pose estimate (m, m, rad).
#: ``lcs.csv``: times, index, the LCS surface temperature (K), the estimate (m, m, rad).
def _nirvss_columns() -> list[str]:
    from lunar_drake.science.nirvss import BANDS

    return ["t_received_s", "t_sample_s", "index", *(f"bd_{b}" for b in BANDS), "x_est_m",
            "y_est_m", "yaw_est_rad"]  # fmt: skip


LCS_COLUMNS = ["t_received_s", "t_sample_s", "index", "temperature_K", "x_est_m", "y_est_m",
               "yaw_est_rad"]  # fmt: skip
#: ``drill.csv``: reception and sample times (s), the sample number, its depth (m), its
#: NIRVSS ice band depth (-), the ground's ice from it (wt%), the on-board estimate of
#: the chassis (m, m, rad) and of the hole (``sensors.drill.x_m`` ahead of it, m).
DRILL_COLUMNS = ["t_received_s", "t_sample_s", "sample", "depth_m", "bd_ice", "ice_est_wt_pct",
                 "x_est_m", "y_est_m", "yaw_est_rad", "hole_x_est_m", "hole_y_est_m"]  # fmt: skip


def write_science(out: Path, *, scenario: Scenario, logs: SimulationLogs,
                  site=None) -> list[Path]:  # fmt: skip
    """``nss.csv`` and ``nss_map.png``, ``nirvss.csv`` and ``lcs.csv`` from the records
    the ground received (each only when its instrument is carried), and the maps of
    :func:`lunar_drake.science.products.science_maps` (GeoTIFFs need ``site``)."""
    from lunar_drake.science.products import science_maps

    paths = []
    if scenario.sensors.drill.enabled:
        k_ice = scenario.sensors.nirvss.ice_per_wt_pct
        hole = scenario.sensors.drill.x_m
        rows = ([f"{t:.6f}", f"{r.t_sample_s:.6f}", str(int(r.values[0])), _fmt(r.values[1]),
                 _fmt(r.values[2]), _fmt(r.values[2] / k_ice if k_ice > 0 else math.nan),
                 *(_fmt(r.pose_estimate[i]) for i in (0, 1, 5)),
                 _fmt(r.pose_estimate[0] + hole * math.cos(r.pose_estimate[5])),
                 _fmt(r.pose_estimate[1] + hole * math.sin(r.pose_estimate[5]))]
                for t, r in logs.science_received if r.instrument == "drill")  # fmt: skip
        write_csv(out / "drill.csv", DRILL_COLUMNS, rows)
        paths.append(out / "drill.csv")
    if scenario.sensors.nirvss.enabled:
        nir = [(t, r) for t, r in logs.science_received if r.instrument == "nirvss"]
        rows = ([f"{t:.6f}", f"{r.t_sample_s:.6f}", str(r.index), *(_fmt(v) for v in r.values[:-1]),
                 _fmt(r.pose_estimate[0]), _fmt(r.pose_estimate[1]), _fmt(r.pose_estimate[5])]
                for t, r in nir)  # fmt: skip
        write_csv(out / "nirvss.csv", _nirvss_columns(), rows)
        rows = ([f"{t:.6f}", f"{r.t_sample_s:.6f}", str(r.index), _fmt(r.values[-1]),
                 *(_fmt(r.pose_estimate[i]) for i in (0, 1, 5))] for t, r in nir)  # fmt: skip
        write_csv(out / "lcs.csv", LCS_COLUMNS, rows)
        paths += [out / "nirvss.csv", out / "lcs.csv"]
    if scenario.sensors.nss.enabled:
        paths += _write_nss(out, scenario=scenario, logs=logs)
    return paths + science_maps(out, scenario=scenario, logs=logs, site=site)


def _write_nss(out: Path, *, scenario: Scenario, logs: SimulationLogs) -> list[Path]:
    from lunar_drake.science.nss import weh_from_epithermal

    cfg = scenario.sensors.nss
    rows = []
    for t_rx, r in logs.science_received:
        if r.instrument != "nss":
            continue
        epi, th = r.values
        weh = float(weh_from_epithermal(epi, r.integration_s, config=cfg))
        p = r.pose_estimate
        rows.append([f"{t_rx:.6f}", f"{r.t_sample_s:.6f}", str(r.index), f"{epi:.0f}",
                     f"{th:.0f}", _fmt(r.integration_s), _fmt(p[0]), _fmt(p[1]), _fmt(p[5]),
                     _fmt(weh)])  # fmt: skip
    write_csv(out / "nss.csv", NSS_COLUMNS, rows)
    return [out / "nss.csv"]


def run_files() -> list[str]:
    """The files :func:`write_run` writes (frames and Meshcat aside)."""
    return [
        "scenario.yaml",
        "summary.json",
        "timing.json",
        *LOG_FILES.values(),
        "telemetry.csv",
        "link.csv",
        "modes.csv",
        "ground_events.csv",
        "images.csv",
        "run.mcap",
    ]


def write_run_summary(out_dir: str | Path, *, scenario: Scenario, summary: dict,
                      timing: dict) -> list[Path]:  # fmt: skip
    """Writes a run's ``scenario.yaml``, ``summary.json`` and ``timing.json`` into
    ``out_dir`` (atomically each); the part of :func:`write_run` a study keeps per case."""
    out = Path(out_dir)
    return [
        atomic_write_text(out / "scenario.yaml", dump_scenario(scenario)),
        atomic_write_text(
            out / "summary.json", json.dumps(summary, indent=2, sort_keys=True) + "\n"
        ),
        atomic_write_text(out / "timing.json", json.dumps(timing, indent=2, sort_keys=True) + "\n"),
    ]


def write_run(
    out_dir: str | Path,
    *,
    scenario: Scenario,
    logs: SimulationLogs,
    summary: dict,
    timing: dict,
    meshcat_html: str | None = None,
    site=None,
) -> list[Path]:
    """Writes the run directory's files into ``out_dir`` (which must exist); returns
    their paths. ``site`` (the run's SiteData) puts the science maps over the site
    hillshade and writes them as GeoTIFFs."""
    out = Path(out_dir)
    paths = write_run_summary(out, scenario=scenario, summary=summary, timing=timing)
    for port, name in LOG_FILES.items():
        if port not in logs.vectors:
            continue
        log = logs.vectors[port]
        rows = (
            [f"{t:.6f}", *(_fmt(v) for v in row)]
            for t, row in zip(log.times, log.data, strict=True)
        )
        write_csv(out / name, ["t_s", *log.columns], rows)
        paths.append(out / name)
    tel = logs.telemetry
    rows = (
        [f"{tr:.6f}", f"{ts:.6f}", str(int(s)), *(_fmt(v) for v in p)]
        for tr, ts, s, p in zip(tel.t_received, tel.t_sent, tel.seq, tel.packets, strict=True)
    )
    write_csv(out / "telemetry.csv", ["t_received_s", "t_sent_s", "seq", *tel.columns], rows)
    paths.append(out / "telemetry.csv")
    rows = (
        [
            r.direction,
            r.channel,
            r.topic,
            str(r.seq),
            str(r.bytes),
            f"{r.t_sent:.6f}",
            f"{r.t_received:.6f}" if math.isfinite(r.t_received) else "",
            "1" if r.dropped else "0",
        ]
        for r in logs.link
    )
    write_csv(out / "link.csv", LINK_RECORD_FIELDS, rows)
    paths.append(out / "link.csv")
    rows = ([f"{m.t_s:.6f}", m.before, m.after, m.reason] for m in logs.transitions)
    write_csv(out / "modes.csv", ["t_s", "before", "after", "reason"], rows)
    paths.append(out / "modes.csv")
    rows = ([f"{e.t_s:.6f}", e.kind, _quote(e.detail)] for e in logs.ground_events)
    write_csv(out / "ground_events.csv", ["t_s", "event", "detail"], rows)
    paths.append(out / "ground_events.csv")
    rows = (
        [f"{tr:.6f}", f"{ts:.6f}", str(int(k)), codec, str(int(n))]
        for tr, ts, k, codec, n in logs.images_received
    )
    write_csv(out / "images.csv", ["t_received_s", "t_sent_s", "frame_index", "codec", "bytes"],
              rows)  # fmt: skip
    paths.append(out / "images.csv")
    if logs.science_received:
        paths += write_science(out, scenario=scenario, logs=logs, site=site)
    if logs.keyframes:
        from lunar_drake.perception.ground_pipeline import KeyframeRecord

        names = [f.name for f in dc.fields(KeyframeRecord)]
        rows = (
            [_quote(v) if isinstance(v, str) else _fmt(v) for v in dc.astuple(r)]
            for r in logs.keyframes
        )
        write_csv(out / "keyframes.csv", names, rows)
        paths.append(out / "keyframes.csv")
    if getattr(logs, "keyframe_clouds", None):
        paths.append(write_keyframe_points(out / "keyframe_points.npy",
                                           clouds=logs.keyframe_clouds))  # fmt: skip
    if getattr(logs, "ground_costmap", None) is not None:
        from lunar_drake.ground_map import write_ground_map

        paths.append(write_ground_map(out / "ground_map.png", logs=logs, scenario=scenario))
    if scenario.sensors.camera.enabled:
        from lunar_drake.perception.calibration import StereoCalibration

        StereoCalibration.from_camera(
            camera=scenario.sensors.camera, description=scenario.rover.description
        ).write(out / "calibration.yaml")
        paths.append(out / "calibration.yaml")
    from lunar_drake.mission_control.recording import write_run_mcap

    paths.append(write_run_mcap(out, costmap=logs.ground_costmap,
                                prior_costmap=logs.ground_prior_costmap))  # fmt: skip
    if meshcat_html is not None:
        paths.append(atomic_write_text(out / "meshcat.html", meshcat_html))
    return paths
