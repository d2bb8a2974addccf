"""The ground's a-priori map as a pre-flight product: what the ground is handed before
the mission, built outside the ground software. Pure numpy/scipy; no Drake.

A :class:`MapProduct` is a DEM window (m; row 0 north) with its pixel size, placement and
provenance. ``source`` says what it is:

* ``orbital`` (the default, DESIGN.md decision 9): what an orbital camera resolves. The
  rocks narrower than ``MapConfig.resolved_rock_m`` are taken out of the terrain first
  (their pixels in the site's rock mask are filled with the plane of the surface round
  them: :func:`remove_unresolved_rocks`), then the DEM is averaged over blocks of
  ``orbital_resolution_m`` and seeded white noise of ``orbital_noise_m`` is added.
  Craters, slopes and boulders wider than the limit stay.
* ``truth``: the site DEM itself, every rock in it -- an **oracle** for testing control
  and the link (:attr:`MapProduct.oracle`); every output that uses it says so.

Without a rock mask (an in-memory site, a plain DEM) the orbital product is the block
mean of the DEM as it is, rocks included, and :attr:`MapProduct.rocks_removed` is 0.
"""

from __future__ import annotations

import dataclasses as dc
import math

import numpy as np
from scipy import ndimage

from lunar_drake import rng
from lunar_drake.errors import ConfigError, OutOfBoundsError, OutOfRangeError, check_range


@dc.dataclass(frozen=True)
class MapProduct:
    """The ground's a-priori map (module docstring).

    Attributes:
        z: heights (m), row 0 north. resolution_m: pixel size (m).
        x0_m, y1_m: site coordinates of the west and north edges (m).
        source: ``orbital`` or ``truth`` (the oracle).
        noise_m: the noise added (m, 1 sigma; 0 for truth).
        resolved_rock_m: rocks narrower than this were taken out (m; 0 for truth).
        rocks_removed: how many rock regions were taken out.
        confirm_slope_deg: orbital cells steeper than this are lethal until stereo has
            seen them (0: trusted; not used with truth).
    """

    z: np.ndarray
    resolution_m: float
    x0_m: float
    y1_m: float
    source: str
    noise_m: float = 0.0
    resolved_rock_m: float = 0.0
    rocks_removed: int = 0
    confirm_slope_deg: float = 0.0

    @property
    def oracle(self) -> bool:
        """Whether this is the true terrain (not something a mission could have)."""
        return self.source == "truth"

    @property
    def shape(self) -> tuple:
        return self.z.shape

    def describe(self) -> dict:
        """Deterministic facts for summaries (no arrays)."""
        rows, cols = self.z.shape
        return {
            "map_source": self.source,
            "oracle": self.oracle,
            "resolution_m": float(self.resolution_m),
            "noise_m": float(self.noise_m),
            "resolved_rock_m": float(self.resolved_rock_m),
            "rocks_removed": int(self.rocks_removed),
            "bounds_m": [float(self.x0_m), float(self.x0_m + cols * self.resolution_m),
                         float(self.y1_m - rows * self.resolution_m), float(self.y1_m)],
        }  # fmt: skip


def remove_unresolved_rocks(z, rock_mask, *, resolution_m: float,
                            max_diameter_m: float) -> tuple[np.ndarray, int]:  # fmt: skip
    """(DEM, count): ``z`` with every rock narrower than ``max_diameter_m`` taken out.

    A rock is a connected region of ``rock_mask`` (8-connected); its width is the
    diameter of the disc of the same area. Its pixels, grown by one pixel (a stamp's
    rim), are replaced by the plane fitted (least squares) to the rock-free pixels of a
    ring ``_RING_PX`` pixels wide round them: exact on a planar surface (rocks a few
    pixels apart share their rings' pixels with the larger label). Pixels of wider
    rocks, and every other pixel, are unchanged.
    """
    z = np.asarray(z, np.float64)
    mask = np.asarray(rock_mask, bool)
    if mask.shape != z.shape:
        raise ConfigError(f"rock_mask has shape {mask.shape}; the DEM {z.shape}")
    check_range("max_diameter_m", max_diameter_m, 0.0, 1e4, unit=" m")
    eight = np.ones((3, 3), bool)
    labels, n = ndimage.label(mask, structure=eight)
    if n == 0 or max_diameter_m <= 0.0:
        return z.copy(), 0
    area_m2 = np.bincount(labels.ravel(), minlength=n + 1) * resolution_m**2
    small = 2.0 * np.sqrt(area_m2 / math.pi) < max_diameter_m
    small[0] = False
    # Each small rock's pixels grown by one (its label), and a ring round them (the
    # nearest small rock's label, 3 x 3 maxima: neighbours within a few pixels share).
    small_lab = np.where(small[labels], labels, 0)
    grown = ndimage.maximum_filter(small_lab, size=3)
    grown[labels > 0] = small_lab[labels > 0]  # a wide rock's pixels stay its own
    ring = ndimage.maximum_filter(grown, size=2 * _RING_PX + 1)
    ring[(labels > 0) | (grown > 0)] = 0
    # Planes z = a + b dr + c dc (about each rock's ring centroid) by least squares,
    # all rocks at once through their normal equations.
    rr, cc = np.nonzero(ring)
    k = ring[rr, cc]
    m = n + 1
    cnt = np.bincount(k, minlength=m).astype(np.float64)
    ok = cnt >= 3
    safe = np.maximum(cnt, 1.0)
    r_mean = np.bincount(k, rr, m) / safe
    c_mean = np.bincount(k, cc, m) / safe
    dr, dc_ = rr - r_mean[k], cc - c_mean[k]
    zz = z[rr, cc]
    a = np.zeros((m, 3, 3))
    b = np.zeros((m, 3))
    cols3 = (np.ones_like(dr), dr, dc_)
    for i in range(3):
        b[:, i] = np.bincount(k, cols3[i] * zz, m)
        for j in range(i, 3):
            a[:, i, j] = a[:, j, i] = np.bincount(k, cols3[i] * cols3[j], m)
    a[~ok] = np.eye(3)
    ok &= np.abs(np.linalg.det(a)) > 1e-9
    a[~ok] = np.eye(3)
    coef = np.linalg.solve(a, b[..., None])[..., 0]
    fr, fc = np.nonzero(grown)
    kf = grown[fr, fc]
    keep = ok[kf]  # a rock walled in by others keeps its heights
    fr, fc, kf = fr[keep], fc[keep], kf[keep]
    out = z.copy()
    out[fr, fc] = (coef[kf, 0] + coef[kf, 1] * (fr - r_mean[kf])
                   + coef[kf, 2] * (fc - c_mean[kf]))  # fmt: skip
    return out, int(np.count_nonzero(small))


