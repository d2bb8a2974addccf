"""A finished run directory as mission control serves it (``lunar-drake serve RUN``):
the telemetry, pose, event and science datums the live mission published, rebuilt from
what the ground received (``telemetry.csv``, ``ground_pose.csv``, ``ground_events.csv``,
``nss.csv``, ``nirvss.csv``, ``lcs.csv``; not the mission clock, the goal counts or the
loss-of-signal caution, which a live mission publishes as it goes)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from lunar_drake.mission_control import dictionary as dic


def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def run_datums(run_dir: str | Path, *, telemetry_period_s: float = 1.0,
               min_soc: float = 0.2) -> list:  # fmt: skip
    """Every datum of a run directory, in time order."""
    d = Path(run_dir)
    conv = dic.Converter(telemetry_period_s=telemetry_period_s, min_soc=min_soc)
    out = []
    fields = dic.TELEMETRY_FIELDS
    for r in _rows(d / "telemetry.csv"):
        packet = np.array([float(r[f]) for f in fields])
        out += conv.packet(seq=int(r["seq"]), t_sent=float(r["t_sent_s"]),
                           t_received=float(r["t_received_s"]), packet=packet)  # fmt: skip
    last = -math.inf
    for r in _rows(d / "ground_pose.csv"):
        t = float(r["t_s"])
        if t - last >= 0.5 - 1e-9:
            last = t
            pose = [float(r[k]) for k in ("x_m", "y_m", "z_rel_m", "roll_rad", "pitch_rad",
                                          "yaw_rad")]  # fmt: skip
            out += dic.ground_pose_datums(t, pose)
    for r in _rows(d / "ground_events.csv"):
        text = r["event"] + (f": {r['detail']}" if r["detail"] else "")
        out.append(("ground.event", float(r["t_s"]), text))
    for r in _rows(d / "nss.csv"):
        t = float(r["t_received_s"])
        out += [("nss.weh", t, float(r["weh_est_wt_pct"])),
                ("nss.epithermal", t, float(r["epithermal_counts"])),
                ("nss.thermal", t, float(r["thermal_counts"]))]  # fmt: skip
    lcs = _rows(d / "lcs.csv")
    for r, c in zip(_rows(d / "nirvss.csv"), lcs, strict=False):
        t = float(r["t_received_s"])
        out += [("nirvss.ice", t, float(r["bd_ice"])), ("nirvss.oh", t, float(r["bd_oh"])),
                ("lcs.temperature", t, float(c["temperature_K"]))]  # fmt: skip
    out.sort(key=lambda d: d[1])
    return out


def load_run(mc, run_dir: str | Path) -> None:
    """Fills the :class:`~lunar_drake.mission_control.server.MissionControl` ``mc`` with
    the run in ``run_dir`` (its scenario, datums, goals, science samples and the
    ground's a-priori map as a hillshade)."""
    from lunar_drake.mission_control.live import hillshade_u8, png_bytes
    from lunar_drake.mission_control.recording import check_run_dir
    from lunar_drake.scenario_files import load_scenario

    d = check_run_dir(run_dir)
    sc = load_scenario(filename=d / "scenario.yaml")
    summary = json.loads((d / "summary.json").read_text()) if (d / "summary.json").is_file() else {}
    site = {"kind": "site", "epoch_utc": sc.site.epoch_utc, "name": sc.name or d.name,
            "duration_s": float(summary.get("simulated_s", sc.simulation_duration)),
            "spawn_xy": [sc.rover.spawn_x_m, sc.rover.spawn_y_m], "live": False,
            "run_dir": str(d.resolve())}  # fmt: skip
    try:
        from lunar_drake import preflight
        from lunar_drake.site import load_site

        mp = preflight.ground_map_product(sc, load_site(sc, progress=False))
        site["map_source"] = mp.source
        site["extent_m"] = [mp.x0_m, mp.x0_m + mp.shape[1] * mp.resolution_m,
                            mp.y1_m - mp.shape[0] * mp.resolution_m, mp.y1_m]  # fmt: skip
        site["hillshade_png"] = png_bytes(hillshade_u8(mp.z, mp.resolution_m))
    except Exception as exc:  # a site that cannot be rebuilt: telemetry still serves
        site["map_error"] = f"no map: {exc}"
    mc.set_site(site)
    mc.info["state"] = "replay"
    mc.store.add(run_datums(d, telemetry_period_s=1.0 / sc.flight.telemetry_rate_hz,
                           min_soc=sc.flight.safety.min_soc))  # fmt: skip
    goals = summary.get("ground", {}).get("goals", [])
    mc.store.map.goals = [[*g["goal_xy_m"], g.get("status", "")] for g in goals
                          if len(g.get("goal_xy_m") or ()) == 2]  # fmt: skip
    heat = mc.store.map.science
    xy = lambda r: [float(r["x_est_m"]), float(r["y_est_m"])]  # noqa: E731
    if rows := _rows(d / "nss.csv"):
        heat["nss_weh"] = [[*xy(r), float(r["weh_est_wt_pct"])] for r in rows]
    if rows := _rows(d / "nirvss.csv"):
        heat["nirvss_ice"] = [[*xy(r), float(r["bd_ice"])] for r in rows]
    if rows := _rows(d / "lcs.csv"):
        heat["lcs_temperature"] = [[*xy(r), float(r["temperature_K"])] for r in rows]
