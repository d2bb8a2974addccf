"""Stereo on the ground: rectified 12-bit frames -> OpenCV semi-global matching ->
disparity, validity and a point cloud in the left camera frame. Pure (numpy + OpenCV).

1. **8-bit**: both raw frames get the same linear stretch, from the ``low_percentile``
   to the ``high_percentile`` of their combined codes, to 0-255 (matching needs the two
   images on one scale; a shadowed scene would otherwise use a few grey levels).
2. **Rectification** from the calibration
   (:meth:`~lunar_drake.perception.calibration.StereoCalibration.rectification`).
3. **StereoSGBM** (``cv2.StereoSGBM``; P1 = 8 n b^2, P2 = 32 n b^2 as OpenCV suggests)
   with ``num_disparities`` rounded up to a multiple of 16 from the nearest depth
   wanted (``min_depth_m``): ``d_max = f B / min_depth``.
   With ``symmetric`` (the default), the frames are matched a second time upside down
   and the two disparities averaged: OpenCV's single-pass modes aggregate only along
   paths running down the image or along rows, which biases a ground plane's
   disparities low (:class:`StereoConfig`).
4. **Validity**: (with ``symmetric``, both passes valid and within 1 px of each other)
   OpenCV's own invalid marks, left-right consistency
   (``disp12_max_diff``), uniqueness and speckle filtering. Both images are padded on
   the left by ``num_disparities`` columns before matching (OpenCV leaves that border
   of its input unmatched), so the left border keeps every point whose match lies in
   the right image (``u - d >= 0``); only nearer ones there are invalid.
5. **Depth** and points through the rectification's ``Q``: ``(X, Y, Z, W) = Q (u, v,
   d, 1)``; for the ideal rig ``Z = f B / d`` (m, along the optical axis) and ``(X, Y)
   = ((u - cx) Z / f, (v - cy) Z / f)``, in the rectified left frame (x right, y down,
   z forward).
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc
import math

import numpy as np

from lunar_drake.errors import ConfigError, check_range
from lunar_drake.perception.calibration import StereoCalibration

MODES = ("sgbm", "hh", "3way")


@dc.dataclass
class StereoConfig:
    """OpenCV StereoSGBM settings (the ground's ``stereo``).

    Attributes:
        min_depth_m: nearest depth to match (m): sets the disparity range.
        block_size: matching block (odd, px).
        uniqueness_ratio: margin (%) by which the best match must beat the second.
        speckle_window_size: largest speckle region removed (px; 0 off).
        speckle_range: disparity variation within a connected region (px).
        disp12_max_diff: left-right consistency tolerance (px; < 0 off).
        pre_filter_cap: clip of the prefiltered image derivative.
        mode: ``sgbm`` (5 directions), ``hh`` (8 directions, full), ``3way``.
        symmetric: also match both frames turned upside down and keep the mean of the two
            disparities where both are valid and agree within 1 px. OpenCV's single-pass
            modes (``sgbm``, ``3way``) aggregate costs only along paths that run down the
            image or along the row, none upward; on a ground plane, whose disparity shrinks
            upward, their smoothness term pulls every pixel toward its upper neighbours'
            smaller disparity: on the default site at 640 x 480, ``sgbm`` alone measures
            0.13-0.44 px short (1-2 % long in depth at 5-9 m, and visual odometry as long),
            ``3way`` 0.05-0.17 px; either one with its flipped twin is within 0.05 px, as
            ``hh`` is, in about half ``hh``'s time for ``3way``. Ignored by ``hh`` (its
            eight paths are symmetric already).
        low_percentile, high_percentile: the 8-bit stretch (percent of codes).
        min_signal: pixels of the left frame darker than this fraction of the stretch's
            high code are not matched (deep shadow: noise, wrong disparities that agree
            from one frame to the next); 0 keeps them.
    """

    min_depth_m: float = 1.5
    block_size: int = 5
    uniqueness_ratio: int = 10
    speckle_window_size: int = 100
    speckle_range: int = 2
    disp12_max_diff: int = 1
    pre_filter_cap: int = 31
    mode: str = "3way"
    symmetric: bool = True
    low_percentile: float = 0.5
    high_percentile: float = 99.5
    min_signal: float = 0.02

    def validate(self) -> None:
        """Checks every field; errors name the field."""
        check_range("min_depth_m", self.min_depth_m, 0.05, 1000.0, unit=" m")
        if self.block_size % 2 == 0:
            raise ConfigError(f"block_size = {self.block_size!r} must be odd")
        check_range("block_size", self.block_size, 1, 31, unit=" px")
        check_range("uniqueness_ratio", self.uniqueness_ratio, 0, 100)
        check_range("speckle_window_size", self.speckle_window_size, 0, 10000, unit=" px")
        check_range("speckle_range", self.speckle_range, 0, 1000, unit=" px")
        check_range("disp12_max_diff", self.disp12_max_diff, -1, 1000, unit=" px")
        check_range("pre_filter_cap", self.pre_filter_cap, 1, 63)
        if self.mode not in MODES:
            raise ConfigError(f"mode = {self.mode!r} is unknown; choose one of {MODES}")
        check_range("low_percentile", self.low_percentile, 0.0, 50.0)
        check_range("high_percentile", self.high_percentile, 50.0, 100.0)
        check_range("min_signal", self.min_signal, 0.0, 1.0)


@dc.dataclass(frozen=True)
class StereoResult:
    """One stereo pair matched.

    Attributes:
        disparity: (H, W) float32 px in the rectified left image (NaN where invalid).
        valid: (H, W) bool. depth_m: (H, W) float32 Z (m; NaN where invalid).
        points: (H, W, 3) float32 (X, Y, Z) m in the rectified left camera frame.
        num_disparities: the disparity range searched (px).
        left_8bit: (H, W) uint8, the rectified left image that was matched (None if
            not kept).
    """

    disparity: np.ndarray
    valid: np.ndarray
    depth_m: np.ndarray
    points: np.ndarray
    num_disparities: int
    left_8bit: np.ndarray | None = None

    def cloud(self) -> np.ndarray:
        """The valid points (N, 3) (m, left camera frame)."""
        return self.points[self.valid]

    def cloud_intensity(self) -> np.ndarray:
        """The rectified left image's value (0..1) at each point of :meth:`cloud`."""
        if self.left_8bit is None:
            raise ConfigError("this StereoResult kept no left image")
        return self.left_8bit[self.valid].astype(np.float64) / 255.0


