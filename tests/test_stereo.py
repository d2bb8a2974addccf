"""Ground stereo: the rig calibration (OpenCV YAML) and SGBM matching, checked against
stereo pairs built here with a known disparity (warped by OpenCV's remap from a seeded
texture: independent of the matcher)."""

import math

import numpy as np
import pytest

from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.models.rover_description import krex2_rp
from lunar_drake.perception.calibration import StereoCalibration
from lunar_drake.perception.stereo import (
    StereoConfig,
    depth_error,
    match,
    num_disparities_for,
    to_8bit,
)
from lunar_drake.render.camera import CameraConfig


@pytest.fixture(scope="module")
def calib():
    return StereoCalibration.from_camera(
        camera=CameraConfig(width=320, height=240, fov_y_deg=45.0), description=krex2_rp()
    )


def _pair(calib, disparity_of_row, *, seed=1):
    """A textured left image and the right image seeing it with the given disparity per
    row (px): right(u, v) = left(u + d(v), v)."""
    import cv2

    rng = np.random.default_rng(seed)
    h, w = calib.height, calib.width
    tex = cv2.GaussianBlur(rng.uniform(0, 4095, (h, w + 200)), (0, 0), 1.2).astype(np.float32)
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    left = tex[:, :w]
    d = disparity_of_row(v).astype(np.float32)
    right = cv2.remap(tex, u + d, v, cv2.INTER_LINEAR)
    return left.astype(np.uint16), right.astype(np.uint16), d


def test_calibration_matches_the_camera_model_and_round_trips(calib, tmp_path):
    cam = CameraConfig(width=320, height=240, fov_y_deg=45.0)
    f = 0.5 * 240 / math.tan(math.radians(22.5))
    np.testing.assert_allclose(calib.K_left, [[f, 0, 159.5], [0, f, 119.5], [0, 0, 1]])
    assert calib.baseline_m == pytest.approx(krex2_rp().camera_baseline_m)
    assert calib.T[0] < 0  # the right camera is on the left camera's +x (image right)
    calib.write(tmp_path / "calibration.yaml")
    text = (tmp_path / "calibration.yaml").read_text()
    assert "K1: !!opencv-matrix" in text and "image_width: 320" in text
    back = StereoCalibration.read(tmp_path / "calibration.yaml")
    for name in ("K_left", "K_right", "dist_left", "dist_right", "R", "T"):
        np.testing.assert_array_equal(getattr(back, name), getattr(calib, name))
    assert (back.width, back.height) == (cam.width, cam.height)
    # The ideal rig (parallel axes, no distortion) rectifies to the identity.
    (m1x, m1y), (m2x, m2y), Q = calib.rectification()
    v, u = np.mgrid[0:240, 0:320]
    for mx, my in ((m1x, m1y), (m2x, m2y)):
        assert np.abs(mx - u).max() < 1e-6 and np.abs(my - v).max() < 1e-6
    # Q maps a disparity to Z = f B / d.
    X = Q @ np.array([160.0, 120.0, 10.0, 1.0])
    assert X[2] / X[3] == pytest.approx(calib.focal_px * calib.baseline_m / 10.0)
    with pytest.raises(ConfigError, match="does not exist"):
        StereoCalibration.read(tmp_path / "nope.yaml")
    (tmp_path / "garbage.yaml").write_text("garbage: [\n")
    with pytest.raises(ConfigError, match="is not OpenCV YAML"):
        StereoCalibration.read(tmp_path / "garbage.yaml")
    (tmp_path / "other.yaml").write_text("%YAML:1.0\n---\na: 1\n")
    with pytest.raises(ConfigError, match="has no 'K1'"):
        StereoCalibration.read(tmp_path / "other.yaml")


