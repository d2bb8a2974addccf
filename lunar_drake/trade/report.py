"""A study's ``report.md`` and plots: for each metric its mean and spread against each
factor (main effects; every run drawn, so the replicate spread shows) and the best
cases. Built from ``results.csv`` alone (pandas, matplotlib), so it can be redrawn."""

from __future__ import annotations

import math
from pathlib import Path

from lunar_drake.files import atomic_path, atomic_write_text
from lunar_drake.trade.results import load_results
from lunar_drake.trade.study import Job, Study

#: Best cases listed per metric with a direction.
BEST_CASES = 5
#: Bins of a continuous (LHS range) factor in the main-effect table and plot.
RANGE_BINS = 4


def _num(x) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if isinstance(x, float):
        return f"{x:.4g}"
    return str(x)


def _level(v) -> str:
    """A factor value as a label: 5.0 -> 5, text as is."""
    return f"{v:g}" if isinstance(v, float) else str(v)


def _slug(key: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in key).strip("_")


def _groups(frame, study: Study, factor):
    """(level label, sub-frame) per level of ``factor`` (bins for an LHS range)."""
    import pandas as pd

    col = frame[factor.key]
    if factor.range is not None:
        edges = [factor.range[0] + (factor.range[1] - factor.range[0]) * k / RANGE_BINS
                 for k in range(RANGE_BINS + 1)]  # fmt: skip
        bins = pd.cut(col, bins=edges, include_lowest=True)
        return [(f"{iv.left:.4g}-{iv.right:.4g}", frame[bins == iv])
                for iv in bins.cat.categories]  # fmt: skip
    out = []
    for v in factor.levels:
        match = col == v
        if not match.any():  # a level pandas read back as another type
            match = col.astype(str) == str(v)
        out.append((_level(v), frame[match]))
    return out


