"""Independent steady-state Wong-Reece wheel reference (adaptive quadrature, root finding).

A check on the simulation core, written separately from it: every integral is
``scipy.integrate.quad`` (adaptive Gauss-Kronrod, split at the kink ``theta_m``) and every
root ``scipy.optimize.brentq``; only the parameter classes and ``ImmobilizedError`` come
from :mod:`lunar_drake.dynamics.terramechanics`. Too slow for a plant step (milliseconds
per wheel), fast enough for tests, plots and fits. Pure Python/scipy, no Drake.

Model (one rigid wheel, steady state; ``theta`` from the downward vertical, positive
forward; sinkage ``z`` in (0, r]; slip ``s`` in [0, 1), driving)::

    theta_1 = arccos(1 - z/r),  theta_2 = -rear_angle_ratio theta_1,
    theta_m = f theta_1,  f = min(max(c1 + c2 s, 0), 0.99)          (Wong & Reece 1967)
    k = k_c/b + k_phi
    sigma = k r^n (cos theta - cos theta_1)^n                 theta_m <= theta <= theta_1
    sigma = k r^n (cos(theta_1 - (theta - theta_2)(theta_1 - theta_m)/(theta_m - theta_2))
                   - cos theta_1)^n                            theta_2 <= theta < theta_m
        (the base clamped at 0 before the power)
    r_s = r + lam h_g                    (shear radius: grousers of height h_g, ratio lam)
    j = r_s [(theta_1 - theta) - (1 - s)(sin theta_1 - sin theta)]
    tau = (c + sigma tan phi)(1 - exp(-|j|/K)) sign(j)         (Janosi & Hanamoto 1961)
    Fz = b int (r sigma cos theta + r_s tau sin theta)   vertical load carried (N)
    DP = b int (r_s tau cos theta - r sigma sin theta)   drawbar pull (N, along +x)
    T  = r_s^2 b int tau                                 driving torque (N m)

integrals over [theta_2, theta_1]. Lateral force under a slip angle ``beta`` (Ishigami,
Miwa, Nagatani & Yoshida 2007, J. Field Robotics 24(3); from memory)::

    j_y = r (1 - s)(theta_1 - theta) |tan beta|,
    tau_y = (c + sigma tan phi)(1 - exp(-j_y / K_y)),
    h = r (cos theta - cos theta_1) >= 0,  X_c = pi/4 - phi/2,
    D1 = cot X_c + tan(X_c + phi),  D2 = cot X_c + cot^2 X_c tan phi,
    R_b(h) = D1 (c h + D2 rho g h^2 / 2)                        (N/m; side-wall bulldozing)
    F_bull = |sin beta| int R_b(h) (r - h cos theta),
    Fy = -sign(beta) (r b int tau_y + F_bull).

``Fz`` does not depend on ``beta`` in this model. Parameters: ``SoilParams`` (n, k_c,
k_phi, c, phi, K, c1, c2, rear_angle_ratio, K_y, density) and ``WheelParams``
(radius_m, width_m, and when present grouser_height_m, default 0, and grouser_ratio,
default 1).
"""

# No `from __future__ import annotations`: keeps dataclass field types real, like the core.

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import quad
from scipy.optimize import brentq

from lunar_drake.dynamics.terramechanics import ImmobilizedError, SoilParams, WheelParams
from lunar_drake.errors import ConfigError, OutOfRangeError, check_range
from lunar_drake.moon import GRAVITY_MPS2

__all__ = [
    "SLIP_GRID",
    "SteadyWheel",
    "WheelIntegrals",
    "equilibrium_sinkage",
    "reference_curve",
    "reference_slip",
    "rover_mass_properties",
    "slope_wheel_loads",
    "steady_wheel",
    "wheel_integrals",
]

SLIP_GRID = np.linspace(0.0, 0.99, 50)
"""Slips scanned (in order) by :func:`reference_slip` for the first sign change."""

_QUAD = {"epsabs": 1.0e-12, "epsrel": 1.0e-11, "limit": 200}
_MIN_SINKAGE_FRACTION = 1.0e-9  # of the radius: the lower end of the sinkage bracket
_MAX_SLIP = 0.99


# ------------------------------------------------------------------------------ validation


def _real(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"{name} = {value!r} must be a real number")
    return float(value)


def _in(name, value, lo, hi, *, lo_open=False, hi_open=False, unit="") -> float:
    v = _real(name, value)
    check_range(name, v, lo, hi, lo_open=lo_open, hi_open=hi_open, unit=unit)
    return v


