"""Where a rover starts: its chassis pose set on the terrain."""

from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.errors import NoDataError, OutOfBoundsError
from lunar_drake.models.rover_sdf import RoverModel


def spawn_pose(
    *, heightfield, rover: RoverModel, x_m: float, y_m: float, yaw_rad: float, soil: tm.SoilParams
) -> RigidTransform:
    """Chassis pose that sets the rover on the terrain at (x, y) with heading ``yaw``.

    The chassis is pitched/rolled to the plane through the terrain under the four wheel
    centres and raised so the wheels rest at the sinkage where the Wong-Reece stresses carry the
    heaviest static wheel load (:func:`~lunar_drake.dynamics.terramechanics.equilibrium_sinkage`).

    Raises:
        OutOfBoundsError: a wheel would be off the raster. NoDataError: over a NaN hole.
    """
    d = rover.description
    wc = np.asarray(d.wheel_centres_C(), dtype=float)
    Rz = RotationMatrix.MakeZRotation(yaw_rad)
    pts = (Rz.matrix() @ wc.T).T[:, :2] + [x_m, y_m]
    try:
        zt = heightfield.height(pts[:, 0], pts[:, 1])
    except OutOfBoundsError as exc:
        raise OutOfBoundsError(f"rover spawn at ({x_m:.2f}, {y_m:.2f}) m: {exc}") from exc
    except NoDataError as exc:
        raise NoDataError(
            f"rover spawn at ({x_m:.2f}, {y_m:.2f}) m is over a nodata hole: {exc}"
        ) from exc
    # Least-squares plane z = a + bx*X + by*Y through the wheel contact points.
    A = np.c_[np.ones(len(pts)), pts - [x_m, y_m]]
    a, bx, by = np.linalg.lstsq(A, zt, rcond=None)[0]
    n = np.array([-bx, -by, 1.0])
    n /= np.linalg.norm(n)
    heading = Rz.matrix()[:, 0]
    fwd = heading - n * heading.dot(n)
    fwd /= np.linalg.norm(fwd)
    R = RotationMatrix(np.column_stack([fwd, np.cross(n, fwd), n]))
    wheel = tm.WheelParams(radius_m=d.wheel_radius_m, width_m=d.wheel_width_m)
    load = float(np.max(rover.static_wheel_load_N)) if len(rover.static_wheel_load_N) else 0.0
    sink = float(tm.equilibrium_sinkage(load, wheel=wheel, soil=soil)) if load > 0 else 0.0
    # Chassis origin above the plane so the wheels touch at static sinkage.
    wc_z = wc[:, 2].min()
    h = -wc_z + d.wheel_radius_m - sink
    p = np.array([x_m, y_m, a]) + h * n
    # Wheels over bumps: raise so no wheel centre is below its terrain + radius - sink.
    R_m = R.matrix()
    centres = p + wc @ R_m.T
    z_need = heightfield.height(centres[:, 0], centres[:, 1]) + d.wheel_radius_m - sink
    p[2] += max(0.0, float(np.max(z_need - centres[:, 2])))
    return RigidTransform(R, p)
