"""A study's metrics: dotted keys of ``summary.json`` plus derived ones.

Derived metrics (computed from the summary alone, so any finished run can be scored):

* ``goals.reached`` / ``goals.count``: goals reached on truth (metrics.goals) / given;
* ``goals.all_reached``: 1 when every goal was reached, else 0;
* ``mission.time_s``: simulated time until the ground had judged its last goal
  (reached or failed), else the whole run;
* ``mission.goals_per_hour``: ``goals.reached`` per hour of ``mission.time_s``;
* ``mission.time_per_goal_s``: ``mission.time_s`` per goal reached (empty when none);
* ``localization.drift_pct``: the on-board estimate's final error per metre driven (%).

A key may index a list: ``goals[0].closest_m``.
"""

from __future__ import annotations

import math
import re

from lunar_drake.errors import ConfigError

#: Top-level sections of ``summary.json`` (metrics.summarize) a metric may start with.
SUMMARY_SECTIONS = (
    "simulated_s", "stop_reason", "rover", "parked", "localization", "goals", "hazards",
    "link", "modes", "ground", "telemetry_received", "images_received",
    "images_bytes_received", "perception", "camera_frames", "science", "power",
    "random_seed", "site_seed",
)  # fmt: skip
#: Sections that are lists: a metric indexes them (``goals[0].closest_m``).
LIST_SECTIONS = ("goals",)
DERIVED = {
    "goals.reached": "goals reached on truth",
    "goals.count": "goals given",
    "goals.all_reached": "1 when every goal was reached",
    "mission.time_s": "simulated s until the ground judged its last goal",
    "mission.goals_per_hour": "goals reached per hour of mission.time_s",
    "mission.time_per_goal_s": "mission.time_s per goal reached",
    "localization.drift_pct": "final on-board position error per metre driven (%)",
}
_PART = re.compile(r"([A-Za-z_]\w*)((?:\[\d+\])*)$")


def check_metric_key(key: str) -> None:
    """Raises ConfigError unless ``key`` is derived or starts with a summary section."""
    if key in DERIVED:
        return
    first = key.split(".")[0]
    head = first.split("[")[0]
    listed = head in LIST_SECTIONS and first == head  # a list needs an index: goals[0]
    if listed or head not in SUMMARY_SECTIONS or not all(_PART.match(p) for p in key.split(".")):
        raise ConfigError(
            f"metric {key!r} is unknown; use a dotted key of summary.json starting with one "
            f"of {', '.join(SUMMARY_SECTIONS)}, or a derived metric: {', '.join(DERIVED)}"
        )


def _lookup(summary: dict, key: str):
    node = summary
    for part in key.split("."):
        m = _PART.match(part)
        node = node[m[1]] if isinstance(node, dict) else None
        for idx in re.findall(r"\[(\d+)\]", m[2]):
            node = node[int(idx)]
    return node


def derived(summary: dict) -> dict:
    """The derived metrics of one run's summary (module docstring)."""
    goals = summary.get("goals") or []
    reached = sum(bool(g.get("reached")) for g in goals)
    judged = (summary.get("ground") or {}).get("goals_judged_s")
    time_s = float(judged) if judged is not None else float(summary["simulated_s"])
    loc = summary.get("localization") or {}
    epd = loc.get("error_per_distance")
    return {
        "goals.reached": reached,
        "goals.count": len(goals),
        "goals.all_reached": int(bool(goals) and reached == len(goals)),
        "mission.time_s": round(time_s, 3),
        "mission.goals_per_hour": round(3600.0 * reached / time_s, 6) if time_s > 0 else None,
        "mission.time_per_goal_s": round(time_s / reached, 3) if reached else None,
        "localization.drift_pct": round(100.0 * epd, 4) if epd is not None else None,
    }


def metric_values(summary: dict, keys) -> dict:
    """key -> value (a number, a bool, text or None) for each of ``keys``.

    Raises:
        ConfigError: a key the summary does not hold (naming it).
    """
    extra = derived(summary)
    out = {}
    for key in keys:
        if key in extra:
            out[key] = extra[key]
            continue
        try:
            value = _lookup(summary, key)
        except (KeyError, IndexError, TypeError):
            raise ConfigError(f"metric {key!r} is not in this run's summary.json") from None
        if isinstance(value, (dict, list)):
            raise ConfigError(f"metric {key!r} is a {type(value).__name__}, not a value; "
                              "name one of its entries")  # fmt: skip
        if isinstance(value, float) and not math.isfinite(value):
            value = None
        out[key] = value
    return out
