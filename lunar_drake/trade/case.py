"""One case of a study, as a worker runs it: the mission's one way to run
(``simulate()`` -> ``metrics.summarize``), then the study's metrics.

Runs in a dask worker process (or any process): it takes the resolved scenario as YAML
text and returns plain data, so nothing but text and numbers crosses the wire.
"""

from __future__ import annotations

import os
import time


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().name)
    except (ImportError, ValueError):
        return f"pid{os.getpid()}"


def run_case(scenario_yaml: str, metric_keys: tuple[str, ...]) -> dict:
    """Simulates the scenario in ``scenario_yaml`` and scores it.

    Returns ``{"status": "ok"|"error", "error": str, "metrics": {key: value},
    "summary": dict|None, "timing": dict, "worker": str}``. A case that raises is
    returned as ``status: error`` with the exception's type and first line, so one bad
    case never stops a study.
    """
    t0 = time.perf_counter()
    result = {"status": "ok", "error": "", "metrics": {}, "summary": None, "timing": {},
              "worker": _worker_name()}  # fmt: skip
    try:
        from lunar_drake import metrics
        from lunar_drake.scenario_files import scenario_from_text
        from lunar_drake.science.world import needs_world, run_world
        from lunar_drake.simulation import simulate
        from lunar_drake.site import load_site
        from lunar_drake.trade.metrics import metric_values

        scenario = scenario_from_text(scenario_yaml)
        site = load_site(scenario, progress=False)
        if needs_world(scenario):
            run_world(scenario=scenario, site=site, progress=False)
        logs = simulate(scenario=scenario, site=site)
        summary = metrics.summarize(scenario=scenario, site=site, logs=logs)
        result["summary"] = summary
        result["timing"] = dict(logs.wall)
        result["metrics"] = metric_values(summary, metric_keys)
    except Exception as exc:  # a failed case is a row, not a dead study
        lines = str(exc).strip().splitlines()
        result["status"] = "error"
        result["error"] = f"{type(exc).__name__}: {lines[0] if lines else ''}"
    result["timing"]["wall_s"] = time.perf_counter() - t0
    return result