def stretch_limits(left, right, *, low_percentile: float, high_percentile: float):
    """(low, high) codes of the shared 8-bit stretch of both frames."""
    both = np.concatenate([np.asarray(left).ravel(), np.asarray(right).ravel()])
    lo, hi = np.percentile(both, [low_percentile, high_percentile])
    return float(lo), float(hi)


def to_8bit(left, right, *, low_percentile: float, high_percentile: float, limits=None):
    """Both frames mapped to uint8 by one linear stretch (see the module docstring);
    ``limits`` (low, high) if already known."""
    a = np.asarray(left, np.float64)
    b = np.asarray(right, np.float64)
    lo, hi = limits or stretch_limits(a, b, low_percentile=low_percentile,
                                      high_percentile=high_percentile)  # fmt: skip
    scale = 255.0 / max(hi - lo, 1.0)

    def conv(x):
        return np.clip(np.rint((x - lo) * scale), 0, 255).astype(np.uint8)

    return conv(a), conv(b)


def num_disparities_for(calib: StereoCalibration, min_depth_m: float) -> int:
    """The disparity range (a multiple of 16, px) that reaches ``min_depth_m``."""
    d_max = calib.focal_px * calib.baseline_m / min_depth_m
    return max(16, 16 * math.ceil(d_max / 16.0))


