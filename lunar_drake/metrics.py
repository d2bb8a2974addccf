"""Pure functions from a simulation's logs (numpy arrays) to its summary (no files).

Every number is rounded to a fixed number of decimals, so ``summary.json`` is
byte-identical for the same scenario and seed.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from lunar_drake.comms.link import DROP_REASONS
from lunar_drake.scenario import Scenario
from lunar_drake.simulation import SimulationLogs
from lunar_drake.site import SiteData
from lunar_drake.systems.wheel_regolith_contact import WHEEL_STATE_FIELDS

MIN_RATE_DISTANCE_M = 1.0
"""Below this traverse (m) the per-metre figures (``error_per_distance``, ``Wh_per_m``)
are None: divided by a few millimetres of creep they say nothing."""


def _r(x, nd: int = 6):
    return round(float(x), nd)


def traverse(logs: SimulationLogs) -> dict:
    """The rover's traverse from ground truth: distance (m), final pose (x, y, z m;
    roll, pitch, yaw rad), maximum tilt (deg), maximum sinkage (m), mean slip while
    moving, drive energy (J)."""
    pose = logs.vectors["truth.pose"].data
    ws = logs.vectors["truth.wheel_state"].data
    energy = logs.vectors["truth.drive_energy"].data[:, 0]
    nf = len(WHEEL_STATE_FIELDS)
    xy = pose[:, :2]
    dist = float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1))) if len(xy) > 1 else 0.0
    slip = ws[:, WHEEL_STATE_FIELDS.index("slip") :: nf]
    sink = ws[:, WHEEL_STATE_FIELDS.index("sinkage_m") :: nf]
    moving = np.abs(pose[:, 6]) + np.abs(pose[:, 7]) > 0.02
    return {
        "distance_m": _r(dist),
        "final_pose": [_r(v) for v in pose[-1, :6]] if len(pose) else [],
        "max_tilt_deg": _r(np.degrees(np.max(np.hypot(pose[:, 3], pose[:, 4]))), 4)
        if len(pose)
        else 0.0,
        "max_sinkage_m": _r(np.max(sink)) if sink.size else 0.0,
        "mean_slip_moving": _r(np.mean(slip[moving])) if moving.any() else 0.0,
        "energy_J": _r(energy[-1], 4) if len(energy) else 0.0,
    }


def parked_drift(logs: SimulationLogs, *, settle_s: float = 2.0) -> dict | None:
    """How far the rover moved while parked with its brakes on after its last drive:
    from ``settle_s`` after the brakes engaged to the end (m, deg), or None when it never
    parked after driving for that long."""
    brake = logs.vectors["flight.brake_command"]
    twist = logs.vectors["flight.twist_command"].data
    pose = logs.vectors["truth.pose"]
    on = brake.data[:, 0] > 0.5
    drove = np.flatnonzero(np.any(twist != 0.0, axis=1))
    if not len(drove) or not on[-1]:
        return None
    # The last stretch of braking after the last drive command.
    k = int(drove[-1])
    rest = np.flatnonzero(~on[k:])
    start = k + (int(rest[-1]) + 1 if len(rest) else 0)
    t0 = brake.times[start] + settle_s
    i0 = int(np.searchsorted(pose.times, t0))
    if i0 >= len(pose.times) - 1:
        return None
    p = pose.data
    return {
        "from_s": _r(pose.times[i0], 3),
        "duration_s": _r(pose.times[-1] - pose.times[i0], 3),
        "drift_m": _r(np.linalg.norm(p[-1, :2] - p[i0, :2])),
        "yaw_change_deg": _r(np.degrees(np.angle(np.exp(1j * (p[-1, 5] - p[i0, 5])))), 4),
    }


#: The 95 % interval of a chi-square variable with 2 degrees of freedom.
CHI2_2DOF_95 = (0.0506356, 7.3777589)


def position_nees(logs: SimulationLogs) -> dict | None:
    """The on-board estimate's horizontal position (x, y) NEES over the run, scored on
    truth: ``e^T C^-1 e`` per logged sample (e the true minus the estimated position, m;
    C the EKF's 2 x 2 position covariance, m^2), the first sample (before any filter
    update) left out. ``mean`` is 2 for a consistent filter (below: too pessimistic,
    above: overconfident); ``inside_95`` the fraction of samples inside the 2-dof 95 %
    chi-square interval :data:`CHI2_2DOF_95`; ``final``: the last sample's. None without
    a covariance log."""
    cov = logs.vectors.get("flight.pose_covariance")
    est = logs.vectors.get("flight.pose_estimate")
    pose = logs.vectors["truth.pose"].data
    if cov is None or est is None or len(cov.data) < 2 or len(pose) < 2:
        return None
    n = min(len(cov.data), len(est.data), len(pose))
    C = cov.data[1:n].reshape(-1, 6, 6)[:, :2, :2]
    e = pose[1:n, :2] - est.data[1:n, :2]
    nees = np.einsum("ki,ki->k", e, np.linalg.solve(C, e[:, :, None])[:, :, 0])
    lo, hi = CHI2_2DOF_95
    return {
        "mean": _r(float(nees.mean()), 4),
        "inside_95": _r(float(np.mean((nees > lo) & (nees < hi))), 4),
        "final": _r(float(nees[-1]), 4),
    }


def localization(logs: SimulationLogs) -> dict:
    """The on-board estimate against truth: at the end, the horizontal position error (m),
    its ratio to the distance driven (None under :data:`MIN_RATE_DISTANCE_M`), the
    heading error (deg) and the estimate's own 1 sigma; over the run, the EKF's
    normalized estimation error squared (NEES, 6 dof: position with z relative to the
    start, world-frame attitude error) -- its mean and
    the fraction of samples inside the 95 % chi-square interval (1.24, 14.45); and the
    horizontal position's own NEES (:func:`position_nees`, 2 dof)."""
    from lunar_drake.autonomy.ekf import so3_log
    from lunar_drake.rotations import rotation_matrix_from_rpy

    est = logs.vectors["flight.pose_estimate"]
    pose = logs.vectors["truth.pose"].data
    if not len(pose):
        return {}
    e = est.data[-1]
    err = float(np.linalg.norm(e[:2] - pose[-1, :2]))
    yaw_err = float(np.degrees(np.angle(np.exp(1j * (e[5] - pose[-1, 5])))))
    dist = traverse(logs)["distance_m"]
    out = {
        "final_position_error_m": _r(err),
        "error_per_distance": _r(err / dist) if dist >= MIN_RATE_DISTANCE_M else None,
        "final_heading_error_deg": _r(yaw_err, 4),
    }
    cov = logs.vectors.get("flight.pose_covariance")
    if cov is None or not len(cov.data):
        return out
    C = cov.data.reshape(-1, 6, 6)
    out["final_position_sigma_m"] = _r(math.sqrt(C[-1, 0, 0] + C[-1, 1, 1]))
    out["final_heading_sigma_deg"] = _r(math.degrees(math.sqrt(C[-1, 5, 5])), 4)
    nees = []
    for k in range(1, len(C)):  # sample 0 precedes the first filter update
        d = np.empty(6)
        d[:2] = pose[k, :2] - est.data[k, :2]
        d[2] = (pose[k, 2] - pose[0, 2]) - est.data[k, 2]
        R_t = rotation_matrix_from_rpy(pose[k, 3:6])
        R_e = rotation_matrix_from_rpy(est.data[k, 3:6])
        d[3:] = so3_log(R_t @ R_e.T)
        nees.append(float(d @ np.linalg.solve(C[k], d)))
    if nees:
        n = np.array(nees)
        out["nees_mean"] = _r(float(n.mean()), 4)
        out["nees_inside_95"] = _r(float(np.mean((n > 1.2373) & (n < 14.4494))), 4)
    out["position_nees"] = position_nees(logs)
    return out


