"""Benchmark: bake a terrain lightmap (paper section 5) and compare with the brute force.

    .venv/bin/python benchmarks/lightmap.py --out bench_lightmap.json
    .venv/bin/python benchmarks/lightmap.py --size 2048 --out small.json   # quick

Measures (one run each; the machine is shared, so repeat and quote medians):

* bake: seconds to compute the lightmap of a ``--size``^2 fractal DEM (generated in
  memory with lunar_drake.terrain.fractal: a coarse spectral fractal upscaled by
  diamond-square, 4 cm pixels by default; generation is not timed) under a low Sun
  (``--el`` 5 deg), for each ``--tile`` setting (default: the library default 4096, and
  one whole-grid tile), with ``--workers`` threads. Goal: <= 60 s for 8192^2.
* ratio: on a ``--crop``^2 crop (512), the fast lightmap's time against the brute-force
  reference (280 rays per cell marched over the bilinear surface). The brute force is
  timed on ``--bf-pixels`` random cells and extrapolated to the crop (it is linear in the
  number of cells; 0 = all cells, slow). Goal: >= 100x. Also reports the agreement on
  those cells (99th percentile, mean and max |difference| of the lit fraction).

Prints a table; writes JSON with --out.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time

from lunar_drake.files import atomic_write_text, check_output_file

try:
    from benchmarks.speed_index import record_speed_index
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import record_speed_index


def make_dem(size: int, res: float, seed: int, factor: int = 128):
    import numpy as np

    from lunar_drake import rng
    from lunar_drake.terrain.fractal import FractalParams, coarse_fractal, upscale_dem

    factor = min(factor, size)
    params = FractalParams()
    n = -(-size // factor)
    coarse = coarse_fractal(
        (n, n),
        resolution_m=res * factor,
        rng=rng.generator(seed, "bench/lightmap/coarse"),
        params=params,
    )
    z = upscale_dem(
        coarse,
        factor=factor,
        key=rng.stream_key(seed, "bench/lightmap/high"),
        params=params,
        coarse_resolution_m=res * factor,
    )
    return np.ascontiguousarray(z[:size, :size])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", type=int, default=8192, help="DEM side (px)")
    p.add_argument("--resolution", type=float, default=0.04, help="m per pixel")
    p.add_argument("--az", type=float, default=250.0, help="Sun azimuth (deg)")
    p.add_argument("--el", type=float, default=5.0, help="Sun elevation (deg)")
    p.add_argument(
        "--tile",
        type=int,
        action="append",
        default=None,
        help="tile_px to time (repeatable; default 4096 and the whole grid)",
    )
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--crop", type=int, default=512)
    p.add_argument("--bf-pixels", type=int, default=1024)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", default=None, help="write results JSON here")
    args = p.parse_args(argv)
    if args.out:
        check_output_file(args.out, what="results JSON")

    import numpy as np

    from lunar_drake.render.horizon import HorizonMask
    from lunar_drake.render.lightmap import lightmap, lightmap_bruteforce

    t0 = time.perf_counter()
    z = make_dem(args.size, args.resolution, args.seed)
    gen_s = time.perf_counter() - t0
    relief = float(z.max() - z.min())
    kw = dict(
        sun_azimuth_deg=args.az,
        sun_elevation_deg=args.el,
        resolution_m=args.resolution,
        horizon_mask=HorizonMask.none(),
    )
    tiles = args.tile or [4096, args.size]
    bakes = []
    ref = None
    for tile in tiles:
        t0 = time.perf_counter()
        L = lightmap(z, tile_px=tile, workers=args.workers, **kw)
        dt = time.perf_counter() - t0
        same = None if ref is None else bool(np.array_equal(L, ref))
        ref = L if ref is None else ref
        bakes.append(
            {
                "tile_px": tile,
                "seconds": dt,
                "mpix_per_s": z.size / dt / 1e6,
                "lit_mean": float(np.nanmean(L)),
                "partial_fraction": float(np.mean((L > 0) & (L < 1))),
                "identical_to_first": same,
            }
        )
        del L

    # Speed ratio and agreement on a crop.
    c0 = (args.size - args.crop) // 2
    zc = np.ascontiguousarray(z[c0 : c0 + args.crop, c0 : c0 + args.crop])
    t0 = time.perf_counter()
    Lc = lightmap(zc, workers=args.workers, **kw)
    fast_s = time.perf_counter() - t0
    n_all = zc.size
    if args.bf_pixels and args.bf_pixels < n_all:
        idx = np.random.default_rng(0).choice(n_all, size=args.bf_pixels, replace=False)
    else:
        idx = np.arange(n_all)
    rows, cols = np.divmod(idx, args.crop)
    t0 = time.perf_counter()
    B = lightmap_bruteforce(zc, pixels=(rows, cols), **kw)
    bf_s = time.perf_counter() - t0
    bf_full_s = bf_s * n_all / idx.size
    err = np.abs(Lc[rows, cols] - B)
    result = {
        "machine": {"python": sys.version.split()[0], "platform": platform.platform()},
        "dem": {
            "size_px": args.size,
            "resolution_m": args.resolution,
            "relief_m": relief,
            "generate_s": gen_s,
        },
        "sun": {"azimuth_deg": args.az, "elevation_deg": args.el},
        "workers": args.workers,
        "bake": bakes,
        "crop": {
            "size_px": args.crop,
            "fast_s": fast_s,
            "bruteforce_pixels": int(idx.size),
            "bruteforce_s": bf_s,
            "bruteforce_full_crop_s_extrapolated": bf_full_s,
            "speed_ratio": bf_full_s / fast_s,
            "abs_diff_p99": float(np.percentile(err, 99)),
            "abs_diff_mean": float(err.mean()),
            "abs_diff_max": float(err.max()),
            "partial_fraction_bruteforce": float(np.mean((B > 0) & (B < 1))),
        },
    }
    print(
        f"DEM {args.size}^2 at {args.resolution} m (relief {relief:.2f} m, generated in "
        f"{gen_s:.1f} s); Sun az {args.az} deg, el {args.el} deg; {args.workers} workers"
    )
    print(f"{'bake':<28s} {'seconds':>9s} {'Mpx/s':>8s} {'lit':>7s} {'partial':>8s}")
    for b in bakes:
        name = f"tile_px={b['tile_px']}"
        print(
            f"{name:<28s} {b['seconds']:9.2f} {b['mpix_per_s']:8.2f} {b['lit_mean']:7.3f} "
            f"{b['partial_fraction']:8.3f}"
            + ("" if b["identical_to_first"] is None else f"  identical: {b['identical_to_first']}")
        )
    c = result["crop"]
    print(
        f"crop {args.crop}^2: fast {c['fast_s']:.3f} s; brute force {c['bruteforce_s']:.1f} s "
        f"on {c['bruteforce_pixels']} cells -> {c['bruteforce_full_crop_s_extrapolated']:.0f} s "
        f"for the crop; ratio {c['speed_ratio']:.0f}x"
    )
    print(
        f"agreement on those cells: |diff| p99 {c['abs_diff_p99']:.4f}, mean "
        f"{c['abs_diff_mean']:.4f}, max {c['abs_diff_max']:.3f} "
        f"(penumbra cells {c['partial_fraction_bruteforce']:.1%})"
    )
    record_speed_index(result)
    if args.out:
        atomic_write_text(args.out, json.dumps(result, indent=2), what="results JSON")
    return 0


if __name__ == "__main__":
    sys.exit(main())