def match(left_raw, right_raw, *, calib: StereoCalibration, config: StereoConfig) -> StereoResult:
    """Matches one stereo pair of raw frames (any unsigned codes, same size as the
    calibration)."""
    import cv2

    config.validate()
    L = np.asarray(left_raw)
    Rr = np.asarray(right_raw)
    if L.shape != (calib.height, calib.width) or Rr.shape != L.shape:
        raise ConfigError(
            f"frames {L.shape} and {Rr.shape} do not match the calibration's "
            f"{calib.height} x {calib.width} px"
        )
    limits = stretch_limits(L, Rr, low_percentile=config.low_percentile,
                            high_percentile=config.high_percentile)  # fmt: skip
    l8, r8 = to_8bit(L, Rr, low_percentile=config.low_percentile,
                     high_percentile=config.high_percentile, limits=limits)  # fmt: skip
    (m1x, m1y), (m2x, m2y), Q = calib.rectification()
    l8 = cv2.remap(l8, m1x, m1y, cv2.INTER_LINEAR)
    r8 = cv2.remap(r8, m2x, m2y, cv2.INTER_LINEAR)
    n = num_disparities_for(calib, config.min_depth_m)
    b = config.block_size
    mode = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
            "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY}[config.mode]  # fmt: skip
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=n, blockSize=b, P1=8 * b * b, P2=32 * b * b,
        disp12MaxDiff=config.disp12_max_diff, preFilterCap=config.pre_filter_cap,
        uniquenessRatio=config.uniqueness_ratio, speckleWindowSize=config.speckle_window_size,
        speckleRange=config.speckle_range, mode=mode,
    )  # fmt: skip
    # Padded on the left by the disparity range, so that SGBM searches every column
    # (OpenCV leaves the first ``n`` columns unmatched); a match must then land inside
    # the right image (u - d >= 0).
    pad = cv2.copyMakeBorder

    def disparity(a, b):
        raw = sgbm.compute(pad(a, 0, 0, n, 0, cv2.BORDER_REPLICATE),
                           pad(b, 0, 0, n, 0, cv2.BORDER_REPLICATE))[:, n:]  # fmt: skip
        return raw.astype(np.float32) / 16.0, raw > 0

    disp, valid = disparity(l8, r8)
    if config.symmetric and config.mode != "hh":
        # Paths from below as well as from above (see StereoConfig.symmetric).
        up, up_valid = disparity(np.ascontiguousarray(l8[::-1]), np.ascontiguousarray(r8[::-1]))
        up, up_valid = up[::-1], up_valid[::-1]
        valid &= up_valid & (np.abs(disp - up) <= 1.0)
        disp = np.float32(0.5) * (disp + up)
    valid &= np.arange(calib.width)[None, :] - disp >= 0.0
    if config.min_signal > 0.0:  # deep shadow: too little light to match
        left_rect = cv2.remap(L.astype(np.float32), m1x, m1y, cv2.INTER_LINEAR)
        valid &= left_rect >= config.min_signal * limits[1]
    disp = np.where(valid, disp, np.nan).astype(np.float32)
    # Through the rectification's Q (the rectified camera, whatever the rig):
    # [X Y Z W] = Q [u v d 1], points (X, Y, Z) / W.
    v, u = np.mgrid[0 : calib.height, 0 : calib.width].astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = Q[3, 2] * disp + Q[3, 3]
        pts = np.stack(
            [(u + Q[0, 3]) / w, (v + Q[1, 3]) / w, np.broadcast_to(Q[2, 3], disp.shape) / w],
            axis=-1,
        ).astype(np.float32)
    Z = pts[..., 2]
    return StereoResult(disparity=disp, valid=valid, depth_m=Z, points=pts, num_disparities=n,
                        left_8bit=l8)  # fmt: skip


def depth_error(result: StereoResult, true_depth_m, *, near_m: float = 2.0, far_m: float = 10.0):
    """Against a true depth image (m along the optical axis, inf/0 = none): over pixels
    with a true depth in [near_m, far_m], the median absolute depth error (% of the
    true depth) of the valid ones and the valid fraction. Returns (median %, valid
    fraction, pixels in range)."""
    t = np.asarray(true_depth_m, np.float64)
    inside = np.isfinite(t) & (t >= near_m) & (t <= far_m)
    n = int(inside.sum())
    if n == 0:
        return math.nan, math.nan, 0
    ok = inside & result.valid
    if not ok.any():
        return math.nan, 0.0, n
    err = np.abs(result.depth_m[ok] - t[ok]) / t[ok]
    return float(100.0 * np.median(err)), float(ok.sum() / n), n


__all__ = [
    "MODES",
    "StereoConfig",
    "StereoResult",
    "depth_error",
    "match",
    "num_disparities_for",
    "stretch_limits",
    "to_8bit",
]