def goals(*, scenario: Scenario, logs: SimulationLogs) -> list:
    """Per operator goal (``ground.goals``), scored on truth: the closest the chassis came
    (m, horizontal) and when (s); ``reached``: the last goal when the *final* true
    position is within ``ground.goal_tolerance_m`` (``final_distance_m``), an earlier
    goal when the closest approach is."""
    pose = logs.vectors["truth.pose"]
    if not scenario.ground.goals or not len(pose.times):
        return []
    tol = scenario.ground.goal_tolerance_m
    out = []
    last = len(scenario.ground.goals) - 1
    for k, g in enumerate(scenario.ground.goals):
        d = np.hypot(pose.data[:, 0] - g.x_m, pose.data[:, 1] - g.y_m)
        i = int(np.argmin(d))
        row = {
            "goal_xy_m": [g.x_m, g.y_m],
            "closest_m": _r(float(d[i])),
            "closest_at_s": _r(float(pose.times[i]), 3),
        }
        if k == last:
            row["final_distance_m"] = _r(float(d[-1]))
            row["reached"] = bool(d[-1] <= tol)
        else:
            row["reached"] = bool(d[i] <= tol)
        out.append(row)
    return out


#: Penetration (m) of the terrain into the chassis underside that counts as a strike
#: (the belly contact is a stiff penalty: a resting belly sinks a few millimetres).
BELLY_STRIKE_M = 0.01
#: Commanded but not moving (truth speed below 1 cm/s) for this long (s): immobilized.
IMMOBILIZED_S = 10.0


