"""Runs a study's cases on dask.distributed and keeps every finished row.

A :class:`distributed.LocalCluster` of single-threaded worker processes (bound to
127.0.0.1) by default, or an existing scheduler (``tcp://HOST:PORT``: ``dask scheduler``
and ``dask worker`` on other machines, each with lunar_drake installed). Each finished
run is journalled at once (``cases/ID/row.json``), so Ctrl-C, a killed process or a
dead worker loses only the runs in flight; ``resume`` runs only the jobs without a row.
Each run is single-threaded (numba, OpenMP, BLAS: one thread), so a row does not depend
on how many workers ran the study.
"""

from __future__ import annotations

import contextlib
import dataclasses as dc
import logging
import re
import time
from pathlib import Path

from lunar_drake.errors import ConfigError, OutputError
from lunar_drake.trade import results
from lunar_drake.trade.study import Job, Study, expand_jobs, resolved_study_text

#: Environment of each local worker process: one thread for every numeric library.
WORKER_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}
#: dask settings for the local cluster: its housekeeping (the event-loop tick, the
#: workers' statistical profiler and GIL monitor) costs a few percent of a core per
#: process, which a study of CPU-bound runs on every core pays in full. Set only once
#: ``distributed`` is imported: leaving a ``dask.config.set`` made before its defaults
#: loaded would take the whole ``distributed`` section with it.
CLUSTER_CONFIG = {
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.admin.system-monitor.gil.enabled": False,
    "distributed.worker.profile.enabled": False,
}
#: Seconds to wait for a remote scheduler before giving up.
CONNECT_TIMEOUT_S = 5.0
_ADDRESS = re.compile(r"(tcp|tls|inproc|ucx|ws|wss)://[^\s/]+(:\d+)?$")


@dc.dataclass
class StudyRun:
    """What :func:`run_study` did. ``rows``: job id -> row (all journalled rows, old and
    new); ``ran``: runs done now; ``failed``: rows with status error; ``dashboard``: the
    dask dashboard's address (None without one)."""

    out: Path
    study: Study
    jobs: list[Job]
    rows: dict
    ran: int = 0
    failed: int = 0
    interrupted: bool = False
    dashboard: str | None = None
    wall_s: float = 0.0
    files: list = dc.field(default_factory=list)


def connect(*, workers: int, scheduler: str | None):
    """A dask Client (and the LocalCluster it owns, or None).

    Raises:
        ConfigError: a malformed or unreachable scheduler address, workers < 1.
    """
    from distributed import Client, LocalCluster

    if scheduler:
        if not _ADDRESS.match(scheduler):
            raise ConfigError(f"--scheduler {scheduler!r} is not a scheduler address; "
                              "expected tcp://HOST:PORT")  # fmt: skip
        try:
            client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            msg = " ".join(str(exc).split())
            raise ConfigError(f"--scheduler {scheduler!r}: cannot connect within "
                              f"{CONNECT_TIMEOUT_S:g} s ({msg})") from None  # fmt: skip
        return client, None
    if workers < 1:
        raise ConfigError(f"--workers = {workers} is out of range; allowed >= 1")
    cluster = LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
        silence_logs=logging.ERROR,
        env=WORKER_ENV,
    )
    client = Client(cluster)
    client.wait_for_workers(workers)  # all of them up before the first task is placed
    return client, cluster


def disconnect(client, cluster) -> None:
    """Closes the client and the LocalCluster it owns (None: a remote scheduler, left
    running), whatever state they are in."""
    with contextlib.suppress(Exception):
        client.close()
    if cluster is not None:
        with contextlib.suppress(Exception):
            cluster.close()


def _dashboard(client) -> str | None:
    with contextlib.suppress(Exception):
        return client.dashboard_link
    return None


def prepare_output(out: Path, *, study_text: str, resume: bool) -> None:
    """Refuses a non-empty ``out`` without ``resume``, and a resume of another study.

    Raises:
        OutputError: ``out`` is a file, or holds something and ``resume`` is off.
        ConfigError: ``resume`` on a directory without this study's ``study.yaml``.
    """
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {str(out)!r} is a file, not a directory")
    busy = out.is_dir() and any(out.iterdir())
    if not resume and busy:
        raise OutputError(f"--out {str(out)!r} is not empty; --resume continues the study "
                          "there, or choose another directory")  # fmt: skip
    if resume and busy:
        old = out / "study.yaml"
        if not old.is_file():
            raise ConfigError(f"--resume: {str(out)!r} holds no study.yaml; it is not a "
                              "study's directory")  # fmt: skip
        if old.read_text(encoding="utf-8") != study_text:
            raise ConfigError(f"--resume: the study in {str(out)!r} differs from this one "
                              "(study.yaml); run it into another --out")  # fmt: skip


