"""Pixel <-> site-coordinate helpers for the conventions in :mod:`lunar_drake.terrain`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GridSpec:
    """Geometry of a site grid.

    Attributes:
        nrows, ncols: grid size (pixels).
        resolution_m: pixel size (m).
    """

    nrows: int
    ncols: int
    resolution_m: float

    @property
    def width_m(self) -> float:
        return self.ncols * self.resolution_m

    @property
    def height_m(self) -> float:
        return self.nrows * self.resolution_m

    @property
    def area_m2(self) -> float:
        return self.width_m * self.height_m

    @property
    def x_min(self) -> float:
        return -0.5 * self.width_m

    @property
    def y_max(self) -> float:
        return 0.5 * self.height_m

    def pixel_centers(self, row0: int, col0: int, nrows: int, ncols: int):
        """Site x (ncols,) and y (nrows,) of the pixel centres of a window (m)."""
        res = self.resolution_m
        x = (np.arange(col0, col0 + ncols) + 0.5 - 0.5 * self.ncols) * res
        y = (0.5 * self.nrows - np.arange(row0, row0 + nrows) - 0.5) * res
        return x, y

    def to_pixel(self, x, y):
        """Fractional (row, col) of site points, so that a centre maps to an integer."""
        res = self.resolution_m
        col = np.asarray(x, dtype=float) / res + 0.5 * self.ncols - 0.5
        row = 0.5 * self.nrows - 0.5 - np.asarray(y, dtype=float) / res
        return row, col


def window_batches(r_lo, r_hi, c_lo, c_hi, *, nrows: int, ncols: int, classes, chunk_pixels: int):
    """Groups per-object pixel boxes ``[r_lo, r_hi) x [c_lo, c_hi)`` of a tile into
    batches of equal padded size, for one elementwise kernel per batch.

    Returns ``(big, batches)``: ``big`` are the indices whose box exceeds the largest
    size class (the caller handles them one by one); ``batches`` yields
    ``(members, rows, cols)`` with ``rows`` (n, hh) and ``cols`` (n, ww) the pixel indices
    of each member's window of the class size from its box's low corner, clamped into
    the tile (duplicated edge pixels are computed but must not be written). Batching
    never changes a value: a pixel's result does not depend on its batch.
    """
    classes = np.asarray(classes)
    hcls = np.searchsorted(classes, np.asarray(r_hi) - r_lo)  # first class >= rows
    wcls = np.searchsorted(classes, np.asarray(c_hi) - c_lo)
    big = (hcls == classes.size) | (wcls == classes.size)

    def batches():
        group = np.where(big, -1, hcls * classes.size + wcls)
        for g in np.unique(group[~big]):
            members = np.flatnonzero(group == g)
            hh, ww = int(classes[g // classes.size]), int(classes[g % classes.size])
            chunk = max(1, chunk_pixels // (hh * ww))
            for k0 in range(0, members.size, chunk):
                mm = members[k0 : k0 + chunk]
                cols = np.minimum(c_lo[mm][:, None] + np.arange(ww), ncols - 1)
                rows = np.minimum(r_lo[mm][:, None] + np.arange(hh), nrows - 1)
                yield mm, rows, cols

    return np.flatnonzero(big), batches()