def hazards(*, scenario: Scenario, site: SiteData, logs: SimulationLogs) -> dict:
    """Hazard strikes on truth: ``belly`` (the true terrain, rocks included, more than
    :data:`BELLY_STRIKE_M` above the chassis underside anywhere on a 7 x 5 grid over the
    chassis footprint), ``tilt`` (roll or pitch beyond the rover's
    ``max_rated_slope_deg``), ``immobilized`` (commanded to move but slower than 1 cm/s
    for :data:`IMMOBILIZED_S`); each counted as events (entries into the state), at the
    log period; ``strikes`` is their sum."""
    from lunar_drake.rotations import rotation_matrix_from_rpy

    pose = logs.vectors["truth.pose"]
    d = scenario.rover.description
    if not len(pose.times):
        return {"strikes": 0, "belly": 0, "tilt": 0, "immobilized": 0}
    gx, gy = np.meshgrid(
        np.linspace(-0.5, 0.5, 7) * d.chassis_length_m,
        np.linspace(-0.5, 0.5, 5) * d.chassis_width_m,
    )
    under_C = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, -0.5 * d.chassis_height_m)])
    hf = site.heightfield
    belly = np.zeros(len(pose.times), bool)
    for k, row in enumerate(pose.data):
        p_W = row[:3] + under_C @ rotation_matrix_from_rpy(row[3:6]).T
        z, ok = hf.heights_within(p_W[:, 0], p_W[:, 1])
        belly[k] = bool(np.any(ok & (z - p_W[:, 2] > BELLY_STRIKE_M)))
    limit = math.radians(d.max_rated_slope_deg)
    tilt = (np.abs(pose.data[:, 3]) > limit) | (np.abs(pose.data[:, 4]) > limit)
    twist = logs.vectors["flight.twist_command"]
    cmd = np.interp(pose.times, twist.times, np.abs(twist.data).max(axis=1)) > 0.0
    slow = np.hypot(pose.data[:, 6], pose.data[:, 7]) < 0.01
    stuck = np.zeros(len(pose.times), bool)
    since = None
    for k, t in enumerate(pose.times):
        if cmd[k] and slow[k]:
            since = t if since is None else since
            stuck[k] = t - since >= IMMOBILIZED_S
        else:
            since = None

    def events(a):
        return int(np.sum(a[1:] & ~a[:-1]) + (1 if a[0] else 0))

    out = {"belly": events(belly), "tilt": events(tilt), "immobilized": events(stuck)}
    out["strikes"] = sum(out.values())
    return out