#: Width (px) of the ring round a rock its plane is fitted to.
_RING_PX = 3


def _block_mean(a: np.ndarray, k: int) -> np.ndarray:
    r, c = (a.shape[0] // k) * k, (a.shape[1] // k) * k
    return a[:r, :c].reshape(r // k, k, c // k, k).mean(axis=(1, 3))


def orbital_dem(z, *, resolution_m: float, orbital_resolution_m: float, noise_m: float,
                seed: int) -> tuple:  # fmt: skip
    """(DEM, pixel size): ``z`` averaged over blocks of ``orbital_resolution_m`` plus
    seeded white noise of ``noise_m`` (m, 1 sigma; stream ``ground/orbital_map``)."""
    check_range("orbital_resolution_m", orbital_resolution_m, resolution_m, 1e4, unit=" m")
    check_range("noise_m", noise_m, 0.0, 100.0, unit=" m")
    k = max(1, round(orbital_resolution_m / resolution_m))
    coarse = _block_mean(np.asarray(z, np.float64), k)
    g = rng.generator(seed, "ground/orbital_map")
    return coarse + g.normal(0.0, noise_m, coarse.shape), resolution_m * k


def map_window(*, heightfield, points_xy, margin_m: float) -> tuple:
    """(row0, col0, rows, cols) of the site raster covering ``points_xy`` (site m) plus
    ``margin_m``, clipped to the site."""
    pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    if not np.isfinite(pts).all():
        raise OutOfRangeError(f"points_xy = {pts.tolist()!r} m must be finite site coordinates")
    b = heightfield.bounds
    res = heightfield.resolution_m
    lo = pts.min(axis=0) - margin_m
    hi = pts.max(axis=0) + margin_m
    col0 = max(0, math.floor((lo[0] - b.left) / res))
    col1 = min(heightfield.shape[1], math.ceil((hi[0] - b.left) / res))
    row0 = max(0, math.floor((b.top - hi[1]) / res))
    row1 = min(heightfield.shape[0], math.ceil((b.top - lo[1]) / res))
    if row1 - row0 < 2 or col1 - col0 < 2:
        raise OutOfBoundsError(
            f"points {pts.tolist()!r} m (margin {margin_m:g} m) lie off the site: "
            f"x in [{b.left:g}, {b.right:g}], y in [{b.bottom:g}, {b.top:g}] m"
        )
    return row0, col0, row1 - row0, col1 - col0


def make_map_product(*, heightfield, points_xy, map_config, seed: int,
                     rock_mask=None) -> MapProduct:  # fmt: skip
    """The ground's a-priori map around ``points_xy`` (start, goals; site m) as
    ``map_config`` (:class:`~lunar_drake.autonomy.costmap.MapConfig`) says (module
    docstring). ``rock_mask(row0, col0, rows, cols)`` reads the site's rock mask (bool)
    for a window, or None when the site has none; ``seed`` drives the orbital noise
    (the site's seed: the product exists before the mission)."""
    map_config.validate()
    row0, col0, rows, cols = map_window(heightfield=heightfield, points_xy=points_xy,
                                        margin_m=map_config.margin_m)  # fmt: skip
    z = np.asarray(heightfield.read_window(row0, col0, rows, cols), np.float64)
    b = heightfield.bounds
    res = float(heightfield.resolution_m)
    x0, y1 = b.left + col0 * res, b.top - row0 * res
    if map_config.source == "truth":
        return MapProduct(z=z, resolution_m=res, x0_m=x0, y1_m=y1, source="truth")
    limit = map_config.resolved_rock_m or 2.0 * map_config.orbital_resolution_m
    removed = 0
    if rock_mask is not None:
        z, removed = remove_unresolved_rocks(z, rock_mask(row0, col0, rows, cols),
                                             resolution_m=res, max_diameter_m=limit)  # fmt: skip
    z, res = orbital_dem(z, resolution_m=res, orbital_resolution_m=map_config.orbital_resolution_m,
                         noise_m=map_config.orbital_noise_m, seed=seed)  # fmt: skip
    return MapProduct(
        z=z, resolution_m=res, x0_m=x0, y1_m=y1, source="orbital",
        noise_m=map_config.orbital_noise_m, resolved_rock_m=limit if rock_mask is not None else 0.0,
        rocks_removed=removed, confirm_slope_deg=map_config.confirm_slope_deg,
    )  # fmt: skip


__all__ = ["MapProduct", "make_map_product", "map_window", "orbital_dem",
           "remove_unresolved_rocks"]  # fmt: skip
