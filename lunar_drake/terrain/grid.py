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
