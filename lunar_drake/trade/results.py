"""A study's files: the per-run journal (``cases/ID/row.json``), ``results.csv``
(deterministic: sorted by case and replicate, no wall times), ``timing.csv`` and,
with pyarrow installed, ``results.parquet``.

``results.csv`` columns: ``case, replicate, seed``, every factor, every metric,
``status`` (ok/error), ``error`` and ``key`` (the hash of the resolved scenario, the
resume identity). Values: numbers as Python writes them (shortest round trip), booleans
``true``/``false``, a missing value empty.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from lunar_drake.files import atomic_write_text
from lunar_drake.trade.study import Job, Study

TIMING_COLUMNS = ("case", "replicate", "worker", "wall_s", "simulate_s", "realtime_factor")


def fmt(value) -> str:
    """One CSV cell."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float, str)):
        return str(value) if not isinstance(value, float) else repr(value)
    return json.dumps(value, sort_keys=True)


def row_path(out: Path, job: Job) -> Path:
    return out / "cases" / job.id / "row.json"


def read_row(out: Path, job: Job) -> dict | None:
    """The journalled row of ``job``, or None (missing, unreadable or another scenario)."""
    p = row_path(out, job)
    try:
        row = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return row if row.get("key") == job.key else None


def write_row(out: Path, job: Job, result: dict) -> dict:
    """Journals one finished run (atomically) and returns its row."""
    row = {
        "key": job.key,
        "status": result["status"],
        "error": result["error"],
        "metrics": result["metrics"],
        "worker": result["worker"],
        "timing": result["timing"],
    }
    atomic_write_text(row_path(out, job), json.dumps(row, indent=1, sort_keys=True) + "\n")
    return row


def columns(study: Study) -> list[str]:
    return ["case", "replicate", "seed", *(f.key for f in study.factors),
            *(m.key for m in study.metrics), "status", "error", "key"]  # fmt: skip


def table_rows(study: Study, jobs: list[Job], rows: dict) -> list[list]:
    """results.csv's rows (values, not text) for the jobs that have a row."""
    out = []
    for job in sorted(jobs, key=lambda j: (j.case, j.replicate)):
        row = rows.get(job.id)
        if row is None:
            continue
        m = row["metrics"]
        out.append([job.case, job.replicate, job.seed, *(job.factors[f.key] for f in study.factors),
                    *(m.get(k.key) for k in study.metrics), row["status"], row["error"],
                    job.key])  # fmt: skip
    return out


def _csv_text(header, rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        w.writerow([fmt(v) for v in r])
    return buf.getvalue()


def write_results(out: Path, *, study: Study, jobs: list[Job], rows: dict) -> list[Path]:
    """Writes results.csv, timing.csv and (with pyarrow) results.parquet; returns the
    paths."""
    header = columns(study)
    table = table_rows(study, jobs, rows)
    paths = [atomic_write_text(out / "results.csv", _csv_text(header, table))]
    timing = []
    for job in sorted(jobs, key=lambda j: (j.case, j.replicate)):
        row = rows.get(job.id)
        if row is None:
            continue
        t = row.get("timing") or {}
        timing.append([job.case, job.replicate, row.get("worker", ""),
                       round(t.get("wall_s", 0.0), 3), round(t.get("simulate_s", 0.0), 3),
                       round(t.get("realtime_factor") or 0.0, 3)])  # fmt: skip
    paths.append(atomic_write_text(out / "timing.csv", _csv_text(TIMING_COLUMNS, timing)))
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        return paths
    frame = load_results(out / "results.csv")
    tmp = out / ".results.parquet.tmp"
    frame.to_parquet(tmp, index=False)
    tmp.replace(out / "results.parquet")
    return [*paths, out / "results.parquet"]


def load_results(path: str | Path):
    """``results.csv`` as a pandas DataFrame (empty cells as NaN, ``error`` as text)."""
    import pandas as pd

    return pd.read_csv(path, keep_default_na=False, na_values=[""],
                       dtype={"error": str, "key": str, "case": str})  # fmt: skip