def _check_params(wheel, soil) -> None:
    if not isinstance(wheel, WheelParams):
        raise ConfigError(f"wheel must be a WheelParams, got {type(wheel).__name__}")
    if not isinstance(soil, SoilParams):
        raise ConfigError(f"soil must be a SoilParams, got {type(soil).__name__}")
    soil.validate()


def _shear_radius(wheel: WheelParams) -> float:
    """r_s = r + lam h_g (m)."""
    h_g = getattr(wheel, "grouser_height_m", 0.0)
    h_g = _in("grouser_height_m", h_g, 0.0, wheel.radius_m, unit=" m (at most the radius)")
    lam = _in("grouser_ratio", getattr(wheel, "grouser_ratio", 1.0), 0.0, 1.0)
    return wheel.radius_m + lam * h_g


# ---------------------------------------------------------------------------- integrands


class _Contact:
    """Angles and stress laws of one wheel at one (slip, sinkage); scalar math only."""

    __slots__ = ("b", "cos1", "kr", "n", "r", "rs", "s", "sin1", "slope", "soil", "t1", "t2",
                 "tm", "tphi")  # fmt: skip

    def __init__(self, *, slip: float, sinkage_m: float, wheel: WheelParams, soil: SoilParams):
        r = wheel.radius_m
        self.r, self.b, self.s, self.soil, self.n = r, wheel.width_m, slip, soil, soil.n
        self.rs = _shear_radius(wheel)
        self.t1 = math.acos(1.0 - sinkage_m / r)
        self.t2 = -soil.rear_angle_ratio * self.t1
        f = min(max(soil.c1 + soil.c2 * slip, 0.0), _MAX_SLIP)
        self.tm = f * self.t1
        span = self.tm - self.t2
        self.slope = (self.t1 - self.tm) / span if span > 0.0 else 0.0
        self.cos1, self.sin1 = math.cos(self.t1), math.sin(self.t1)
        self.kr = (soil.k_c / wheel.width_m + soil.k_phi) * r**soil.n
        self.tphi = math.tan(soil.phi)

    def sigma(self, t: float) -> float:
        """Normal stress (Pa) at angle t."""
        if t >= self.tm:
            base = math.cos(t) - self.cos1
        else:
            base = math.cos(self.t1 - (t - self.t2) * self.slope) - self.cos1
        return self.kr * base**self.n if base > 0.0 else 0.0

    def tau(self, t: float, sigma: float) -> float:
        """Longitudinal shear stress (Pa) at angle t."""
        j = self.rs * ((self.t1 - t) - (1.0 - self.s) * (self.sin1 - math.sin(t)))
        if j == 0.0:
            return 0.0
        mob = -math.expm1(-abs(j) / self.soil.K)
        return math.copysign((self.soil.c + sigma * self.tphi) * mob, j)

    def integral(self, f) -> float:
        """int f over [theta_2, theta_1], split at theta_m (where sigma has a kink)."""
        total = 0.0
        for a, b in ((self.t2, self.tm), (self.tm, self.t1)):
            if b > a:
                total += quad(f, a, b, **_QUAD)[0]
        return total

    def vertical(self) -> float:
        def f(t):
            sg = self.sigma(t)
            return self.r * sg * math.cos(t) + self.rs * self.tau(t, sg) * math.sin(t)

        return self.b * self.integral(f)

    def drawbar(self) -> float:
        def f(t):
            sg = self.sigma(t)
            return self.rs * self.tau(t, sg) * math.cos(t) - self.r * sg * math.sin(t)

        return self.b * self.integral(f)

    def torque(self) -> float:
        return self.rs**2 * self.b * self.integral(lambda t: self.tau(t, self.sigma(t)))

    def lateral(self, beta: float, gravity: float) -> float:
        if beta == 0.0:
            return 0.0
        soil, r = self.soil, self.r
        ky = r * (1.0 - self.s) * abs(math.tan(beta)) / soil.K_y

        def shear(t):
            return (soil.c + self.sigma(t) * self.tphi) * -math.expm1(-(self.t1 - t) * ky)

        xc = 0.25 * math.pi - 0.5 * soil.phi
        cot = 1.0 / math.tan(xc)
        d1 = cot + math.tan(xc + soil.phi)
        d2 = cot + cot * cot * self.tphi
        rho_g = soil.density * gravity

        def bulldoze(t):
            h = max(r * (math.cos(t) - self.cos1), 0.0)
            return d1 * (soil.c * h + 0.5 * d2 * rho_g * h * h) * (r - h * math.cos(t))

        total = r * self.b * self.integral(shear) + abs(math.sin(beta)) * self.integral(bulldoze)
        return -math.copysign(total, beta)


# -------------------------------------------------------------------------------- results