def power(logs: SimulationLogs) -> dict | None:
    """The power system over the run, from the logged ``truth.power`` (``power.csv``),
    each sample held until the next (a left Riemann sum over the log):
    ``energy_generated_Wh`` (the array), ``energy_used_Wh`` (the loads), ``min_soc`` and
    ``final_soc``, ``shadow_s`` (time with no direct sunlight on the panel: visible
    fraction 0 or incidence >= 90 deg) and ``Wh_per_m`` (energy used per metre driven,
    None under :data:`MIN_RATE_DISTANCE_M` of traverse). None when the run has no power system."""
    log = logs.vectors.get("truth.power")
    if log is None or not len(log.times):
        return None
    dt = np.diff(log.times)
    incidence, fraction, array_W, load_W, soc = (log.column(c) for c in log.columns)
    dark = (fraction <= 0.0) | (incidence >= 90.0)
    generated = float(np.sum(array_W[:-1] * dt)) / 3600.0
    used = float(np.sum(load_W[:-1] * dt)) / 3600.0
    dist = traverse(logs)["distance_m"]
    return {
        "energy_generated_Wh": _r(generated),
        "energy_used_Wh": _r(used),
        "min_soc": _r(np.min(soc)),
        "final_soc": _r(soc[-1]),
        "shadow_s": _r(float(np.sum(dt[dark[:-1]])), 3),
        "Wh_per_m": _r(used / dist) if dist >= MIN_RATE_DISTANCE_M else None,
    }


def link_stats(logs: SimulationLogs) -> dict:
    """Per direction: messages and bytes offered, delivered, still in flight, dropped
    (and why), and the delivery latency of what was delivered (``latency_s``: ``min``,
    ``median``, ``max``, s from sending to receipt; None when nothing was)."""
    out = {}
    for direction in ("uplink", "downlink"):
        rows = [r for r in logs.link if r.direction == direction]
        got = [r for r in rows if np.isfinite(r.t_received)]
        lat = [r.t_received - r.t_sent for r in got]
        out[direction] = {
            "messages": len(rows),
            "bytes": int(sum(r.bytes for r in rows)),
            "delivered": len(got),
            "in_flight_at_end": sum(1 for r in rows if not r.dropped) - len(got),
            "dropped": sum(1 for r in rows if r.dropped),
            "dropped_by_reason": {
                k: n for k in DROP_REASONS if (n := sum(1 for r in rows if r.reason == k))
            },
            "latency_s": (
                {"min": _r(min(lat)), "median": _r(float(np.median(lat))), "max": _r(max(lat))}
                if lat
                else None
            ),
        }
    return out


def modes(logs: SimulationLogs) -> dict:
    """On-board mode changes: ``count``, ``safings`` by reason and every ``transitions``
    entry (t_s, before, after, reason); ``seen_by_ground``: the mode changes the newest
    received telemetry packet counted."""
    safings = {}
    for m in logs.transitions:
        if m.after == "safed":
            safings[m.reason] = safings.get(m.reason, 0) + 1
    tel = logs.telemetry
    seen = int(tel.packets[-1, tel.columns.index("mode_changes")]) if len(tel.seq) else 0
    return {
        "count": len(logs.transitions),
        "safings": safings,
        "seen_by_ground": seen,
        "transitions": [
            {"t_s": _r(m.t_s, 3), "before": m.before, "after": m.after, "reason": m.reason}
            for m in logs.transitions
        ],
    }


def ground(logs: SimulationLogs) -> dict:
    """The ground's own account: each goal it was given and its status as the ground
    judged it from telemetry; when it had judged them all (``goals_judged_s``, None
    while any is open); counts of plans, replans and resumes."""
    kinds = [e.kind for e in logs.ground_events]
    judged = [e.t_s for e in logs.ground_events if e.kind in ("goal_reached", "goal_failed")]
    done = bool(logs.ground_goals) and len(judged) >= len(logs.ground_goals)
    return {
        "goals": [{"goal_xy_m": [_r(g[0]), _r(g[1])], "status": st} for g, st in logs.ground_goals],
        "goals_judged_s": _r(max(judged), 3) if done else None,
        "plans": kinds.count("plan"),
        "replans": sum(1 for e in logs.ground_events if e.kind == "plan" and "replan" in e.detail),
        "safings_seen": kinds.count("safed"),
        "resumes": kinds.count("resume"),
    }


