"""Benchmark: Hapke shading and the camera sensor model on a 1280 x 960 frame.

    .venv/bin/python benchmarks/render_photometry.py --out bench_photometry.json

Cases (median of --repeat runs; the machine may be shared):

* hapke ``random``: independent random cos_i, cos_e, g per pixel (incoherent, worst case
  for branch prediction), float32 and float64, 1 and 2 worker threads;
* hapke ``scene``: a rough synthetic terrain seen by a camera with the Sun 7 deg above the
  horizon (coherent geometry, realistic);
* blended (Hapke + Lunar-Lambert limb blend) on ``scene``;
* sensor ``expose`` on a bright and a dim (exact-Poisson branch) frame.

Prints a table; writes JSON with --out.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from lunar_drake import rng
from lunar_drake.files import atomic_write_text, check_output_file
from lunar_drake.render import hapke as hk
from lunar_drake.render import sensor as sn

try:
    from benchmarks.speed_index import record_speed_index
except ImportError:  # run as a script: benchmarks/ itself is on sys.path
    from speed_index import record_speed_index

H, W = 960, 1280


def _time(fn, repeat):
    fn()
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def _random_geometry():
    g = np.random.default_rng(0)
    return g.uniform(-0.1, 1, (H, W)), g.uniform(-0.1, 1, (H, W)), g.uniform(0, np.pi, (H, W))


def _scene_geometry():
    """Per-pixel cosines for bumpy ground seen from 1.5 m with the Sun at 7 deg elevation."""
    g = np.random.default_rng(1)
    yy, xx = np.mgrid[0:H, 0:W]
    # view rays from a pinhole camera pitched 20 deg down (70 deg HFOV)
    f = (W / 2) / np.tan(np.radians(35))
    d = np.stack([(xx - W / 2) / f, np.ones_like(xx, float), -(yy - H / 2) / f], -1)
    pitch = np.radians(-20)
    rot = np.array(
        [[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]]
    )
    d = d @ rot.T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    # facet normals: tilted by smooth noise up to ~25 deg
    nx = np.cumsum(g.normal(0, 0.02, (H, W)), 1) * 0.05
    ny = np.cumsum(g.normal(0, 0.02, (H, W)), 0) * 0.05
    n = np.stack([nx, ny, np.ones_like(nx)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    sun = np.array(
        [np.cos(np.radians(7)) * 0.3, np.cos(np.radians(7)) * 0.95, np.sin(np.radians(7))]
    )
    sun /= np.linalg.norm(sun)
    view = -d
    cos_i = n @ sun
    cos_e = np.sum(n * view, -1)
    phase = np.arccos(np.clip(view @ sun, -1, 1))
    ground = d[..., 2] < -0.02  # sky pixels get NaN, as the ray caster would
    return (
        np.where(ground, cos_i, np.nan),
        np.where(ground, cos_e, np.nan),
        np.where(ground, phase, np.nan),
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--out", type=str, default="")
    a = p.parse_args(argv)
    if a.out:
        check_output_file(a.out, what="results JSON")
    rows = []
    rnd = _random_geometry()
    scene = _scene_geometry()
    for name, geo in (("random", rnd), ("scene", scene)):
        for dtype in (np.float32, np.float64):
            for workers in (1, 2):
                t = _time(
                    lambda geo=geo, dtype=dtype, workers=workers: hk.hapke_reflectance(
                        *geo, dtype=dtype, workers=workers
                    ),
                    a.repeat,
                )
                rows.append(
                    {
                        "case": f"hapke {name}",
                        "dtype": np.dtype(dtype).name,
                        "workers": workers,
                        "ms": t * 1e3,
                    }
                )
    t = _time(lambda: hk.blended_reflectance(*scene), a.repeat)
    rows.append({"case": "blended scene", "dtype": "float32", "workers": 1, "ms": t * 1e3})
    key = rng.stream_key(0, "camera/bench")
    bright = np.full((H, W), float(sn.radiance_from_i_over_f(0.1)))
    for name, L, t_exp in (("expose bright", bright, 1e-3), ("expose dim", bright * 5e-3, 1e-3)):
        t = _time(
            lambda L=L, t_exp=t_exp: sn.expose(L, exposure_s=t_exp, key=key, frame_index=0),
            a.repeat,
        )
        rows.append({"case": name, "dtype": "uint16", "workers": 1, "ms": t * 1e3})
    print(f"{'case':<16} {'dtype':<8} {'workers':>7} {'ms':>8}   ({W}x{H} px)")
    for r in rows:
        print(f"{r['case']:<16} {r['dtype']:<8} {r['workers']:>7} {r['ms']:>8.1f}")
    if a.out:
        result = {"width": W, "height": H, "repeat": a.repeat, "rows": rows}
        record_speed_index(result)
        atomic_write_text(a.out, json.dumps(result, indent=2), what="results JSON")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