def prebuild_sites(jobs: list[Job], *, progress: bool) -> None:
    """Builds each distinct site (and world model) into the cache before the workers
    start, so no two workers synthesize the same site at once."""
    from lunar_drake.scenario_files import dump_scenario, scenario_from_text
    from lunar_drake.science.world import needs_world, run_world
    from lunar_drake.site import ensure_site, load_site

    seen = set()
    for job in jobs:
        s = scenario_from_text(job.scenario_yaml)
        probe = dc.replace(s, random_seed=0, name="", simulation_duration=1.0)
        key = dump_scenario(probe)  # the whole scenario less what only the run changes
        if key in seen:
            continue
        seen.add(key)
        if needs_world(s):
            run_world(scenario=s, site=load_site(s, progress=progress), progress=progress)
        else:
            ensure_site(s, progress=progress)


def run_study(
    *,
    study: Study,
    out: str | Path,
    workers: int = 2,
    scheduler: str | None = None,
    resume: bool = False,
    quick: bool = False,
    progress: bool = True,
    echo=print,
) -> StudyRun:
    """Runs ``study`` into directory ``out``: ``study.yaml`` (as run), per run
    ``cases/ID/scenario.yaml`` (rerun one alone with ``lunar-drake run --scenario``),
    ``summary.json`` and ``row.json``; then results.csv, timing.csv, report.md and its
    plots.

    Raises:
        ConfigError, OutputError: bad study, scheduler or output directory, before
            anything is written.
        KeyboardInterrupt: after Ctrl-C, once the finished rows and results.csv are
            written.
    """
    t0 = time.perf_counter()
    out = Path(out)
    jobs = expand_jobs(study, quick=quick)
    text = resolved_study_text(study, quick=quick)
    prepare_output(out, study_text=text, resume=resume)
    import dask
    import distributed  # noqa: F401  (its config defaults load before ours go over them)

    with dask.config.set(CLUSTER_CONFIG):
        return _run_study(study=study, out=out, jobs=jobs, text=text, workers=workers,
                          scheduler=scheduler, quick=quick, progress=progress, echo=echo,
                          t0=t0)  # fmt: skip


def _run_study(*, study, out, jobs, text, workers, scheduler, quick, progress, echo, t0):
    from lunar_drake.cli._common import plural
    from lunar_drake.files import atomic_write_text

    client, cluster = connect(workers=workers, scheduler=scheduler)
    run = StudyRun(out=out, study=study, jobs=jobs, rows={}, dashboard=_dashboard(client))
    try:
        (out / "cases").mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "study.yaml", text)
        for job in jobs:
            d = out / "cases" / job.id
            d.mkdir(exist_ok=True)
            if not (d / "scenario.yaml").is_file():
                atomic_write_text(d / "scenario.yaml", job.scenario_yaml)
            row = results.read_row(out, job)
            if row is not None:
                run.rows[job.id] = row
        todo = [j for j in jobs if j.id not in run.rows]
        where = f"scheduler {scheduler}" if scheduler else plural(workers, "local worker")
        echo(f"Study {study.name!r}: {len(jobs)} runs ({len(jobs) - len(todo)} already done); "
             f"{len(todo)} to run on {where}"
             + (f"; dashboard {run.dashboard}" if run.dashboard else ""))  # fmt: skip
        if todo and cluster is not None:
            prebuild_sites(todo, progress=progress)
        _run_jobs(client, study, todo, run, progress=progress)
    except KeyboardInterrupt:
        run.interrupted = True
    finally:
        disconnect(client, cluster)
    run.failed = sum(r["status"] != "ok" for r in run.rows.values())
    run.files = results.write_results(out, study=study, jobs=jobs, rows=run.rows)
    if run.interrupted:
        raise KeyboardInterrupt
    from lunar_drake.trade.report import write_report

    run.files += write_report(out, study=study, jobs=jobs, quick=quick)
    run.wall_s = time.perf_counter() - t0
    return run