def _perception(keyframes) -> dict:
    """The ground perception's keyframes: how many, VO outcomes, lethal cells added, the
    ground's final position sigma since the first keyframe (m, per axis)."""
    vo = {}
    for k in keyframes:
        vo[k.vo] = vo.get(k.vo, 0) + 1
    return {
        "keyframes": len(keyframes),
        "vo": dict(sorted(vo.items())),
        "lethal_cells_added": int(sum(k.new_lethal for k in keyframes)),
        "final_sigma_m": round(float(keyframes[-1].sigma_m), 6) if keyframes else None,
    }


#: A true hazard counts for detection when its cell lies within this distance (m) of
#: the rover's true track.
NEAR_PATH_M = 3.0


def _truth_pose_at(pose, t: float) -> np.ndarray:
    """(x, y, z, roll, pitch, yaw) of the truth log at time ``t`` (linear; yaw unwrapped)."""
    cols = [np.interp(t, pose.times, pose.data[:, i]) for i in range(5)]
    yaw = np.interp(t, pose.times, np.unwrap(pose.data[:, 5]))
    return np.array([*cols, yaw])


def vo_scores(*, scenario: Scenario, logs: SimulationLogs) -> dict:
    """Stereo and VO against truth: mean fraction of pixels with a valid disparity;
    ``vo_acceptance`` (accepted / tried: accepted, rejected or gated);
    ``vo_error_per_m``: over the accepted links, the summed length of (VO's translation
    - the true camera translation, both in the previous keyframe's camera frame) over
    the summed true translation. The true camera pose is the true chassis pose at the
    capture time (the truth log, interpolated) with the rover model's mast at the
    frame's pan and tilt."""
    from lunar_drake.perception.ground_pipeline import pose_matrix
    from lunar_drake.systems.ground_perception import camera_in_chassis_fn

    kf = logs.keyframes
    valid = [k.valid_fraction for k in kf if math.isfinite(k.valid_fraction)]
    tried = [k for k in kf if k.vo in ("accepted", "rejected", "gated")]
    out = {
        "stereo_valid_fraction": _r(float(np.mean(valid)), 4) if valid else None,
        "vo_tried": len(tried),
        "vo_acceptance": _r(sum(k.vo == "accepted" for k in tried) / len(tried), 4)
        if tried else None,
        "vo_error_per_m": None,
    }
    pose = logs.vectors["truth.pose"]
    if not len(pose.times) or not any(k.vo == "accepted" for k in kf):
        return out
    X_BC = camera_in_chassis_fn(scenario.rover.description)

    def X_WC(k):
        return pose_matrix(_truth_pose_at(pose, k.t_capture_s)) @ X_BC(k.pan_rad, k.tilt_rad)

    err = dist = 0.0
    for prev, cur in itertools.pairwise(kf):
        if cur.vo != "accepted":
            continue
        t_true = (np.linalg.inv(X_WC(prev)) @ X_WC(cur))[:3, 3]
        t_vo = np.array([cur.vo_tx_m, cur.vo_ty_m, cur.vo_tz_m])
        err += float(np.linalg.norm(t_vo - t_true))
        dist += float(np.linalg.norm(t_true))
    out["vo_error_per_m"] = _r(err / dist, 5) if dist > 0 else None
    return out