def _plot(frame, study: Study, metric: str, path: Path) -> bool:
    import numpy as np
    from matplotlib.figure import Figure

    y_all = frame[metric]
    if not np.issubdtype(y_all.dtype, np.number) or y_all.notna().sum() == 0:
        return False
    n = len(study.factors)
    fig = Figure(figsize=(3.6 * n + 0.6, 3.2))
    axes = fig.subplots(1, n, squeeze=False, sharey=True)
    for ax, f in zip(axes[0], study.factors, strict=True):
        groups = _groups(frame, study, f)
        rng = np.random.default_rng(0)
        for i, (_, sub) in enumerate(groups):
            y = sub[metric].dropna().to_numpy(float)
            if len(y):
                ax.scatter(i + rng.uniform(-0.12, 0.12, len(y)), y, s=10, color="0.55",
                           zorder=2)  # fmt: skip
                ax.errorbar(i, y.mean(), yerr=y.std() if len(y) > 1 else 0.0, fmt="o",
                            color="C0", ms=7, capsize=4, zorder=3)  # fmt: skip
        means = [sub[metric].mean() for _, sub in groups]
        ax.plot(range(len(groups)), means, color="C0", lw=1, zorder=1)
        ax.set_xticks(range(len(groups)), [g for g, _ in groups],
                      rotation=30 if len(groups) > 3 else 0, fontsize=8)  # fmt: skip
        ax.set_xlabel(f.key, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel(metric, fontsize=9)
    fig.suptitle(f"{study.name}: {metric} (mean \u00b1 sd over the other factors and "
                 "replicates; grey: runs)", fontsize=9)  # fmt: skip
    fig.tight_layout()
    with atomic_path(path, what="plot") as tmp:
        fig.savefig(tmp, dpi=110, format="png", metadata={"Software": None})
    return True


def _case_table(ok, study: Study) -> list[str]:
    """Every case: its factor levels and each numeric metric's mean (sd) over the
    replicates."""
    import numpy as np

    keys = [m.key for m in study.metrics
            if m.key in ok and np.issubdtype(ok[m.key].dtype, np.number)]  # fmt: skip
    if ok.empty or not keys:
        return []
    head = [f"`{f.key}`" for f in study.factors] + [f"`{k}`" for k in keys]
    lines = ["## All cases (mean, sd over the replicates)", "",
             "| case | " + " | ".join(head) + " | runs |",
             "|---|" + "---|" * len(study.factors) + "---:|" * len(keys) + "---:|"]  # fmt: skip
    for case, sub in ok.groupby("case", sort=True):
        levels = [_level(sub.iloc[0][f.key]) for f in study.factors]
        cells = []
        for k in keys:
            y = sub[k].dropna()
            sd = f" ({_num(float(y.std()))})" if len(y) > 1 else ""
            cells.append(_num(float(y.mean())) + sd if len(y) else "-")
        lines.append(f"| {case} | " + " | ".join(levels + cells) + f" | {len(sub)} |")
    return [*lines, ""]


def write_report(out: Path, *, study: Study, jobs: list[Job], quick: bool) -> list[Path]:
    """Writes ``report.md`` and ``plots/METRIC.png`` into ``out`` from its
    results.csv; returns the paths."""
    import numpy as np

    frame = load_results(out / "results.csv")
    ok = frame[frame["status"] == "ok"]
    plots_dir = out / "plots"
    plots_dir.mkdir(exist_ok=True)
    paths = []
    n_cases = len({j.case for j in jobs})
    reps = sorted({j.seed for j in jobs})
    lines = [
        f"# Trade study: {study.name}" + (" (quick form)" if quick else ""),
        "",
        study.description.strip() or "(no description)",
        "",
        f"- Base scenario: `{study.scenario}`"
        + (f" with `{study.scenario_text.strip()}`" if study.scenario_text.strip() != "{}" else ""),
        f"- Design: {study.design}, {n_cases} cases x {len(reps)} replicates "
        f"(random_seed {', '.join(map(str, reps))}) = {len(jobs)} runs; "
        f"{len(ok)} ok, {len(frame) - len(ok)} failed, {len(jobs) - len(frame)} not run",
        f"- Factors: {', '.join(f'`{f.key}`' for f in study.factors)}",
        "- Every row of `results.csv` can be rerun alone: "
        "`lunar-drake run --scenario cases/ID/scenario.yaml`",
        "",
    ]
    for m in study.metrics:
        col = ok[m.key] if m.key in ok else None
        numeric = col is not None and np.issubdtype(col.dtype, np.number)
        lines += [f"## {m.key}" + (f" (better: {m.better})" if m.better else ""), ""]
        if not numeric or col.notna().sum() == 0:
            lines += ["No numeric values.", ""]
            continue
        png = plots_dir / f"{_slug(m.key)}.png"
        if _plot(ok, study, m.key, png):
            paths.append(png)
            lines += [f"![{m.key}](plots/{png.name})", ""]
        lines += ["| factor | level | mean | sd | runs |", "|---|---|---:|---:|---:|"]
        for f in study.factors:
            for label, sub in _groups(ok, study, f):
                y = sub[m.key].dropna()
                sd = float(y.std()) if len(y) > 1 else None
                lines.append(f"| `{f.key}` | {label} | {_num(float(y.mean()) if len(y) else None)}"
                             f" | {_num(sd)} | {len(y)} |")  # fmt: skip
        lines.append("")
        if m.better:
            by_case = ok.groupby("case")[m.key].agg(["mean", "std", "count"])
            by_case = by_case.dropna(subset=["mean"]).sort_values(
                "mean", ascending=m.better == "min", kind="stable")
            first = ok.drop_duplicates("case").set_index("case")
            lines += [f"Best cases by {m.key}:", "",
                      "| case | " + " | ".join(f"`{f.key}`" for f in study.factors)
                      + " | mean | sd | runs |",
                      "|---|" + "---|" * len(study.factors) + "---:|---:|---:|"]  # fmt: skip
            for case, r in by_case.head(BEST_CASES).iterrows():
                vals = " | ".join(_level(first.loc[case, f.key]) for f in study.factors)
                lines.append(f"| {case} | {vals} | {_num(r['mean'])} | "
                             f"{_num(r['std'] if r['count'] > 1 else None)} | {int(r['count'])} |")
            lines.append("")
    lines += _case_table(ok, study)
    failed = frame[frame["status"] != "ok"]
    if len(failed):
        lines += ["## Failed runs", "", "| case | replicate | error |", "|---|---:|---|"]
        lines += [f"| {r.case} | {r.replicate} | {r.error} |" for r in failed.itertuples()]
        lines.append("")
    paths.append(atomic_write_text(out / "report.md", "\n".join(lines)))
    return paths
