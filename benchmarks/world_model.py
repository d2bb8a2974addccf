"""Benchmark: the science world model's full stack on an N^2 site at 4 cm.

    .venv/bin/python benchmarks/world_model.py --size 2048 --out bench_world_2048.json
    .venv/bin/python benchmarks/world_model.py --size 8192 --out bench_world_8192.json

A site of ``--size``^2 pixels at ``--resolution`` (4 cm) is synthesized first (``terrain
synth`` in a child process, cached under ``--cache``; not timed), then ``lunar-drake
world build`` runs in another: ``seconds`` is its wall time and ``peak_rss_mb`` its peak
resident memory (``wait4``'s rusage of that child alone; Linux charges a child, at its
exec, with the peak of the process it was forked from, so this one synthesizes nothing
itself); ``stage_seconds`` comes from the build's ``world.json``. Goals (issue 15):
8192^2 in <= 60 s and <= 4 GB; 30720^2 within 15 minutes and 4 GB. Sites above 80 Mpx
build out of core (illumination strips with a decimated far field,
:mod:`lunar_drake.science.strips`); ``--strip-px N`` forces that at any size.
``--compress zstd`` compresses the GeoTIFFs (a 30720^2 stack is 50 GB uncompressed).
Prints a table; writes JSON with --out.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import record_speed_index
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import record_speed_index


def site_for(size: int, resolution_m: float, seed: int, cache: Path) -> Path:
    """A synthesized site directory (built once per size/resolution/seed, in a child
    process: a 30720^2 synthesis peaks at several GB, which this process must not)."""
    from lunar_drake.errors import OutputError
    from lunar_drake.terrain.synth import SynthConfig

    # Bad sizes are refused here, in one line (the child would only print a traceback).
    SynthConfig(size_px=size, resolution_m=resolution_m, seed=seed)
    d = cache / f"site_{size}_{resolution_m:g}_{seed}"
    if not (d / "site.json").is_file():
        code = (
            "from lunar_drake.terrain.synth import SynthConfig, synthesize_site\n"
            f"cfg = SynthConfig(size_px={int(size)}, resolution_m={float(resolution_m)!r}, "
            f"seed={int(seed)}, center_lat_deg=-85.4, center_lon_deg=31.6)\n"
            f"synthesize_site(config=cfg, out_dir={str(d)!r}, progress=True, overview=False)\n"
        )
        if subprocess.run([sys.executable, "-c", code]).returncode != 0:
            raise OutputError(f"synthesizing the site {str(d)!r} failed (its error is above)")
    return d


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", type=int, default=2048, help="site side (px)")
    p.add_argument("--resolution", type=float, default=0.04, help="pixel (m)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--strip-px", type=int, default=0,
                   help="build out of core whatever the size, illumination strips of this "
                        "many rows (ThermalConfig.strip_px; default: out of core above "
                        "ThermalConfig.whole_max_mpx, 80 Mpx)")  # fmt: skip
    p.add_argument("--compress", default="none", choices=("none", "zstd", "deflate", "lzw"),
                   help="the GeoTIFFs' compression (WorldConfig.compress)")  # fmt: skip
    p.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "lunar_drake_bench"),
                   help="where synthesized sites are kept")  # fmt: skip
    p.add_argument("--out", default=None, help="write results as JSON here")
    args = p.parse_args(argv)
    if args.out:
        check_output_file(args.out)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    site = site_for(args.size, args.resolution, args.seed, cache)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        out = Path(tmp) / "world"
        cmd = [sys.executable, "-m", "lunar_drake.cli", "world", "build", str(site),
               "--out", str(out), "--workers", str(args.workers), "--no-progress"]  # fmt: skip
        if args.strip_px or args.compress != "none":
            cfg = Path(tmp) / "config.yaml"
            th = f"{{strip_px: {args.strip_px}, whole_max_mpx: 0}}" if args.strip_px else "{}"
            cfg.write_text(f"thermal: {th}\ncompress: {args.compress}\n")
            cmd += ["--config", str(cfg)]
        t0 = time.perf_counter()
        with tempfile.TemporaryFile("w+") as err:
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, text=True)
            _, status, usage = os.wait4(proc.pid, 0)  # this child's rusage alone
            proc.returncode = os.waitstatus_to_exitcode(status)
            seconds = time.perf_counter() - t0
            if proc.returncode != 0:
                err.seek(0)
                print(err.read(), file=sys.stderr)
                return proc.returncode
        peak_kb = usage.ru_maxrss
        world = json.loads((out / "world.json").read_text())
        output_bytes = sum(f.stat().st_size for f in out.iterdir())
    doc = {
        "size": args.size,
        "resolution_m": args.resolution,
        "seconds": round(seconds, 2),
        "peak_rss_mb": round(peak_kb / 1024.0, 1),
        "psr_fraction": world["psr_fraction"],
        "stage_seconds": world.get("stage_seconds", {}),
        "workers": args.workers,
        "strip_px": args.strip_px,
        "compress": args.compress,
        "output_gb": round(output_bytes / 1e9, 3),
        "machine": platform.platform(),
    }
    print(f"{'size':>8} {'pixel m':>8} {'seconds':>9} {'peak MB':>9} {'PSR %':>7}")
    print(f"{args.size:>8} {args.resolution:>8g} {doc['seconds']:>9.1f} "
          f"{doc['peak_rss_mb']:>9.0f} {100 * doc['psr_fraction']:>7.2f}")  # fmt: skip
    for stage, sec in doc["stage_seconds"].items():
        print(f"  {stage:<40} {sec:>7.1f} s")
    record_speed_index(doc)
    if args.out:
        atomic_write_text(args.out, json.dumps(doc, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks import run_main

    run_main(main, "world_model.py")
