"""The mast stereo rig's calibration, as operations would hold it: intrinsics from the
camera model, extrinsics from the mast geometry, written and read as an OpenCV-style
YAML file (``cv2.FileStorage``). Pure (numpy + OpenCV); no Drake.

Frames follow OpenCV (and Drake's camera convention): x to image right, y down, z along
the optical axis. The right camera sits ``baseline_m`` to the left camera's +x, with
parallel axes (the model's cameras share the mast head), so ``R = I`` and
``T = (-baseline, 0, 0)`` (``x_right = R x_left + T``). The lenses are ideal pinholes:
zero distortion.
"""

from __future__ import annotations

import dataclasses as dc
from pathlib import Path

import numpy as np

from lunar_drake.errors import ConfigError


@dc.dataclass(frozen=True)
class StereoCalibration:
    """A calibrated stereo pair.

    Attributes:
        width, height: image size (px).
        K_left, K_right: 3 x 3 camera matrices (px).
        dist_left, dist_right: OpenCV distortion coefficients (5,).
        R: 3 x 3 rotation and T (3,) translation (m) from the left camera frame to the
            right's (``x_right = R x_left + T``).
    """

    width: int
    height: int
    K_left: np.ndarray
    K_right: np.ndarray
    dist_left: np.ndarray
    dist_right: np.ndarray
    R: np.ndarray
    T: np.ndarray

    @property
    def baseline_m(self) -> float:
        """Distance between the camera centres (m)."""
        return float(np.linalg.norm(self.T))

    @property
    def focal_px(self) -> float:
        """The left camera's horizontal focal length (px)."""
        return float(self.K_left[0, 0])

    @classmethod
    def from_camera(cls, *, camera, description) -> StereoCalibration:
        """From the scenario's ``sensors.camera`` (a
        :class:`~lunar_drake.render.camera.CameraConfig`) and the rover description
        (``camera_baseline_m``)."""
        p = camera.pinhole()
        K = np.array([[p.fx, 0.0, p.cx], [0.0, p.fy, p.cy], [0.0, 0.0, 1.0]])
        return cls(
            width=int(p.width),
            height=int(p.height),
            K_left=K,
            K_right=K.copy(),
            dist_left=np.zeros(5),
            dist_right=np.zeros(5),
            R=np.eye(3),
            T=np.array([-float(description.camera_baseline_m), 0.0, 0.0]),
        )

    def write(self, path: str | Path) -> None:
        """Writes an OpenCV-style YAML calibration (``image_width``, ``image_height``,
        ``K1``, ``D1``, ``K2``, ``D2``, ``R``, ``T``) atomically."""
        import cv2

        from lunar_drake.files import atomic_path

        with atomic_path(Path(path), what="calibration") as tmp:
            fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
            fs.write("image_width", self.width)
            fs.write("image_height", self.height)
            for name, m in (("K1", self.K_left), ("D1", self.dist_left), ("K2", self.K_right),
                            ("D2", self.dist_right), ("R", self.R), ("T", self.T)):  # fmt: skip
                fs.write(name, np.asarray(m, np.float64).reshape(3, -1) if name[0] in "KR"
                         else np.asarray(m, np.float64).reshape(-1, 1))  # fmt: skip
            fs.release()

    @classmethod
    def read(cls, path: str | Path) -> StereoCalibration:
        """Reads a file :meth:`write` wrote (or any with the same keys)."""
        import cv2

        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"calibration file {str(p)!r} does not exist")
        try:
            fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
        except (cv2.error, SystemError) as exc:
            msg = " ".join(str(exc).split())[:120]
            raise ConfigError(f"calibration file {str(p)!r} is not OpenCV YAML: {msg}") from None
        try:

            def mat(name):
                m = fs.getNode(name).mat()
                if m is None:
                    raise ConfigError(f"calibration file {str(p)!r} has no {name!r}")
                return np.asarray(m, np.float64)

            return cls(
                width=int(fs.getNode("image_width").real()),
                height=int(fs.getNode("image_height").real()),
                K_left=mat("K1"),
                K_right=mat("K2"),
                dist_left=mat("D1").ravel(),
                dist_right=mat("D2").ravel(),
                R=mat("R"),
                T=mat("T").ravel(),
            )
        finally:
            fs.release()

    def rectification(self):
        """OpenCV rectification: ``(maps_left, maps_right, Q)``, each map a pair for
        ``cv2.remap`` and ``Q`` the 4 x 4 disparity-to-depth matrix."""
        import cv2

        size = (self.width, self.height)
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
            self.K_left, self.dist_left, self.K_right, self.dist_right, size, self.R,
            self.T.reshape(3, 1),
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=0.0,
        )  # fmt: skip
        m1 = cv2.initUndistortRectifyMap(self.K_left, self.dist_left, R1, P1, size, cv2.CV_32FC1)
        m2 = cv2.initUndistortRectifyMap(self.K_right, self.dist_right, R2, P2, size, cv2.CV_32FC1)
        return m1, m2, Q


__all__ = ["StereoCalibration"]