@dataclass(frozen=True)
class WheelIntegrals:
    """Wong-Reece resultants of one wheel at a given slip and sinkage.

    Attributes:
        vertical_N: vertical load the soil carries, Fz (N).
        drawbar_pull_N: drawbar pull DP, along +x (N).
        torque_Nm: driving torque the motor must supply, T (N m).
        lateral_N: lateral force Fy, along +y (N); opposite in sign to the slip angle.
    """

    vertical_N: float
    drawbar_pull_N: float
    torque_Nm: float
    lateral_N: float


@dataclass(frozen=True)
class SteadyWheel:
    """A wheel in steady state under a load: its equilibrium sinkage (m) and the
    :class:`WheelIntegrals` fields there (N, N m)."""

    sinkage_m: float
    vertical_N: float
    drawbar_pull_N: float
    torque_Nm: float
    lateral_N: float


def _slip(slip) -> float:
    return _in("slip", slip, 0.0, 1.0, hi_open=True)


def _beta(slip_angle) -> float:
    return _in("slip_angle", slip_angle, -0.5 * math.pi, 0.5 * math.pi, lo_open=True,
               hi_open=True, unit=" rad")  # fmt: skip


def _gravity(g) -> float:
    return _in("gravity_mps2", g, 0.0, 100.0, lo_open=True, unit=" m/s^2")


def wheel_integrals(
    *,
    slip: float,
    sinkage_m: float,
    wheel: WheelParams,
    soil: SoilParams,
    slip_angle: float = 0.0,
    gravity_mps2: float = GRAVITY_MPS2,
) -> WheelIntegrals:
    """Fz, DP, T and Fy (module docstring) of a wheel at ``slip`` in [0, 1), sinkage
    ``sinkage_m`` in (0, r] (m) and ``slip_angle`` in (-pi/2, pi/2) (rad); gravity (m/s^2)
    enters only the bulldozing term.

    Raises:
        ConfigError / OutOfRangeError: a value is not a number or out of its range.
    """
    _check_params(wheel, soil)
    s = _slip(slip)
    z = _in("sinkage_m", sinkage_m, 0.0, wheel.radius_m, lo_open=True,
            unit=" m (0 < z <= wheel radius)")  # fmt: skip
    beta = _beta(slip_angle)
    g = _gravity(gravity_mps2)
    c = _Contact(slip=s, sinkage_m=z, wheel=wheel, soil=soil)
    return WheelIntegrals(
        vertical_N=c.vertical(),
        drawbar_pull_N=c.drawbar(),
        torque_Nm=c.torque(),
        lateral_N=c.lateral(beta, g),
    )


def _sinkage(s: float, load: float, wheel: WheelParams, soil: SoilParams) -> float:
    """Equilibrium sinkage (m), inputs already checked."""
    r = wheel.radius_m

    def fz(z):
        return _Contact(slip=s, sinkage_m=z, wheel=wheel, soil=soil).vertical()

    top = fz(r)
    if top < load:
        raise ImmobilizedError(
            f"load_N = {load:.6g} N cannot be carried at slip {s:.4g} on {soil.name}: even "
            f"full sinkage (z = r = {r:g} m) carries only {top:.6g} N"
        )
    lo = _MIN_SINKAGE_FRACTION * r
    bottom = fz(lo)
    if bottom >= load:
        return lo
    # Brent on log z (Fz grows like a power of z, so log Fz is nearly linear in log z):
    # the same root in z, in a handful of iterations.
    log_load = math.log(load)

    def g(u):
        return math.log(max(fz(math.exp(u)), 1e-300)) - log_load

    u = brentq(g, math.log(lo), math.log(r), xtol=1e-13, rtol=4.0 * np.finfo(float).eps)
    return min(math.exp(u), r)


def equilibrium_sinkage(
    *,
    slip: float,
    load_N: float,
    wheel: WheelParams,
    soil: SoilParams,
    slip_angle: float = 0.0,
) -> float:
    """Sinkage z (m) in (0, r] at which the wheel carries ``load_N`` (N): Fz(z) = load.

    Brent's method on (1e-9 r, r]. ``slip_angle`` is checked but does not change Fz in
    this model.

    Raises:
        ImmobilizedError: even z = r carries less than the load.
        ConfigError / OutOfRangeError: bad input.
    """
    _check_params(wheel, soil)
    s = _slip(slip)
    load = _in("load_N", load_N, 0.0, math.inf, lo_open=True, unit=" N")
    if not math.isfinite(load):
        raise OutOfRangeError(f"load_N = {load!r} must be finite")
    _beta(slip_angle)
    return _sinkage(s, load, wheel, soil)