def hazard_detection(*, scenario: Scenario, site: SiteData, logs: SimulationLogs) -> dict:
    """How far ahead the ground's stereo found the hazards near the path. A hazard is a
    cell of the ground's costmap grid holding a true hazard (a lethal cell of the true
    terrain's costmap at the site's resolution, the same hazard rules) within
    :data:`NEAR_PATH_M` of the rover's true track that the a-priori map did not mark
    lethal (only stereo could find it). It is detected at the first keyframe whose
    stereo made it, or a neighbouring cell (the ground's pose error), lethal; its range
    is the distance from the rover's true position then to the cell's centre. Returns
    ``hazards_near_path``, ``hazards_detected``, ``hazards_missed`` and
    ``detection_range_m`` (median, p90), or {} without ground stereo."""
    import dataclasses as dc

    from lunar_drake import preflight
    from lunar_drake.autonomy.costmap import RoverEnvelope, costmap_of_product
    from lunar_drake.autonomy.map_product import make_map_product

    cm, first, prior = logs.ground_costmap, logs.ground_first_lethal_s, logs.ground_prior_costmap
    pose = logs.vectors["truth.pose"]
    if cm is None or first is None or prior is None or len(pose.times) < 2:
        return {}
    track = pose.data[:, :2]
    lo, hi = track.min(axis=0) - NEAR_PATH_M, track.max(axis=0) + NEAR_PATH_M
    truth_cfg = dc.replace(scenario.ground.map, source="truth", margin_m=2.0)
    product = make_map_product(heightfield=site.heightfield, points_xy=[tuple(lo), tuple(hi)],
                               map_config=truth_cfg, seed=scenario.site.seed,
                               rock_mask=preflight.rock_mask_reader(site))  # fmt: skip
    true_cm = costmap_of_product(product, rover=RoverEnvelope.of(scenario.rover.description),
                                 hazards=scenario.ground.hazards)  # fmt: skip
    rows, cols = np.nonzero(true_cm.lethal_raw)
    res = true_cm.resolution_m
    x = true_cm.x0_m + (cols + 0.5) * res
    y = true_cm.y1_m - (rows + 0.5) * res
    r = np.floor((cm.y1_m - y) / cm.resolution_m).astype(int)
    c = np.floor((x - cm.x0_m) / cm.resolution_m).astype(int)
    inside = (r >= 0) & (r < cm.shape[0]) & (c >= 0) & (c < cm.shape[1])
    hazard = np.zeros(cm.shape, bool)
    hazard[r[inside], c[inside]] = True
    hazard &= ~prior.lethal_raw
    hr, hc = np.nonzero(hazard)
    cx = cm.x0_m + (hc + 0.5) * cm.resolution_m
    cy = cm.y1_m - (hr + 0.5) * cm.resolution_m
    from scipy.spatial import cKDTree

    near = cKDTree(track).query(np.column_stack([cx, cy]))[0] <= NEAR_PATH_M
    hr, hc, cx, cy = hr[near], hc[near], cx[near], cy[near]
    padded = np.pad(first, 1, constant_values=np.nan)
    ranges = []
    for i in range(len(hr)):
        window = padded[hr[i]:hr[i] + 3, hc[i]:hc[i] + 3]
        if np.isnan(window).all():
            continue
        t = float(np.nanmin(window))
        p = _truth_pose_at(pose, t)
        ranges.append(math.hypot(p[0] - cx[i], p[1] - cy[i]))
    det = {"median": _r(float(np.median(ranges)), 3),
           "p90": _r(float(np.percentile(ranges, 90)), 3)} if ranges else None  # fmt: skip
    return {
        "hazards_near_path": len(hr),
        "hazards_detected": len(ranges),
        "hazards_missed": len(hr) - len(ranges),
        "detection_range_m": det,
    }


def _ground_map(logs) -> dict:
    """The ground's a-priori map as summaries report it: ``map_source`` (orbital, or truth:
    the oracle) and the product's facts (:func:`lunar_drake.preflight.describe`)."""
    m = logs.preflight.get("ground_map")
    return {"map_source": m["map_source"], "map": m} if m else {"map_source": None}


