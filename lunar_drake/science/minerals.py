"""Hydrogen-bearing minerals and minerals: seeded, tile-invariant fractal noise.

Value noise (the lattice flavour of Perlin's): at each octave of scale ``L`` (m), a
uniform value per lattice node from :func:`lunar_drake.rng.hash_uniform` keyed by (seed,
layer, octave) and the node's *global* integer position, blended with the quintic
fade ``6t^5 - 15t^4 + 10t^3``; octaves add with weights ``L / L_0`` (coarse ones
dominate). A cell's value depends only on its global position, so tiles agree
byte for byte. The sum is standardised by its exact variance (uniform nodes: 1/12 per
node weight) and mapped log-normally.
"""

from __future__ import annotations

import numpy as np

from lunar_drake import rng
from lunar_drake.science.config import MINERALS, MineralConfig


def _fade(t: np.ndarray) -> np.ndarray:
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def value_noise(key: int, *, rows, cols, resolution_m: float, scale_m: float) -> np.ndarray:
    """Value noise in [0, 1) at global cells ``rows`` x ``cols`` (1-D integer arrays) for
    lattice spacing ``scale_m``."""
    y = (np.asarray(rows, np.float64) + 0.5) * resolution_m / scale_m
    x = (np.asarray(cols, np.float64) + 0.5) * resolution_m / scale_m
    iy, ix = np.floor(y).astype(np.int64), np.floor(x).astype(np.int64)
    fy, fx = _fade(y - iy)[:, None], _fade(x - ix)[None, :]
    # Node values on the lattice covering the window, then gathered per cell.
    ny0, nx0 = int(iy.min()), int(ix.min())
    ni, nj = np.meshgrid(
        np.arange(ny0, int(iy.max()) + 2), np.arange(nx0, int(ix.max()) + 2), indexing="ij"
    )
    nodes = rng.hash_uniform(key, ni, nj)
    ry, cx = iy - ny0, ix - nx0

    def node(di, dj):
        return nodes[np.ix_(ry + di, cx + dj)]

    top = node(0, 0) * (1 - fx) + node(0, 1) * fx
    bottom = node(1, 0) * (1 - fx) + node(1, 1) * fx
    return top * (1 - fy) + bottom * fy


def fractal_noise(
    seed: int,
    name: str,
    *,
    row0: int,
    col0: int,
    nrows: int,
    ncols: int,
    resolution_m: float,
    scales_m,
) -> np.ndarray:
    """Zero-mean, roughly unit-variance fractal value noise on a window of the global grid."""
    rows = np.arange(row0, row0 + nrows)
    cols = np.arange(col0, col0 + ncols)
    total = np.zeros((nrows, ncols))
    weights = [s / scales_m[0] for s in scales_m]
    for k, (s, w) in enumerate(zip(scales_m, weights, strict=True)):
        key = rng.stream_key(seed, f"science/{name}/octave{k}")
        total += w * (
            value_noise(key, rows=rows, cols=cols, resolution_m=resolution_m, scale_m=s) - 0.5
        )
    # Variance of a node value is 1/12; blending lowers it -- use the node variance as a
    # conservative unit (values stay within a few units).
    return total / np.sqrt(sum(w * w for w in weights) / 12.0)


def h_minerals_ppm(
    seed: int, *, window, resolution_m: float, config: MineralConfig | None = None
) -> np.ndarray:
    """Hydrogen in hydrogen-bearing minerals (ppm) on ``window = (row0, col0, nrows,
    ncols)``: ``h_mean_ppm exp(h_amplitude n - h_amplitude^2 / 2)``."""
    cfg = config or MineralConfig()
    n = fractal_noise(
        seed,
        "h_minerals",
        row0=window[0],
        col0=window[1],
        nrows=window[2],
        ncols=window[3],
        resolution_m=resolution_m,
        scales_m=cfg.scales_m,
    )
    a = cfg.h_amplitude
    return cfg.h_mean_ppm * np.exp(a * n - 0.5 * a * a)


def minerals_wt_pct(
    seed: int, *, window, resolution_m: float, config: MineralConfig | None = None
) -> np.ndarray:
    """``(len(MINERALS), nrows, ncols)`` wt%: each mineral's mean abundance times a
    log-normal noise, renormalised to sum to 100."""
    cfg = config or MineralConfig()
    a = cfg.mineral_amplitude
    bands = []
    for name, mean in zip(MINERALS, cfg.abundances_wt_pct, strict=True):
        n = fractal_noise(
            seed,
            f"mineral/{name}",
            row0=window[0],
            col0=window[1],
            nrows=window[2],
            ncols=window[3],
            resolution_m=resolution_m,
            scales_m=cfg.scales_m,
        )
        bands.append(mean * np.exp(a * n))
    out = np.stack(bands)
    return 100.0 * out / out.sum(axis=0)


__all__ = ["fractal_noise", "h_minerals_ppm", "minerals_wt_pct", "value_noise"]