def steady_wheel(
    *,
    slip: float,
    load_N: float,
    wheel: WheelParams,
    soil: SoilParams,
    slip_angle: float = 0.0,
    gravity_mps2: float = GRAVITY_MPS2,
) -> SteadyWheel:
    """The wheel at its :func:`equilibrium_sinkage` for ``load_N`` (N) and the
    :func:`wheel_integrals` there."""
    z = equilibrium_sinkage(slip=slip, load_N=load_N, wheel=wheel, soil=soil, slip_angle=slip_angle)
    f = wheel_integrals(
        slip=slip, sinkage_m=z, wheel=wheel, soil=soil, slip_angle=slip_angle,
        gravity_mps2=gravity_mps2,
    )  # fmt: skip
    return SteadyWheel(
        sinkage_m=z,
        vertical_N=f.vertical_N,
        drawbar_pull_N=f.drawbar_pull_N,
        torque_Nm=f.torque_Nm,
        lateral_N=f.lateral_N,
    )


# ------------------------------------------------------------------------- rover on a slope


def _loads(wheel_loads_N) -> np.ndarray:
    try:
        loads = np.atleast_1d(np.asarray(wheel_loads_N, dtype=np.float64)).ravel()
    except (TypeError, ValueError):
        loads = np.array([])
    if loads.size == 0 or not np.all(np.isfinite(loads)) or np.any(loads <= 0.0):
        raise OutOfRangeError(
            f"wheel_loads_N = {wheel_loads_N!r} must be a non-empty list of finite loads > 0 N"
        )
    return loads


def reference_slip(
    *,
    slope_rad: float,
    wheel_loads_N,
    wheel: WheelParams,
    soil: SoilParams,
) -> float:
    """Steady slip in [0, 0.99] of a rover driving straight up a uniform slope.

    ``wheel_loads_N`` are the wheels' normal loads on the slope (perpendicular to it, N).
    All wheels share one slip ``s`` (a rigid rover driving straight), each sits at its
    :func:`equilibrium_sinkage` for its load at that ``s``, and ``s`` solves
    ``sum_i DP_i(s) = sum_i N_i tan(slope)`` (the downslope weight). The slips of
    :data:`SLIP_GRID` (50 points on [0, 0.99]) are scanned upwards until the first sign
    change, which Brent's method refines (xtol 1e-12). 0 if the pull at zero slip already
    meets the demand (this module does not model braking). Wheels with equal loads are
    evaluated once.

    Raises:
        ImmobilizedError: no slip in [0, 0.99] balances the demand (the rover cannot
            climb), or a wheel's load cannot be carried.
        ConfigError / OutOfRangeError: slope outside [0, pi/2), bad loads.
    """
    _check_params(wheel, soil)
    slope = _in("slope_rad", slope_rad, 0.0, 0.5 * math.pi, hi_open=True, unit=" rad")
    loads = _loads(wheel_loads_N)
    unique, counts = np.unique(loads, return_counts=True)
    demand = float(np.sum(loads)) * math.tan(slope)
    memo: dict[tuple[float, float], float] = {}

    def pull(s: float, load: float) -> float:
        key = (s, load)
        if key not in memo:
            z = _sinkage(s, load, wheel, soil)
            memo[key] = _Contact(slip=s, sinkage_m=z, wheel=wheel, soil=soil).drawbar()
        return memo[key]

    def excess(s: float) -> float:
        return sum(int(k) * pull(s, float(w)) for w, k in zip(unique, counts, strict=True)) - demand

    prev_s, prev = float(SLIP_GRID[0]), excess(float(SLIP_GRID[0]))
    if prev >= 0.0:
        return 0.0
    best = prev
    for s in SLIP_GRID[1:]:
        s = float(s)
        e = excess(s)
        if e >= 0.0:
            if e == 0.0:
                return s
            return float(brentq(excess, prev_s, s, xtol=1e-12, rtol=4.0 * np.finfo(float).eps))
        best = max(best, e)
        prev_s = s
    raise ImmobilizedError(
        f"cannot climb slope_rad = {slope:.6g} ({math.degrees(slope):.2f} deg) on "
        f"{soil.name}: the best drawbar pull on slip [0, 0.99] is {best + demand:.4g} N "
        f"but the downslope weight is {demand:.4g} N"
    )