def test_sgbm_recovers_a_plane_and_its_depth(calib):
    """A fronto-parallel plane 4 m away: disparity f B / Z within 0.25 px (SGBM's 1/16 px
    steps lock towards whole pixels), depth within 1.5 %, points on the pinhole
    back-projection, the left border matched where its match is inside the right image."""
    Z = 4.0
    d_true = calib.focal_px * calib.baseline_m / Z
    left, right, _ = _pair(calib, lambda v: np.full_like(v, d_true))
    res = match(left, right, calib=calib, config=StereoConfig())
    n = res.num_disparities
    assert n == num_disparities_for(calib, 1.5) and n % 16 == 0
    # Left border: a pixel whose match would fall left of the right image is invalid,
    # the rest of the first n columns (which OpenCV alone leaves unmatched) is matched.
    assert not res.valid[:, : int(d_true)].any()
    assert res.valid[:, int(d_true) + 3 : n].mean() > 0.9
    inner = res.valid[:, n:]
    assert inner.mean() > 0.9
    assert np.nanmedian(res.disparity) == pytest.approx(d_true, abs=0.25)  # sub-pixel lock
    med, frac, count = depth_error(res, np.full(left.shape, Z))
    assert med < 1.5 and frac > 0.7 and count == left.size
    v, u = np.nonzero(res.valid)
    P = res.points[v, u]
    np.testing.assert_allclose(P[:, 0], (u - 159.5) * P[:, 2] / calib.focal_px, rtol=1e-5,
                               atol=1e-5)  # fmt: skip
    np.testing.assert_allclose(P[:, 1], (v - 119.5) * P[:, 2] / calib.focal_px, rtol=1e-5,
                               atol=1e-5)  # fmt: skip
    assert res.cloud().shape == (int(res.valid.sum()), 3)


def test_sgbm_follows_a_slanted_ground_plane(calib):
    """Disparity growing down the image (a ground plane seen from a mast): each row's
    median within 0.25 px of the truth."""
    left, right, d = _pair(calib, lambda v: 8.0 + 0.12 * v, seed=3)
    res = match(left, right, calib=calib, config=StereoConfig())
    errs = [abs(np.nanmedian(res.disparity[r]) - d[r, 0]) for r in range(10, 230, 20)
            if res.valid[r].sum() > 50]  # fmt: skip
    assert len(errs) >= 8 and max(errs) < 0.25


def test_symmetric_matching_removes_the_single_pass_bias_on_a_ground_plane(calib):
    """On a plane whose disparity grows 0.3 px a row down the image (a ground plane
    near the mast), OpenCV's single-pass SGBM, whose paths all come from the rows above,
    reads disparities low (toward the rows above); matched upside down as well, the
    median error is within 0.05 px of the known disparity."""
    left, right, d = _pair(calib, lambda v: 8.0 + 0.3 * v, seed=3)
    one = match(left, right, calib=calib, config=StereoConfig(mode="sgbm", symmetric=False))
    both = match(left, right, calib=calib, config=StereoConfig(mode="sgbm"))
    bias_one = float(np.median((one.disparity - d)[one.valid]))
    bias_both = float(np.median((both.disparity - d)[both.valid]))
    assert bias_one < -0.1 and abs(bias_both) < 0.05
    assert both.valid.mean() > 0.6


def test_the_stretch_is_shared_and_bad_input_is_refused(calib):
    a = np.full((4, 4), 100, np.uint16)
    b = np.full((4, 4), 300, np.uint16)
    a8, b8 = to_8bit(a, b, low_percentile=0.0, high_percentile=100.0)
    assert a8.max() == 0 and b8.min() == 255  # one scale for both
    with pytest.raises(ConfigError, match="do not match the calibration"):
        match(a, b, calib=calib, config=StereoConfig())
    with pytest.raises(ConfigError, match="block_size = 4 must be odd"):
        StereoConfig(block_size=4).validate()
    with pytest.raises(ConfigError, match="mode"):
        StereoConfig(mode="bm").validate()
    with pytest.raises(OutOfRangeError, match="min_depth_m"):
        StereoConfig(min_depth_m=0.0).validate()


def test_deep_shadow_is_not_matched(calib):
    """The lower half of the view 500 times darker (a shadow lit by Earthshine): below
    min_signal of the stretch's high code it gives no points; with min_signal 0 it does."""
    d_true = calib.focal_px * calib.baseline_m / 4.0
    left, right, _ = _pair(calib, lambda v: np.full_like(v, d_true))
    dark = np.ones(left.shape)
    dark[120:] = 0.002
    left = (left * dark).astype(np.uint16)
    right = (right * dark).astype(np.uint16)
    res = match(left, right, calib=calib, config=StereoConfig())
    n = res.num_disparities
    assert res.valid[:110, n:].mean() > 0.8 and not res.valid[125:].any()
    # With min_signal 0 a single pass fills the dark half (codes 0 after the stretch:
    # no texture) by propagating the rows above; the symmetric pass finds nothing there.
    res0 = match(left, right, calib=calib, config=StereoConfig(min_signal=0.0, symmetric=False))
    assert res0.valid[125:].any()
    res1 = match(left, right, calib=calib, config=StereoConfig(min_signal=0.0))
    assert not res1.valid[125:].any()