def summarize(*, scenario: Scenario, site: SiteData, logs: SimulationLogs) -> dict:
    """The deterministic summary of a run (``summary.json``)."""
    tel = logs.telemetry
    summary = {
        "scenario": scenario.name,
        "random_seed": scenario.random_seed,
        "site_seed": scenario.site.seed,
        "simulated_s": _r(logs.simulated_s),
        "stop_reason": logs.stop_reason,
        "diagram": "mission",
        "systems": logs.systems,
        "site": site.info,
        "site_dir": str(site.site.directory or site.site.dem) if site.site else "",
        "rover": traverse(logs),
        "power": power(logs),
        "parked": parked_drift(logs),
        "localization": localization(logs),
        "goals": goals(scenario=scenario, logs=logs),
        "hazards": hazards(scenario=scenario, site=site, logs=logs),
        "link": link_stats(logs),
        "modes": modes(logs),
        "ground": {**_ground_map(logs), **ground(logs)},
        "flight": {"slip_calibration": logs.preflight.get("slip_calibration")},
        "telemetry_received": len(tel.seq),
        "images_received": len(logs.images_received),
        "images_bytes_received": int(sum(r[4] for r in logs.images_received)),
        "perception": _perception(logs.keyframes),
        "camera_frames": int(logs.frames_written),
    }
    if logs.keyframes:
        summary["perception"].update(vo_scores(scenario=scenario, logs=logs))
        summary["perception"].update(hazard_detection(scenario=scenario, site=site, logs=logs))
    if scenario.sensors.nss.enabled or scenario.sensors.nirvss.enabled:
        summary["science"] = science(scenario=scenario, site=site, logs=logs)
    return summary


def _nd(x, nd: int = 6):
    return None if x is None else _r(x, nd)


def _scored(prefix: str, a: dict, unit: str) -> dict:
    """``{prefix}_r``, ``_cells``, ``_rmse_{unit}``, ``_bias_{unit}`` of an
    :func:`~lunar_drake.science.scoring.agreement`."""
    return {
        f"{prefix}_r": _nd(a["r"]),
        f"{prefix}_cells": a["cells"],
        f"{prefix}_rmse_{unit}": _nd(a["rmse"]),
        f"{prefix}_bias_{unit}": _nd(a["bias"]),
    }


def _lcs(*, scenario: Scenario, site: SiteData, logs: SimulationLogs, grids: dict) -> dict:
    """NIRVSS records received; the ground's LCS and NIRVSS maps against the world
    model's layers averaged over each map cell (``lcs_world_*``: temperature, K;
    ``nirvss_world``: per band, the cells' band depth over its coefficient -- the
    abundance the band implies -- against the layer it reads); and, as the
    instrument's performance, the LCS against the spot it read at the true position
    (``lcs_spot_rmse_K``)."""
    from lunar_drake.rotations import rotation_matrix_from_rpy
    from lunar_drake.science.nirvss import spot_means
    from lunar_drake.science.scoring import nirvss_world, world_agreement
    from lunar_drake.science.world import surface_map

    recs = [r for _t, r in logs.science_received if r.instrument == "nirvss"]
    out = {"nirvss_records": len(recs)}
    if not recs:
        return out
    cfg = scenario.sensors.nirvss
    smap = surface_map(scenario=scenario, site=site)
    geo = {"x0_m": smap.x0_m, "y1_m": smap.y1_m, "resolution_m": smap.resolution_m}
    if grids.get("lcs") is not None:
        out.update(_scored("lcs_world", world_agreement(grids["lcs"],
                           smap.layers["temperature_K"], **geo), "K"))  # fmt: skip
    if grids.get("nirvss") is not None:
        out["nirvss_world"] = {
            band: {k: (_nd(v) if k != "cells" else v) for k, v in a.items()}
            for band, a in nirvss_world(grids["nirvss"], smap=smap, config=cfg).items()
        }
    pose = logs.vectors["truth.pose"]
    err = []
    for r in recs:
        k = min(int(np.searchsorted(pose.times, r.t_sample_s - 1e-9)), len(pose.times) - 1)
        row = pose.data[k]  # the logged true pose at the sample time
        p = row[:3] + rotation_matrix_from_rpy(row[3:6]) @ np.array([cfg.x_m, 0.0, 0.0])
        spot = spot_means(smap, float(p[0]), float(p[1]), radius_m=cfg.spot_radius_m)
        err.append(r.values[-1] - spot["temperature_K"])
    out["lcs_spot_rmse_K"] = _r(float(np.sqrt(np.mean(np.square(err)))))
    return out