def map_on_cluster(fn, items: list, *, workers: int = 2, scheduler: str | None = None,
                   progress: bool = True, desc: str = "runs") -> list:
    """``[fn(item) for item in items]`` on the study engine (a LocalCluster of
    ``workers`` single-threaded processes, or ``scheduler``), in the items' order, with
    a progress bar: for the studies that are not scenario missions (``slip-study``).
    ``fn`` and the items must pickle; an exception in one re-raises here.

    Raises:
        ConfigError: a malformed or unreachable scheduler, workers < 1.
    """
    import dask
    from distributed import as_completed  # (its config defaults load before ours)
    from tqdm import tqdm

    with dask.config.set(CLUSTER_CONFIG):
        client, cluster = connect(workers=workers, scheduler=scheduler)
        try:
            futures = client.map(fn, items, pure=False)
            index = {f.key: k for k, f in enumerate(futures)}
            out = [None] * len(items)
            with tqdm(total=len(items), desc=desc, unit="run", disable=not progress) as bar:
                for fut in as_completed(futures):
                    out[index[fut.key]] = fut.result()
                    bar.update(1)
            return out
        finally:
            disconnect(client, cluster)


def map_cases(fn, items: list, *, workers: int = 1, scheduler: str | None = None,
              progress: bool = True, desc: str = "runs") -> list:  # fmt: skip
    """``[fn(item) for item in items]``: in this process with one worker and no
    scheduler, else on the engine (:func:`map_on_cluster`); the same results either way,
    in the items' order, with a progress bar.

    Raises:
        ConfigError: workers < 1, or (on the engine) a malformed or unreachable scheduler.
    """
    if workers < 1:
        raise ConfigError(f"workers = {workers!r}; must be >= 1")
    if workers > 1 or scheduler:
        return map_on_cluster(fn, items, workers=workers, scheduler=scheduler,
                              progress=progress, desc=desc)  # fmt: skip
    from tqdm.auto import tqdm

    return [fn(item) for item in tqdm(items, desc=desc, unit="run", disable=not progress)]


def _run_jobs(client, study: Study, todo: list[Job], run: StudyRun, *, progress: bool) -> None:
    from distributed import as_completed
    from tqdm import tqdm

    from lunar_drake.trade.case import run_case

    keys = tuple(m.key for m in study.metrics)
    # One task prefix for every run: dask then queues them on the scheduler and hands one
    # to each worker as it frees up (unique prefixes were assigned up front, to whichever
    # workers had started: 10 and 6 runs of 16 on two workers, a speedup of 1.62).
    futures = {
        client.submit(run_case, job.scenario_yaml, keys, key=f"lunar_drake_run-{job.id}-{job.key}",
                      pure=False): job
        for job in todo
    }
    bar = tqdm(total=len(run.jobs), initial=len(run.jobs) - len(todo), unit="run",
               desc=study.name, disable=not progress, dynamic_ncols=True)  # fmt: skip
    try:
        for fut in as_completed(futures):
            job = futures[fut]
            try:
                result = fut.result()
            except Exception as exc:  # the worker died (KilledWorker) or the task was lost
                lines = str(exc).strip().splitlines()
                result = {"status": "error", "error": f"{type(exc).__name__}: "
                          f"{lines[0] if lines else ''}", "metrics": {}, "summary": None,
                          "timing": {}, "worker": ""}  # fmt: skip
            _journal(run.out, job, result)
            run.rows[job.id] = results.write_row(run.out, job, result)
            run.ran += 1
            run.failed += result["status"] != "ok"
            bar.update(1)
            bar.set_postfix(failed=run.failed, refresh=False)
    except KeyboardInterrupt:
        for fut in futures:
            fut.cancel()
        raise
    finally:
        bar.close()


def _journal(out: Path, job: Job, result: dict) -> None:
    """The run's summary.json and timing.json beside its scenario.yaml."""
    if result.get("summary") is None:
        return
    from lunar_drake import outputs
    from lunar_drake.scenario_files import scenario_from_text

    scenario = scenario_from_text(job.scenario_yaml)
    outputs.write_run_summary(out / "cases" / job.id, scenario=scenario,
                              summary=result["summary"], timing=result["timing"])  # fmt: skip