def reference_curve(*, slopes_rad, wheel_loads_fn, wheel: WheelParams, soil: SoilParams):
    """:func:`reference_slip` at each slope (rad), with the normal loads
    ``wheel_loads_fn(slope_rad)`` (N); NaN where the rover is immobilized."""
    out = []
    for a in np.atleast_1d(np.asarray(slopes_rad, dtype=np.float64)).ravel():
        try:
            out.append(
                reference_slip(
                    slope_rad=float(a),
                    wheel_loads_N=wheel_loads_fn(float(a)),
                    wheel=wheel,
                    soil=soil,
                )
            )
        except ImmobilizedError:
            out.append(math.nan)
    return np.asarray(out, dtype=np.float64)


def rover_mass_properties(*, description) -> tuple[float, np.ndarray]:
    """(total mass (kg), centre of mass (3,) in the chassis frame C (m)) of a
    ``RoverDescription`` at zero joint angles, summed body by body from the same masses
    and placements as ``lunar_drake.models.rover_sdf.rover_sdf`` (no Drake needed)."""
    d = description
    top = d.chassis_height_m / 2
    centres = np.asarray(d.wheel_centres_C(), dtype=np.float64)
    bodies = [(d.chassis_mass_kg, (0.0, 0.0, 0.0))]
    bodies += [(d.wheel_mass_kg, tuple(c)) for c in centres]
    if d.steering == "explicit":
        y_axis = d.track_m / 2 - d.steering_offset_m
        leg = centres[0, 2]
        bodies += [(d.rocker_mass_kg, (0.0, s * y_axis, 0.0)) for s in (1.0, -1.0)]
        bodies += [
            (d.steering_module_mass_kg, (c[0], math.copysign(y_axis, c[1]), leg / 2))
            for c in centres
        ]
    gimbal = (d.mast_x_m, 0.0, top + d.mast_height_m)
    bodies += [
        (d.mast_mass_kg, (d.mast_x_m, 0.0, top + d.mast_height_m / 2)),
        (d.gimbal_mass_kg, gimbal),  # yoke and head, half each, both at the gimbal centre
        (d.solar_panel_mass_kg,
         (d.solar_panel_x_m, d.solar_panel_y_m, top + d.solar_panel_mount_height_m)),
    ]  # fmt: skip
    m = np.array([b[0] for b in bodies])
    p = np.array([b[1] for b in bodies])
    total = float(m.sum())
    return total, (m @ p) / total


def slope_wheel_loads(
    *, description, slope_rad: float, gravity_mps2: float = GRAVITY_MPS2
) -> np.ndarray:
    """Quasi-static normal loads (N; fl, fr, rl, rr) of a rover climbing straight up a
    uniform slope, perpendicular to it.

    The weight ``m g`` (mass and CoM from :func:`rover_mass_properties`) has the normal
    component ``m g cos(slope)`` and the downslope component ``m g sin(slope)``, which
    the wheels' traction balances at the ground. Moments about the contact line (the
    ground below the chassis origin, wheels just touching) give
    ``sum_i x_i N_i = m g (x_cm cos(slope) - h sin(slope))`` with ``h`` the CoM height
    above the ground, so the front pair carries
    ``m g (x_cm cos - h sin - x_r cos) / (x_f - x_r)`` and the rear pair the rest, split
    equally left/right (the CoM's lateral offset is ignored). Rigid geometry at zero joint
    angles: it ignores sinkage and the suspension's own compliance (rocker and chassis
    pitch), hence the small shift of the CoM that they cause. At zero slope it equals the
    level loads of ``rover_sdf.level_wheel_loads`` for a laterally centred CoM.

    Raises:
        OutOfRangeError: slope outside (-pi/2, pi/2), or so steep that a wheel pair would
            lift off (the rover tips over backwards).
    """
    a = _in("slope_rad", slope_rad, -0.5 * math.pi, 0.5 * math.pi, lo_open=True,
            hi_open=True, unit=" rad")  # fmt: skip
    g = _gravity(gravity_mps2)
    mass, com = rover_mass_properties(description=description)
    h = description.nominal_chassis_height_m() + com[2]
    x = np.asarray(description.wheel_centres_C(), dtype=np.float64)[:, 0]
    x_f, x_r = 0.5 * (x[0] + x[1]), 0.5 * (x[2] + x[3])
    weight = mass * g
    front = weight * ((com[0] - x_r) * math.cos(a) - h * math.sin(a)) / (x_f - x_r)
    rear = weight * math.cos(a) - front
    if front <= 0.0 or rear <= 0.0:
        raise OutOfRangeError(
            f"slope_rad = {a:.6g} ({math.degrees(a):.1f} deg): the "
            f"{'front' if front <= 0.0 else 'rear'} wheels of {description.name} would lift "
            "off (the rover tips over); allowed slopes keep every wheel loaded"
        )
    return np.array([front / 2, front / 2, rear / 2, rear / 2])