def _drill(*, scenario: Scenario, site: SiteData, logs: SimulationLogs) -> dict:
    """Drill samples received and the ground's drill product against the world at the
    holes it claims (:func:`lunar_drake.science.scoring.drill_world`)."""
    from lunar_drake.science.scoring import drill_holes, drill_world
    from lunar_drake.science.world import surface_map

    recs = [r for _t, r in logs.science_received if r.instrument == "drill"]
    out = {"drill_samples": len(recs)}
    if not recs:
        return out
    nir = scenario.sensors.nirvss
    holes = drill_holes(recs, hole_x_m=scenario.sensors.drill.x_m,
                        ice_per_wt_pct=nir.ice_per_wt_pct, sigma=nir.sigma_lamp)  # fmt: skip
    w = drill_world(holes, smap=surface_map(scenario=scenario, site=site))
    out["drill_world_rmse_wt_pct"] = _nd(w["rmse_wt_pct"])
    out["drill_holes"] = [{k: (_nd(v) if isinstance(v, float) else v) for k, v in h.items()}
                          for h in w["holes"]]  # fmt: skip
    return out


def science(*, scenario: Scenario, site: SiteData, logs: SimulationLogs) -> dict:
    """Science scored on truth. Each ground map (2 m cells,
    :func:`lunar_drake.science.products.instrument_grid`) against the world model's own
    layers averaged over each cell it publishes (``*_world_*``,
    :mod:`lunar_drake.science.scoring`): NSS hydrogen against the world's
    depth-weighted hydrogen column (``nss_world_*``; ``nss_cells_seen``: cells with
    records, published or not); LCS and NIRVSS (:func:`_lcs`). As the instruments'
    performance: NSS against the footprint hydrogen the detector saw at its true
    positions (``nss_footprint_*``, :func:`lunar_drake.science.products.nss_truth`),
    the LCS against its spot. The drill: its product at the holes the ground claims
    against the world's dry layer and ice there (:func:`_drill`)."""
    from lunar_drake.science.products import (
        instrument_grid,
        instrument_records,
        nss_table,
        nss_truth,
    )
    from lunar_drake.science.scoring import agreement, nss_world
    from lunar_drake.science.world import hydrogen_map

    keyframes = getattr(logs, "keyframes", None) or ()
    recs = instrument_records(logs.science_received, scenario=scenario, keyframes=keyframes)
    grids = {name: instrument_grid(name, *r, scenario=scenario) for name, r in recs.items()}
    out = {}
    if scenario.sensors.nirvss.enabled:
        out.update(_lcs(scenario=scenario, site=site, logs=logs, grids=grids))
    if scenario.sensors.drill.enabled:
        out.update(_drill(scenario=scenario, site=site, logs=logs))
    if not scenario.sensors.nss.enabled:
        return out
    cfg = scenario.sensors.nss
    table = nss_table(logs.science_received, config=cfg, keyframes=keyframes)
    out["nss_records"] = len(table)
    if not len(table):
        return out
    hmap = hydrogen_map(scenario=scenario, site=site)
    pose = logs.vectors["truth.pose"]
    t = nss_truth(table, truth_times=pose.times, truth_xy_yaw=pose.data[:, [0, 1, 5]],
                  hmap=hmap, config=cfg)  # fmt: skip
    grid = grids["nss"]
    world = agreement([], []) if grid is None else nss_world(grid, hmap=hmap, config=cfg)
    footprint = {"r": t["r"], "cells": t["cells"], "rmse": t["rmse_wt_pct"],
                 "bias": t["bias_wt_pct"]}  # fmt: skip
    out.update(
        weh_est_mean_wt_pct=_r(float(np.mean(table.weh_est))),
        weh_truth_mean_wt_pct=_r(float(np.mean(t["truth_weh"]))),
        **_scored("nss_world", world, "wt_pct"),
        nss_cells_seen=int(np.count_nonzero(grid.count)) if grid is not None else 0,
        **_scored("nss_footprint", footprint, "wt_pct"),
    )
    return out
