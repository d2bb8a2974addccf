"""Rover kinematics: body twist <-> wheel steering angles and speeds (numpy, no Drake).

Paper section 7, "Rover Kinematics": "the software that translates vehicle body motion
commands into motor commands" (move_base plus explicit steering control on RP/KRex2),
for both vehicle models of section 6: a skid-steer rover (Husky-like) and an
explicit-steer rover (every wheel independently steered, like RP and KRex2).

Frames and units
----------------
Body frame B: x forward, y left, z up; the twist is ``(vx, vy, wz)`` = the velocity of
B's origin expressed in B (m/s) and the yaw rate (rad/s, positive counter-clockwise seen
from above). Wheel i's *steering axis* is vertical through ``p_BS[i] = (x_i, y_i)`` (m).
A wheel's steer angle ``delta`` (rad) is the heading of its rolling direction
``h = (cos delta, sin delta)`` from B's x axis; its left axis is ``l = (-sin delta,
cos delta)``; its rolling speed ``omega`` (rad/s) is positive when the wheel rolls along
``+h``.

Explicit steering with a steering offset (derivation)
-----------------------------------------------------
The wheel centre (and its contact point below) sits ``o`` metres from the steering axis
along the wheel's left axis: ``c = p + o l``. With the steering angle held (the wheel
assembly turns with the body at ``wz``) the planar rigid-body velocity of the centre is::

    v_c = v + wz z x c = v_p + wz o (z x l) = v_p - wz o h,    v_p = v + wz z x p,

since ``z x l = -h``. Rolling without side slip needs ``v_c`` parallel to ``h``; as the
offset term is already along ``h`` this holds exactly when ``v_p`` is parallel to ``h``:

* **the steer angle is the heading of the steering-axis velocity v_p** - the offset
  does not change it - and
* **the rolling speed is** ``omega = (v_p . h - wz o) / r``.

``v_p . h = +-|v_p|``: angles are wrapped to [-pi/2, pi/2] by turning the wheel the
short way and reversing its speed. A wheel whose steering axis is at the instantaneous
centre of rotation (``v_p = 0``, every wheel at zero twist) has no defined heading; it
keeps its previous angle (no spurious flips) and spins at ``-wz o / r``.

Forward kinematics (:func:`explicit_steer_twist`) inverts this: for each wheel the
rolling constraint ``h . v_c = r omega`` and the no-side-slip constraint ``l . v_c = 0``
are linear in ``(vx, vy, wz)``; the 2n equations are solved by least squares, so a
consistent command set is reproduced exactly and an inconsistent one (slipping wheels)
gives the best rigid-body fit.

Skid steer
----------
Wheels are fixed (``delta = 0``); their centres sit at lateral position ``y_c = y + o``.
All wheels of a side (left: ``y > 0``, right: ``y < 0``) are driven at the same speed,
that of the side's mean lateral position ``y_L`` or ``y_R``::

    omega_side = (vx - wz * icr_scale * y_side) / r

``icr_scale`` >= 1 models the skid-steer "ICR expansion" - the wheels' instantaneous
centres lie further out than the geometric track because the tyres skid (Mandow et
al. 2007, "Experimental kinematics for wheeled skid-steer mobile robots", IROS; they
fit a factor ~1.5 on hard ground, from memory). A skid-steer rover cannot move sideways:
``vy != 0`` raises :class:`~lunar_drake.errors.ConfigError`.

Wheel servos
------------
:func:`wheel_servo_gains` sizes PD gains for a steering (position) servo and a drive
(velocity) servo from the reflected inertia and a closed-loop bandwidth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError

__all__ = [
    "STEER_MODES",
    "ServoGains",
    "SteerCommands",
    "SteeringLimitError",
    "WheelGeometry",
    "explicit_steer_commands",
    "explicit_steer_one",
    "explicit_steer_twist",
    "skid_steer_twist",
    "skid_steer_wheel_speeds",
    "skid_twist_map",
    "steer_kernel_args",
    "wheel_geometry_for",
    "wheel_servo_gains",
]

STEER_MODES = ("auto", "ackermann", "crab", "point_turn")
_HALF_PI = 0.5 * math.pi
# Angle slack (rad) when comparing a needed steer angle with its limit.
_LIMIT_SLACK = 1e-9


class SteeringLimitError(ConfigError):
    """A twist needs a steering angle beyond a wheel's steering limit (even after the flip)."""


def _as_wheel_array(value, n: int, name: str, dtype=np.float64) -> np.ndarray:
    arr = np.asarray(value, dtype=dtype)
    if arr.ndim == 0:
        arr = np.full(n, arr, dtype=dtype)
    if arr.shape != (n,):
        raise ConfigError(f"{name} has shape {arr.shape}; must be a scalar or have shape ({n},)")
    arr = arr.copy()
    arr.setflags(write=False)
    return arr


def _default_p_BS() -> np.ndarray:
    return np.array([[0.6, 0.6], [0.6, -0.6], [-0.6, 0.6], [-0.6, -0.6]])


@dataclass(frozen=True, eq=False)
class WheelGeometry:
    """Planar wheel layout of a rover, in the body frame B (x forward, y left, z up).

    Array attributes are stored as read-only float (bool for ``steerable``) arrays of
    shape (n,); scalars given for per-wheel values are broadcast.

    Attributes:
        p_BS: steering-axis positions (n, 2) (m); for a skid-steer rover, the wheel
            positions. The default is an illustrative 4-wheel, 1.2 m x 1.2 m layout of
            the size of RP/VIPER-class rovers (~1.4-1.5 m footprint, from memory).
        wheel_radius: wheel radius (m), scalar or (n,). Default 0.25 m (RP/VIPER-class
            ~0.5 m wheel diameter, from memory).
        steering_offset: signed lateral offset ``o`` of the wheel centre from its
            steering axis, along the wheel's left axis (m), scalar or (n,). Default 0.
        steering_limit: largest steering angle magnitude (rad), scalar or (n,), in
            [0, pi]; wrapped angles never exceed pi/2, so a limit >= pi/2 is no limit.
            Default pi/2.
        steerable: whether each wheel can steer, bool scalar or (n,); a non-steerable
            wheel has an effective limit of 0. Default True.
        names: wheel names used in messages; default ``wheel0``, ``wheel1``, ...
    """

    p_BS: np.ndarray = field(default_factory=_default_p_BS)
    wheel_radius: float | np.ndarray = 0.25
    steering_offset: float | np.ndarray = 0.0
    steering_limit: float | np.ndarray = _HALF_PI
    steerable: bool | np.ndarray = True
    names: tuple[str, ...] | None = None

    def __post_init__(self):
        p = np.array(self.p_BS, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 1:
            raise ConfigError(f"p_BS has shape {p.shape}; must be (n, 2) with n >= 1")
        if not np.all(np.isfinite(p)):
            raise ConfigError(f"p_BS = {p.tolist()} holds non-finite values")
        p.setflags(write=False)
        n = p.shape[0]
        object.__setattr__(self, "p_BS", p)
        r = _as_wheel_array(self.wheel_radius, n, "wheel_radius")
        if not np.all(r > 0) or not np.all(np.isfinite(r)):
            raise OutOfRangeError(f"wheel_radius = {r.tolist()} m; must be finite and > 0")
        o = _as_wheel_array(self.steering_offset, n, "steering_offset")
        if not np.all(np.isfinite(o)):
            raise OutOfRangeError(f"steering_offset = {o.tolist()} m; must be finite")
        lim = _as_wheel_array(self.steering_limit, n, "steering_limit")
        if not np.all((lim >= 0) & (lim <= math.pi)):
            raise OutOfRangeError(f"steering_limit = {lim.tolist()} rad; allowed [0, pi]")
        st = _as_wheel_array(self.steerable, n, "steerable", dtype=bool)
        names = tuple(f"wheel{i}" for i in range(n)) if self.names is None else self.names
        names = tuple(str(s) for s in names)
        if len(names) != n:
            raise ConfigError(f"names = {names!r} has {len(names)} entries; need {n}")
        object.__setattr__(self, "wheel_radius", r)
        object.__setattr__(self, "steering_offset", o)
        object.__setattr__(self, "steering_limit", lim)
        object.__setattr__(self, "steerable", st)
        object.__setattr__(self, "names", names)

    @property
    def n_wheels(self) -> int:
        """Number of wheels n."""
        return self.p_BS.shape[0]

    @property
    def effective_limit(self) -> np.ndarray:
        """Steering limit (rad) per wheel, 0 for non-steerable wheels."""
        return np.where(self.steerable, self.steering_limit, 0.0)

    @classmethod
    def rectangular(
        cls,
        *,
        wheelbase: float,
        track: float,
        wheel_radius: float,
        n_axles: int = 2,
        steering_offset: float = 0.0,
        steering_limit: float = _HALF_PI,
        steerable: bool = True,
    ) -> WheelGeometry:
        """Axles evenly spaced over ``wheelbase`` (m), centred on B's origin, wheels at
        ``y = +-track/2`` (m). Order: front-left, front-right, ..., rear-left, rear-right
        (names ``fl, fr, [m1l, m1r, ...], rl, rr``)."""
        if n_axles < 2:
            raise OutOfRangeError(f"n_axles = {n_axles!r}; must be >= 2")
        if not (wheelbase > 0 and track > 0):
            raise OutOfRangeError(f"wheelbase = {wheelbase!r} m, track = {track!r} m; both > 0")
        xs = np.linspace(0.5 * wheelbase, -0.5 * wheelbase, n_axles)
        p = np.array([[x, s * 0.5 * track] for x in xs for s in (1.0, -1.0)])
        tags = ["f"] + [f"m{i}" for i in range(1, n_axles - 1)] + ["r"]
        names = tuple(f"{t}{side}" for t in tags for side in ("l", "r"))
        return cls(
            p_BS=p,
            wheel_radius=wheel_radius,
            steering_offset=steering_offset,
            steering_limit=steering_limit,
            steerable=steerable,
            names=names,
        )


def _split_twist(twist) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.asarray(twist, dtype=np.float64)
    if t.ndim == 0 or t.shape[-1] != 3:
        raise ConfigError(f"twist has shape {t.shape}; must be (..., 3) = (vx, vy, wz)")
    return t[..., 0], t[..., 1], t[..., 2]


def _first(mask: np.ndarray) -> tuple:
    return tuple(int(a[0]) for a in np.nonzero(mask))


# ----------------------------------------------------------------------------- skid steer


def _skid_sides(geometry: WheelGeometry) -> np.ndarray:
    """Per-wheel lateral lever arm (m): the mean wheel-centre y of the wheel's side."""
    y = geometry.p_BS[:, 1]
    if np.any(y == 0):
        i = int(np.nonzero(y == 0)[0][0])
        raise ConfigError(
            f"skid steer: wheel {geometry.names[i]!r} has p_y = 0; the side (left p_y > 0, "
            "right p_y < 0) must be defined for every wheel"
        )
    left = y > 0
    if left.all() or not left.any():
        raise ConfigError(
            f"skid steer needs wheels on both sides; p_y = {y.tolist()} (left > 0, right < 0)"
        )
    yc = y + geometry.steering_offset
    return np.where(left, yc[left].mean(), yc[~left].mean())


def skid_steer_wheel_speeds(
    twist, *, geometry: WheelGeometry, icr_scale: float = 1.0, tol: float = 1e-9
) -> np.ndarray:
    """Wheel speeds (rad/s), shape (..., n), of a skid-steer rover for twists (..., 3).

    ``omega_i = (vx - wz * icr_scale * y_side(i)) / r_i`` (module docstring). Raises
    ConfigError if any ``|vy| > tol`` (m/s): a skid-steer rover cannot crab.
    """
    if not icr_scale > 0:
        raise OutOfRangeError(f"icr_scale = {icr_scale!r}; must be > 0")
    vx, vy, wz = _split_twist(twist)
    bad = np.abs(vy) > tol
    if np.any(bad):
        v = float(vy[_first(bad)] if vy.ndim else vy)
        raise ConfigError(
            f"skid steer cannot move sideways: vy = {v!r} m/s; a skid-steer twist needs "
            "vy = 0 (use explicit steering for crab motion)"
        )
    y_side = _skid_sides(geometry)
    v_wheel = vx[..., None] - wz[..., None] * (icr_scale * y_side)
    return v_wheel / geometry.wheel_radius


def skid_steer_twist(omega, *, geometry: WheelGeometry, icr_scale: float = 1.0) -> np.ndarray:
    """Body twist (..., 3) = (vx, 0, wz) from skid-steer wheel speeds (..., n) (rad/s).

    Least squares over the wheels of ``r_i omega_i = vx - wz * icr_scale * y_side(i)``;
    exact inverse of :func:`skid_steer_wheel_speeds`.
    """
    w = np.asarray(omega, dtype=np.float64)
    n = geometry.n_wheels
    if w.ndim == 0 or w.shape[-1] != n:
        raise ConfigError(f"omega has shape {w.shape}; must be (..., {n})")
    v_wheel = w * geometry.wheel_radius
    sol = v_wheel @ skid_twist_map(geometry, icr_scale=icr_scale).T  # (..., 2)
    return np.stack([sol[..., 0], np.zeros_like(sol[..., 0]), sol[..., 1]], axis=-1)


def skid_twist_map(geometry: WheelGeometry, *, icr_scale: float = 1.0) -> np.ndarray:
    """(2, n) least-squares map from skid-steer rim speeds ``r_i omega_i`` (m/s) to
    (vx (m/s), wz (rad/s)): the pseudo-inverse of :func:`skid_steer_twist`'s equations."""
    if not icr_scale > 0:
        raise OutOfRangeError(f"icr_scale = {icr_scale!r}; must be > 0")
    n = geometry.n_wheels
    a = np.stack([np.ones(n), -icr_scale * _skid_sides(geometry)], axis=1)  # (n, 2)
    return np.ascontiguousarray(np.linalg.pinv(a))


# ------------------------------------------------------------------------- explicit steer


@dataclass(frozen=True, eq=False)
class SteerCommands:
    """Result of :func:`explicit_steer_commands`; unpacks as ``delta, omega = ...``.

    Attributes:
        delta: steer angles (..., n) (rad), in [-pi/2, pi/2] and within the limits.
        omega: rolling speeds (..., n) (rad/s).
        saturated: (..., n) bool, True where ``clip=True`` saturated a wheel's angle.
        needed_delta: the wrapped angles the twist needed, before clipping (rad).
    """

    delta: np.ndarray
    omega: np.ndarray
    saturated: np.ndarray
    needed_delta: np.ndarray

    def __iter__(self):
        return iter((self.delta, self.omega))


def _check_mode(mode: str, vx, vy, wz, tol: float) -> None:
    if mode not in STEER_MODES:
        raise ConfigError(f"mode = {mode!r}; must be one of {STEER_MODES}")

    def need_zero(name, values, why):
        bad = np.abs(values) > tol
        if np.any(bad):
            v = float(values[_first(bad)] if values.ndim else values)
            raise ConfigError(f"mode = {mode!r} needs {why}; got {name} = {v!r}")

    if mode == "ackermann":
        need_zero("vy", vy, "vy = 0 (turning about a centre on the body y axis)")
    elif mode == "crab":
        need_zero("wz", wz, "wz = 0 (pure translation)")
    elif mode == "point_turn":
        need_zero("vx", vx, "vx = vy = 0 (rotation about the body origin)")
        need_zero("vy", vy, "vx = vy = 0 (rotation about the body origin)")


def explicit_steer_commands(
    twist,
    *,
    geometry: WheelGeometry,
    mode: str = "auto",
    previous_delta=None,
    clip: bool = False,
    tol: float = 1e-9,
) -> SteerCommands:
    """Steer angles and wheel speeds that realise a body twist on an explicit-steer rover.

    Args:
        twist: (..., 3) = (vx (m/s), vy (m/s), wz (rad/s)) in B.
        geometry: the wheel layout.
        mode: "auto" (any twist), "ackermann" (needs vy = 0: turning about a centre on
            B's y axis; for 4-wheel steering this is double Ackermann), "crab" (needs
            wz = 0) or "point_turn" (needs vx = vy = 0). Every mode uses the same
            no-side-slip solution; the mode only checks that the twist fits it.
        previous_delta: (..., n) angles (rad) kept by wheels whose steering axis does
            not move (zero twist, or the axis at the centre of rotation); default 0.
        clip: if False, a needed angle beyond a wheel's limit raises
            :class:`SteeringLimitError`; if True the angle is saturated at the limit,
            the wheel speed is the projection of the needed velocity on the saturated
            heading, and the wheel is flagged in ``saturated``.
        tol: a speed (m/s, rad/s for wz) at or below which a value counts as zero.

    Returns:
        :class:`SteerCommands` (unpacks as ``delta, omega``).
    """
    vx, vy, wz = _split_twist(twist)
    _check_mode(mode, vx, vy, wz, tol)
    g = geometry
    px, py = g.p_BS[:, 0], g.p_BS[:, 1]
    if vx.ndim == 0:  # one twist (the flight software's 50 Hz call): one compiled call
        prev1 = np.zeros(px.shape) if previous_delta is None else previous_delta
        prev1 = np.broadcast_to(np.asarray(prev1, np.float64), px.shape)
        delta, omega, over, needed = _steer_one(
            float(vx), float(vy), float(wz), px, py, np.ascontiguousarray(prev1),
            g.effective_limit, g.steering_offset, g.wheel_radius, float(tol),
        )  # fmt: skip
        if clip or not over.any():
            return SteerCommands(delta=delta, omega=omega, saturated=over, needed_delta=needed)
    vpx = vx[..., None] - wz[..., None] * py
    vpy = vy[..., None] + wz[..., None] * px
    prev = np.zeros(vpx.shape) if previous_delta is None else np.asarray(previous_delta, float)
    prev = np.broadcast_to(prev, vpx.shape)

    raw = np.arctan2(vpy, vpx)  # (-pi, pi]
    delta = np.where(raw > _HALF_PI, raw - math.pi, np.where(raw < -_HALF_PI, raw + math.pi, raw))
    # Exactly sideways (+-pi/2 are the same line): take the sign nearer the previous angle.
    edge = np.abs(np.abs(delta) - _HALF_PI) < 1e-12
    delta = np.where(edge & (delta * prev < 0), -delta, delta)
    moving = np.hypot(vpx, vpy) > tol
    delta = np.where(moving, delta, prev)

    lim = g.effective_limit
    over = np.abs(delta) > lim + _LIMIT_SLACK
    if np.any(over) and not clip:
        idx = _first(over)
        i = idx[-1]
        need = float(delta[idx])
        t = np.asarray(twist, dtype=np.float64)[idx[:-1]]
        what = "is not steerable (limit 0)" if not g.steerable[i] else "has a steering limit of"
        raise SteeringLimitError(
            f"wheel {g.names[i]!r} (index {i}) needs a steering angle of {need:.6g} rad "
            f"({math.degrees(need):.3f} deg) but {what} +-{lim[i]:.6g} rad "
            f"({math.degrees(lim[i]):.3f} deg), for twist (vx, vy, wz) = {t.tolist()}; "
            "pass clip=True to saturate instead"
        )
    needed = delta
    delta = np.minimum(np.maximum(delta, -lim), lim)
    c, s = np.cos(delta), np.sin(delta)
    omega = (vpx * c + vpy * s - wz[..., None] * g.steering_offset) / g.wheel_radius
    return SteerCommands(delta=delta, omega=omega, saturated=over, needed_delta=needed)


def steer_kernel_args(geometry: WheelGeometry) -> tuple:
    """The wheel arrays :func:`explicit_steer_one` takes (compute once per rover): steering
    axis x and y (m), effective steering limit (rad), steering offset (m), wheel radius
    (m), (n,) each."""
    g = geometry
    return (
        np.ascontiguousarray(g.p_BS[:, 0]), np.ascontiguousarray(g.p_BS[:, 1]),
        np.ascontiguousarray(g.effective_limit), np.ascontiguousarray(g.steering_offset),
        np.ascontiguousarray(g.wheel_radius),
    )  # fmt: skip


def explicit_steer_one(vx: float, vy: float, wz: float, previous_delta, args, *,
                       tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``explicit_steer_commands((vx, vy, wz), previous_delta=..., clip=True)``'s
    ``(delta, omega)`` (rad, rad/s; (n,) each) in one compiled call, ``args`` from
    :func:`steer_kernel_args` (the flight software's 50 Hz call)."""
    prev = np.ascontiguousarray(previous_delta, dtype=np.float64)
    px, py, lim, offset, radius = args
    delta, omega, _, _ = _steer_one(
        float(vx), float(vy), float(wz), px, py, prev, lim, offset, radius, float(tol)
    )
    return delta, omega


@numba.njit(cache=True)
def _steer_one(vx, vy, wz, px, py, prev, lim, offset, radius, tol):  # pragma: no cover - numba
    """:func:`explicit_steer_commands` of one twist: the same operations, wheel by wheel
    (``delta, omega, saturated, needed_delta``)."""
    n = px.size
    delta = np.empty(n)
    omega = np.empty(n)
    over = np.zeros(n, np.bool_)
    needed = np.empty(n)
    for i in range(n):
        vpx = vx - wz * py[i]
        vpy = vy + wz * px[i]
        d = np.arctan2(vpy, vpx)  # (-pi, pi]
        if d > _HALF_PI:
            d = d - math.pi
        elif d < -_HALF_PI:
            d = d + math.pi
        if abs(abs(d) - _HALF_PI) < 1e-12 and d * prev[i] < 0:
            d = -d  # exactly sideways: the sign nearer the previous angle
        if not np.hypot(vpx, vpy) > tol:
            d = prev[i]
        over[i] = abs(d) > lim[i] + _LIMIT_SLACK
        needed[i] = d
        d = min(max(d, -lim[i]), lim[i])
        delta[i] = d
        omega[i] = (vpx * np.cos(d) + vpy * np.sin(d) - wz * offset[i]) / radius[i]
    return delta, omega, over, needed


def explicit_steer_twist(delta, omega, *, geometry: WheelGeometry) -> np.ndarray:
    """Body twist (..., 3) from steer angles (..., n) (rad) and wheel speeds (..., n) (rad/s).

    Least squares over the wheels' rolling (``h . v_c = r omega``) and no-side-slip
    (``l . v_c = 0``) constraints, ``v_c`` being the velocity of each wheel centre
    ``c = p + o l`` (module docstring). Exact for commands from
    :func:`explicit_steer_commands` that were not clipped.
    """
    g = geometry
    n = g.n_wheels
    d = np.asarray(delta, dtype=np.float64)
    w = np.asarray(omega, dtype=np.float64)
    if d.ndim == 0 or d.shape[-1] != n or w.ndim == 0 or w.shape[-1] != n:
        raise ConfigError(f"delta {d.shape} and omega {w.shape} must both be (..., {n})")
    if d.ndim == 1 and w.ndim == 1:  # one rover state (the flight's odometry, 100 Hz)
        return _explicit_steer_twist_1(d, w, g.p_BS, g.steering_offset, g.wheel_radius)
    d, w = np.broadcast_arrays(d, w)
    c, s = np.cos(d), np.sin(d)
    cx = g.p_BS[:, 0] - g.steering_offset * s  # wheel centre c = p + o l, l = (-s, c)
    cy = g.p_BS[:, 1] + g.steering_offset * c
    # v_c = (vx - wz cy, vy + wz cx)
    roll = np.stack([c, s, -c * cy + s * cx], axis=-1)  # (..., n, 3)
    side = np.stack([-s, c, s * cy + c * cx], axis=-1)
    a = np.concatenate([roll, side], axis=-2)  # (..., 2n, 3)
    b = np.concatenate([w * g.wheel_radius, np.zeros_like(w)], axis=-1)  # (..., 2n)
    # Normal equations (A^T A is 3 x 3 and well conditioned for any rover with wheels
    # on both sides of its centre): the least-squares solution, as pinv but ~10x faster.
    ata = np.einsum("...ki,...kj->...ij", a, a)
    atb = np.einsum("...ki,...k->...i", a, b)
    return np.linalg.solve(ata, atb[..., None])[..., 0]


@numba.njit(cache=True)
def _explicit_steer_twist_1(d, w, p_BS, offset, radius):  # pragma: no cover - numba
    """:func:`explicit_steer_twist` of one state (n,): the same normal equations, summed
    wheel by wheel in one compiled call."""
    ata = np.zeros((3, 3))
    atb = np.zeros(3)
    for i in range(d.size):
        c, s = math.cos(d[i]), math.sin(d[i])
        cx = p_BS[i, 0] - offset[i] * s
        cy = p_BS[i, 1] + offset[i] * c
        roll = (c, s, -c * cy + s * cx)
        side = (-s, c, s * cy + c * cx)
        b = w[i] * radius[i]
        for r in range(3):
            atb[r] += roll[r] * b
            for q in range(3):
                ata[r, q] += roll[r] * roll[q] + side[r] * side[q]
    return np.linalg.solve(ata, atb)


# --------------------------------------------------------------------------------- servos


class ServoGains(NamedTuple):
    """PD gains of a joint servo: torque = kp (q_d - q) + kd (v_d - v).

    Attributes:
        kp: stiffness (N m/rad).
        kd: damping (N m s/rad).
    """

    kp: float
    kd: float


def wheel_servo_gains(
    *, inertia: float, bandwidth_hz: float, damping_ratio: float = math.sqrt(0.5)
) -> ServoGains:
    """PD gains placing a joint servo's closed-loop poles for a given bandwidth.

    The joint (reflected inertia ``I`` about the joint axis, kg m^2, including the motor
    rotor times the gear ratio squared) under ``tau = kp (q_d - q) + kd (v_d - v)`` has
    error dynamics ``I e'' + kd e' + kp e = 0``. With ``kp = I wn^2`` and
    ``kd = 2 zeta wn I`` these are the canonical second-order poles; ``wn`` is chosen so
    that the -3 dB bandwidth of ``wn^2 / (s^2 + 2 zeta wn s + wn^2)`` is ``bandwidth_hz``:
    ``w_bw = wn sqrt(1 - 2 zeta^2 + sqrt(4 zeta^4 - 4 zeta^2 + 2))`` (``w_bw = wn`` at
    ``zeta = 1/sqrt(2)``).

    * Steering (position) servo: ``q_d`` = commanded steer angle, ``v_d = 0``.
    * Drive (velocity) servo: ``v_d`` = commanded wheel speed and ``q_d`` its running
      integral, i.e. a PI velocity loop ``kd (w_d - w) + kp int(w_d - w) dt`` with the
      same poles (no steady-state speed error under a constant load torque). Both map
      directly onto Drake's PD-controlled joint actuators
      (``JointActuator.set_controller_gains(PdControllerGains(p=kp, d=kd))``).

    Gains ignore torque saturation, friction and the terrain load.
    """
    if not (inertia > 0 and math.isfinite(inertia)):
        raise OutOfRangeError(f"inertia = {inertia!r} kg m^2; must be finite and > 0")
    if not (bandwidth_hz > 0 and math.isfinite(bandwidth_hz)):
        raise OutOfRangeError(f"bandwidth_hz = {bandwidth_hz!r}; must be finite and > 0")
    if not (0 < damping_ratio <= 10):
        raise OutOfRangeError(f"damping_ratio = {damping_ratio!r}; allowed (0, 10]")
    z2 = damping_ratio**2
    ratio = math.sqrt(1.0 - 2.0 * z2 + math.sqrt(4.0 * z2 * z2 - 4.0 * z2 + 2.0))
    wn = 2.0 * math.pi * bandwidth_hz / ratio
    return ServoGains(kp=inertia * wn * wn, kd=2.0 * damping_ratio * wn * inertia)


def wheel_geometry_for(description) -> WheelGeometry:
    """Kinematic wheel geometry of a :class:`~lunar_drake.models.rover_description.
    RoverDescription` (body frame = chassis frame C).

    Skid: wheel centres, no steering. Explicit: steering axes ``steering_offset_m``
    inboard of the wheel centres; offsets signed along each wheel's left axis.
    """
    wc = np.asarray(description.wheel_centres_C(), dtype=float)[:, :2]
    if description.steering == "skid":
        return WheelGeometry(
            p_BS=wc,
            wheel_radius=description.wheel_radius_m,
            steering_offset=0.0,
            steering_limit=0.0,
            steerable=False,
        )
    o = float(description.steering_offset_m)
    side = np.sign(wc[:, 1])
    p = wc.copy()
    p[:, 1] -= side * o
    return WheelGeometry(
        p_BS=p,
        wheel_radius=description.wheel_radius_m,
        steering_offset=side * o,
        steering_limit=float(description.steering_limit_rad),
        steerable=True,
    )
