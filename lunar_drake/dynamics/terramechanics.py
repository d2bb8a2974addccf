"""Rigid-wheel terramechanics core: Bekker sinkage, Wong-Reece stresses, Janosi-Hanamoto shear,
and a static shear patch that holds a wheel at rest.

Pure numpy/scipy (no Drake). A LeafSystem calls :func:`normal_force`,
:func:`wheel_forces` and the static shear patch functions (:func:`patch_static_force`,
:func:`update_patch_displacement`) once per plant step for all wheels at once, so every
per-step function takes arrays (one entry per wheel), uses closed forms or a fixed
24-node Gauss-Legendre quadrature, and has no Python loop over wheels and no root
finding.

Frames and signs
----------------
Forces are expressed in each wheel's *contact frame* C: ``x`` forward along the wheel
heading projected on the terrain tangent plane, ``y`` to the left (along the axle),
``z`` along the terrain normal (up, out of the soil). The caller rotates them into the
world frame and applies them at the contact point.

* ``z`` (sinkage, m) is the penetration of the wheel's lowest point below the local
  terrain surface along ``C.z``, positive into the soil; ``z_dot`` (m/s) is positive
  while sinking.
* :func:`normal_force` is the force along ``+C.z`` (>= 0: the soil never pulls).
* :class:`WheelForces`: ``thrust`` (N, along ``+C.x``), ``resistance`` (N, compaction
  resistance, positive when it opposes forward travel, i.e. it acts along ``-C.x``),
  ``drawbar_pull = thrust - resistance`` (the net force along ``+C.x``), ``lateral``
  (N, along ``+C.y``; opposes lateral sliding) and ``torque`` (N m, the moment of the
  soil shear about the axle, positive when it opposes forward rolling; as a vector about
  ``+C.y`` it is ``-torque``, since forward rolling is a positive spin about ``+C.y``).

Slip conventions
----------------
* Slip ratio ``s = (r omega - v) / max(|r omega|, |v|, v_eps)`` (:func:`slip_ratio`),
  clipped to [-1, 1]: driving ``s`` in (0, 1] (wheel surface outruns the hub), braking
  negative; ``v_eps`` makes it continuous through zero speed.
* Slip angle ``beta = arctan(v_y / max(|v_x|, v_eps))`` (:func:`slip_angle`), in
  (-pi/2, pi/2); positive when the wheel slides to its left, which gives a negative
  (rightward) lateral force.
* ``direction`` (optional, in [-1, 1], :func:`travel_direction`) is the regularized
  sign of travel along ``C.x``. With ``direction = d`` the forward-travel model and its
  mirror image (wheel travelling backward) are blended with weights ``(1 + d)/2`` and
  ``(1 - d)/2``, and the compaction resistance is scaled by ``d``. Thus a wheel at rest
  (``v = 0``, ``omega = 0``) feels no force, and everything is continuous through
  ``v = 0``. Omit it (``None``) for a wheel known to travel forward.

Model (per wheel; theta measured from the downward vertical, positive forward)
------------------------------------------------------------------------------
* Normal load vs sinkage, Bekker's rigid-wheel closed form (Bekker 1969, *Introduction
  to Terrain-Vehicle Systems*; Wong 2008, *Theory of Ground Vehicles*, 4th ed., §2.4)::

      W(z) = (3 - n) (k_c + b k_phi) sqrt(2 r) z^((2n + 1)/2) / 3

* Compaction (motion) resistance, Bekker::  R_c = (k_c + b k_phi) z^(n+1) / (n + 1)
* Entry angle ``theta_1 = arccos(1 - z/r)`` (``z`` capped at ``r``), exit angle
  ``theta_2 = -rear_angle_ratio theta_1``, max-stress angle
  ``theta_m = (c1 + c2 s) theta_1`` (Wong & Reece 1967).
* Normal stress: Wong-Reece shape, ``(cos theta - cos theta_1)^n`` ahead of
  ``theta_m`` and its mapped mirror behind it, scaled so its vertical resultant equals
  the load ``W`` passed for this step (so transient loads from the compliant contact
  carry into traction). Note that at the same sinkage the Wong-Reece distribution
  (peak at ``theta_m`` instead of the bottom) supports less load than Bekker's closed
  form: with ``W`` = Bekker ``W(z)`` the stresses come out 1.45x (``s = 0``) to 2.7x
  (``s = 0.9``) the raw ``(k_c/b + k_phi) r^n (cos theta - cos theta_1)^n`` for the
  default coefficients. The load is taken as authoritative (it is what the plant's
  contact carries); the shear component of the vertical balance is neglected.
* Shear (Janosi & Hanamoto 1961, Mohr-Coulomb envelope)::

      tau = (c + sigma tan phi) (1 - exp(-|j| / K)) sign(j),   j = s x,
      x = r (sin theta_1 - sin theta)  (horizontal distance from the entry point)

  Wong & Reece's tangential form is ``j = r[(theta_1 - theta) - (1 - s)(sin theta_1 -
  sin theta)] = s x + r[(theta_1 - theta) - (sin theta_1 - sin theta)]``; we drop the
  second, purely geometric term (``~ r (theta_1^3 - theta^3)/6``, about 1 mm at the
  bottom for ``r = 0.25 m``, ``z = 1 cm``) so that at ``s = 0`` the shear displacement
  is exactly zero: a freely rolling wheel develops no thrust and only compaction
  resistance acts (drawbar pull = -R_c, the rolling resistance).
* Thrust ``H = r b int tau cos theta``, torque ``T = r^2 b int tau``, drawbar pull
  ``DP = H - R_c`` (Wong 2008 §4; Wong & Reece 1967).
* Lateral shear (Ishigami, Miwa, Nagatani & Yoshida 2007, J. Field Robotics 24(3))::

      j_y = r (1 - s)(theta_1 - theta) tan|beta|,
      F_y = -sign(beta) r b int (c + sigma tan phi)(1 - exp(-j_y / K_y))

  The side-wall bulldozing term of Ishigami et al. is not modelled, and longitudinal
  and lateral shear are not coupled through a common strength envelope.
* Compliant contact normal force: ``N = max(0, W(z) + d(z) z_dot)`` with
  ``d(z) = 2 zeta sqrt(W'(z) W(z) / g) = 2 zeta (k_c + b k_phi) sqrt(2 r) (3 - n)/3
  sqrt((2n + 1)/(2 g)) z^n``: the damping that gives damping ratio ``zeta`` to a mass
  ``W(z)/g`` resting at ``z`` (Hunt-Crossley-like: it vanishes at ``z = 0``).

Static shear patch (stiction)
-----------------------------
The forces above depend on slip ratio and slip angle, regularized by ``v_eps`` so that
they can be applied explicitly; at rest they vanish, and a sustained load (gravity on a
slope) makes a wheel creep viscously. Soil holds a resting wheel by static shear: the
Janosi-Hanamoto stress depends on the shear *displacement*. So each wheel carries the
shear displacement ``j = (j_x, j_y)`` (m, contact frame) of its contact patch relative
to the soil, a first-order brush/LuGre-type state (one bristle for the whole patch):

* Slip velocity of the rim point in contact relative to the ground
  (:func:`patch_slip_velocity`): ``u = (v_x - r omega, v_y)``.
* Evolution: ``dj/dt = u - (|r omega| / L) j`` with the relaxation length equal to the
  patch length ``L = r (sin theta_1 + sin(rear_angle_ratio theta_1))``
  (:func:`patch_length`): rim elements enter the patch unsheared, so rolling renews it
  over one patch length of travel. Integrated exactly over each step with ``u``,
  ``r omega`` and ``L`` held (:func:`update_patch_displacement`; unconditionally
  stable): at rest ``j`` integrates the creep; a rolling wheel relaxes towards
  ``u L / |r omega|`` (``s L`` in pure slip: the shear at the rear of the patch in
  Wong's ``j = s x``). Elasto-plastic: ``j`` is projected back onto the ellipse
  ``rho = sqrt((j_x/K)^2 + (j_y/K_y)^2) = n_sat`` (default 4, where 98 % of the strength
  is mobilized), so beyond it the patch slides.
* Static force (:func:`patch_static_force`), Janosi-Hanamoto in the displacement with
  the Mohr-Coulomb strength of the patch (cohesion over the patch area ``b L``, friction
  on the load; Wong's maximum thrust ``A c + W tan phi``)::

      F_max = c b L + N tan phi,
      F = -F_max (1 - exp(-rho)) (j_x/K, j_y/K_y) / rho - (c_x u_x, c_y u_y),
      |F| <= F_max.

  Along one axis this is ``-F_max (1 - exp(-|j|/K)) sign(j)``, i.e. Janosi-Hanamoto's
  ``tau = tau_max (1 - exp(-|j|/K))`` over a uniformly displaced patch. Longitudinal and
  lateral shear share one strength envelope here (unlike the Wong-Reece part).
* Bristle damping (a numerical modelling choice, not a soil property):
  ``c_x = 2 zeta_p sqrt(k_x m)`` with ``k_x = F_max / K`` (initial stiffness) and
  ``m = N / g`` (the mass the wheel carries); ``c_y`` likewise with ``K_y``. Stability:
  the force is applied explicitly over the plant step ``h``; for one wheel's share of
  the rover (``a = h c / m``, ``b = h^2 k / m``) the step is linear in ``(j, v)``. If
  ``j`` advances with the velocity at the start of the step (forward Euler, matrix
  ``[[1, h], [-h k/m, 1 - a]]``) the eigenvalues lie inside the unit circle iff
  ``b < a < 2 + b/2``, i.e. ``omega_p h / 2 < zeta_p < 1 / (omega_p h) + omega_p h / 4``;
  if it advances with the velocity at the end of the step (semi-implicit Euler: what
  happens in a Drake diagram, whose discrete plant steps in an unrestricted update that
  precedes discrete updates) iff ``2 a + b < 4``, i.e.
  ``zeta_p < 1 / (omega_p h) - omega_p h / 4``. Here
  ``omega_p = sqrt(k/m) = sqrt(g (tan phi + c b L / N) / K) ~ sqrt(g tan phi / K)``,
  about 8 rad/s on lunar soil for either rover: at ``h`` = 10 ms both hold for
  ``0.04 < zeta_p < 12.5``, and the default ``zeta_p = 1`` (critical) sits far from
  both ends. The damping also acts on the wheel spin, as ``c r^2`` on ``omega`` (76 N m
  s/rad for the 300 kg rover), explicitly, against the drive servo's implicit ``kd``
  (2000): stable while ``c r^2 < 2 I / h + kd``, satisfied by a wide margin.
* Blend (:func:`static_weight`): tangential force and soil moment are
  ``w F_static + (1 - w) F_Wong-Reece`` with ``w`` = 1 below a rolling speed ``|r omega|``
  of 1 cm/s, 0 above 2 cm/s, a C1 smoothstep between; so at driving speeds the forces
  are exactly the Wong-Reece ones. The patch force acts at the rim, so its moment about
  the axle is its lever arm's. The weight uses the *rolling* speed, not the hub speed:
  Wong-Reece is a rolling-wheel model, while a wheel that does not roll (parked,
  braked, or locked and dragged) keeps shearing the same patch; a locked wheel sliding
  at any speed gets the saturated patch force, Coulomb friction at its full strength.
  (Weighted by ``max(|v_x|, |r omega|)`` instead, a braked 300 kg rover that passed
  2 cm/s while loading up on a 30 deg slope kept sliding at 3 cm/s, since there the
  ``v_eps``-regularized slip develops only part of the strength.)

Approximations: one bristle per wheel (a brush model would resolve the shear along the
patch); the static part ignores the normal-stress distribution (uniform mobilization);
``j`` lives in the (steered) contact frame, so steering a parked wheel turns its shear
with it; the strength uses the step's normal load. Sources: Janosi & Hanamoto (1961)
and Wong (2008) for the shear law and strength; the bristle state with rolling
relaxation follows the LuGre friction model (Canudas de Wit, Olsson, Astrom & Lischinsky
1995, IEEE TAC 40(3)) and its distributed tyre version (Canudas de Wit, Tsiotras,
Velenis, Basset & Gissinger 2003, Vehicle System Dynamics 39(3)); relaxation length as
in tyre mechanics (Pacejka, *Tyre and Vehicle Dynamics*). Citations from memory.
"""

# No `from __future__ import annotations`: yaml_load_typed reads SoilParams' real field
# types (the scenario's `soil` section).

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError, check_range
from lunar_drake.moon import GRAVITY_MPS2

__all__ = [
    "GRC1",
    "LUNAR_REGOLITH",
    "SOIL_PRESETS",
    "ImmobilizedError",
    "ShearPatchParams",
    "SlipCurve",
    "SoilParams",
    "WheelForces",
    "WheelParams",
    "bekker_load",
    "compaction_resistance",
    "contact_damping",
    "contact_stiffness",
    "drawbar_pull",
    "entry_angle",
    "normal_force",
    "patch_length",
    "patch_slip_velocity",
    "patch_static_force",
    "patch_strength",
    "reference_slip",
    "shear_stress",
    "slip_angle",
    "slip_ratio",
    "slip_vs_drawbar_curve",
    "slip_vs_slope_curve",
    "soil_preset",
    "static_sinkage",
    "static_weight",
    "travel_direction",
    "update_patch_displacement",
    "wheel_forces",
]


QUADRATURE_NODES_PER_SEGMENT = 12
"""Gauss-Legendre nodes on each of [theta_2, theta_m] and [theta_m, theta_1]."""

_MIN_SINKAGE_FRACTION = 1.0e-12  # of the radius: entry angle >= ~1.4e-6 rad

_x, _w = np.polynomial.legendre.leggauss(QUADRATURE_NODES_PER_SEGMENT)
_U = 0.5 * (_x + 1.0)  # nodes on [0, 1]; symmetric: _U[::-1] == 1 - _U
_WU = 0.5 * _w  # weights on [0, 1]
del _x, _w


class ImmobilizedError(LunarDrakeError, RuntimeError):
    """No slip in the allowed range balances the load: the rover cannot climb (or hold)."""


# ------------------------------------------------------------------------------ validation


def _real(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"{name} = {value!r} must be a real number")
    value = float(value)
    if not math.isfinite(value):
        raise OutOfRangeError(f"{name} = {value!r} must be finite")
    return value


def _check(name: str, value, lo: float, hi: float, *, lo_open=False, hi_open=False, unit=""):
    check_range(name, _real(name, value), lo, hi, lo_open=lo_open, hi_open=hi_open, unit=unit)


# ---------------------------------------------------------------------------- parameters


@dataclass
class SoilParams:
    """Bekker / Mohr-Coulomb / Janosi-Hanamoto / Wong-Reece soil parameters (SI units).

    Attributes:
        name: label used in messages and plots.
        n: Bekker sinkage exponent (-), in (0, 2].
        k_c: Bekker cohesive modulus, N/m^(n+1), in [0, 1e8].
        k_phi: Bekker frictional modulus, N/m^(n+2), in (0, 1e10].
        c: Mohr-Coulomb cohesion, Pa, in [0, 1e6].
        phi: internal friction angle, rad, in [0, pi/2).
        K: Janosi-Hanamoto (longitudinal) shear deformation modulus, m, in (0, 1].
        c1, c2: Wong-Reece max-stress angle coefficients, ``theta_m = (c1 + c2 s)
            theta_1``; each in [0, 1] with ``c1 + c2 <= 0.99``.
        rear_angle_ratio: exit angle ``theta_2 = -rear_angle_ratio * theta_1`` (soil
            rebound behind the wheel), in [0, 1).
        K_y: lateral shear deformation modulus, m, in (0, 1].
        density: bulk density, kg/m^3, in (0, 5000] (informational here; for
            bulldozing/excavation models).
        damping_ratio: damping ratio of the compliant normal contact (-), in [0, 10].
            A numerical modelling choice, not a measured soil property.
    """

    name: str = "lunar_regolith"
    n: float = 1.0
    k_c: float = 1400.0
    k_phi: float = 820_000.0
    c: float = 170.0
    phi: float = math.radians(35.0)
    K: float = 0.018
    c1: float = 0.43
    c2: float = 0.32
    rear_angle_ratio: float = 0.0
    K_y: float = 0.018
    density: float = 1500.0
    damping_ratio: float = 0.5

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Checks every field; raises ConfigError / OutOfRangeError naming the field (also
        for instances built without ``__post_init__``, e.g. by a YAML loader)."""
        if not isinstance(self.name, str) or not self.name.strip():
            raise ConfigError(f"name = {self.name!r} must be a non-empty string")
        _check("n", self.n, 0.0, 2.0, lo_open=True)
        _check("k_c", self.k_c, 0.0, 1.0e8, unit=" N/m^(n+1)")
        _check("k_phi", self.k_phi, 0.0, 1.0e10, lo_open=True, unit=" N/m^(n+2)")
        _check("c", self.c, 0.0, 1.0e6, unit=" Pa")
        _check("phi", self.phi, 0.0, 0.5 * math.pi, hi_open=True, unit=" rad (below 90 deg)")
        _check("K", self.K, 0.0, 1.0, lo_open=True, unit=" m")
        _check("c1", self.c1, 0.0, 1.0)
        _check("c2", self.c2, 0.0, 1.0)
        if self.c1 + self.c2 > 0.99:
            raise OutOfRangeError(
                f"c1 = {self.c1:g} and c2 = {self.c2:g}: c1 + c2 must be <= 0.99 so that "
                "theta_m = (c1 + c2 s) theta_1 stays inside the contact for s <= 1"
            )
        _check("rear_angle_ratio", self.rear_angle_ratio, 0.0, 1.0, hi_open=True)
        _check("K_y", self.K_y, 0.0, 1.0, lo_open=True, unit=" m")
        _check("density", self.density, 0.0, 5000.0, lo_open=True, unit=" kg/m^3")
        _check("damping_ratio", self.damping_ratio, 0.0, 10.0)


@dataclass(frozen=True)
class WheelParams:
    """Rigid cylindrical wheel.

    Attributes:
        radius_m: wheel radius r, m, in (0, 5].
        width_m: wheel (contact) width b, m, in (0, 3].
    """

    radius_m: float = 0.25
    width_m: float = 0.2

    def __post_init__(self) -> None:
        _check("radius_m", self.radius_m, 0.0, 5.0, lo_open=True, unit=" m")
        _check("width_m", self.width_m, 0.0, 3.0, lo_open=True, unit=" m")


LUNAR_REGOLITH = SoilParams(
    name="lunar_regolith",
    # Lunar soil, Bekker/LRV-era values as tabulated by Wong (2008), Theory of Ground
    # Vehicles, and the Lunar Sourcebook (Carrier, Olhoeft & Mendell 1991, ch. 9):
    # n = 1, k_c = 1.4 kN/m^2, k_phi = 820 kN/m^3, c = 0.17 kPa, phi = 35 deg,
    # K = 1.8 cm (from memory of those tables).
    n=1.0,
    k_c=1400.0,
    k_phi=820_000.0,
    c=170.0,
    phi=math.radians(35.0),
    K=0.018,
    # Wong & Reece (1967) max-stress coefficients for sand (from memory); no rebound.
    c1=0.43,
    c2=0.32,
    rear_angle_ratio=0.0,
    # Lateral modulus: no lunar measurement; assumed isotropic (K_y = K).
    K_y=0.018,
    # Bulk density of the upper 15 cm, 1.50 g/cm^3 (Carrier et al. 1991, from memory).
    density=1500.0,
    damping_ratio=0.5,
)
"""Nominal lunar regolith (see the inline citations)."""

GRC1 = SoilParams(
    name="grc1",
    # GRC-1 lunar soil simulant (Oravec, Zeng & Asnani 2010, J. Terramechanics 47(6),
    # 361-377), a blend of manufactured silica sands designed to reproduce lunar
    # compaction and shear response. Verified: min/max density 1.60/1.89 g/cm^3 (as
    # quoted from that paper by the simulant database at simulantdb.com). Everything
    # else here is from memory or assumed -- check against the paper before
    # quantitative use:
    # * n, k_c, k_phi: assumed equal to the lunar nominal set (the simulant was designed
    #   to match lunar compaction; no verified Bekker triple for GRC-1 at hand).
    # * c = 0.1 kPa (small apparent cohesion of a dry sand, from memory),
    #   phi = 33 deg (medium-dense triaxial value, from memory), K = 1.5 cm (assumed).
    n=1.0,
    k_c=1400.0,
    k_phi=820_000.0,
    c=100.0,
    phi=math.radians(33.0),
    K=0.015,
    c1=0.43,
    c2=0.32,
    rear_angle_ratio=0.0,
    K_y=0.015,
    # Mid-range of the verified 1.60-1.89 g/cm^3 min/max densities.
    density=1700.0,
    damping_ratio=0.5,
)
"""GRC-1 lunar simulant used for the RP rover tests at NASA GRC (see inline notes)."""

SOIL_PRESETS: dict[str, SoilParams] = {"lunar_regolith": LUNAR_REGOLITH, "grc1": GRC1}


def soil_preset(name: str) -> SoilParams:
    """The named soil preset (case-insensitive; ``-`` and ``_`` optional for ``grc1``)."""
    key = str(name).strip().lower()
    if key in SOIL_PRESETS:
        return dataclasses.replace(SOIL_PRESETS[key])  # a copy: configs are mutable
    if key.replace("-", "").replace("_", "") == "grc1":
        return dataclasses.replace(GRC1)
    raise ConfigError(f"soil preset {name!r} is unknown; choose one of {sorted(SOIL_PRESETS)}")


# ------------------------------------------------------------------- sinkage and normal force


def _bekker_coefficient(wheel: WheelParams, soil: SoilParams) -> float:
    """A in W = A z^((2n+1)/2): (3 - n)(k_c + b k_phi) sqrt(2 r)/3, N/m^((2n+1)/2)."""
    return (
        (3.0 - soil.n)
        * (soil.k_c + wheel.width_m * soil.k_phi)
        * math.sqrt(2.0 * wheel.radius_m)
        / 3.0
    )


def bekker_load(z, *, wheel: WheelParams, soil: SoilParams) -> np.ndarray:
    """Bekker's rigid-wheel normal load W(z), N, for sinkage ``z`` (m); 0 for ``z <= 0``.

    ``W = (3 - n)(k_c + b k_phi) sqrt(2 r) z^((2n+1)/2) / 3`` (Bekker 1969; Wong 2008).
    """
    zp = np.maximum(np.asarray(z, dtype=np.float64), 0.0)
    return _bekker_coefficient(wheel, soil) * zp ** (soil.n + 0.5)


def static_sinkage(W, *, wheel: WheelParams, soil: SoilParams) -> np.ndarray:
    """Sinkage z (m) at which Bekker's load equals ``W`` (N): the inverse of :func:`bekker_load`.

    ``z = (3 W / ((3 - n)(k_c + b k_phi) sqrt(2 r)))^(2/(2n+1))``; 0 for ``W <= 0``.
    """
    Wp = np.maximum(np.asarray(W, dtype=np.float64), 0.0)
    return (Wp / _bekker_coefficient(wheel, soil)) ** (1.0 / (soil.n + 0.5))


def contact_stiffness(z, *, wheel: WheelParams, soil: SoilParams) -> np.ndarray:
    """dW/dz (N/m) of Bekker's load at sinkage ``z`` (m); 0 for ``z <= 0``.

    ``(n + 1/2) A z^(n - 1/2)``; it grows without bound as ``z -> 0+`` when ``n < 1/2``.
    For an explicit step ``h`` with mass ``m`` on the wheel, stability needs roughly
    ``h < 2 sqrt(m / k)``.
    """
    z = np.asarray(z, dtype=np.float64)
    pos = z > 0.0
    zp = np.where(pos, z, 1.0)
    k = (soil.n + 0.5) * _bekker_coefficient(wheel, soil) * zp ** (soil.n - 0.5)
    return np.where(pos, k, 0.0)


def contact_damping(
    z, *, wheel: WheelParams, soil: SoilParams, gravity_mps2: float = GRAVITY_MPS2
) -> np.ndarray:
    """Damping coefficient d(z) (N s/m) of the compliant contact; 0 for ``z <= 0``.

    ``d(z) = 2 zeta sqrt(W'(z) W(z) / g) = 2 zeta A sqrt((n + 1/2)/g) z^n``: the
    damping that gives a mass ``W(z)/g`` resting on the contact at ``z`` the damping
    ratio ``zeta = soil.damping_ratio``.
    """
    zp = np.maximum(np.asarray(z, dtype=np.float64), 0.0)
    coef = (
        2.0
        * soil.damping_ratio
        * _bekker_coefficient(wheel, soil)
        * math.sqrt((soil.n + 0.5) / gravity_mps2)
    )
    return coef * zp**soil.n


def normal_force(
    z,
    z_dot,
    *,
    wheel: WheelParams,
    soil: SoilParams,
    gravity_mps2: float = GRAVITY_MPS2,
) -> np.ndarray:
    """Compliant contact normal force (N, along the terrain normal, >= 0).

    ``N = max(0, W(z) + d(z) z_dot)`` with Bekker's ``W`` (:func:`bekker_load`) and
    :func:`contact_damping` ``d``. Both terms vanish at ``z = 0`` so ``N`` is continuous
    at contact onset, and ``N = 0`` for ``z <= 0``.

    Args:
        z: penetration (sinkage), m, positive into the soil (array over wheels).
        z_dot: its rate, m/s, positive while sinking.
    """
    zp = np.maximum(np.asarray(z, dtype=np.float64), 0.0)
    A = _bekker_coefficient(wheel, soil)
    d = 2.0 * soil.damping_ratio * A * math.sqrt((soil.n + 0.5) / gravity_mps2)
    zn = zp**soil.n
    return np.maximum(zn * (A * np.sqrt(zp) + d * np.asarray(z_dot, dtype=np.float64)), 0.0)


def compaction_resistance(z, *, wheel: WheelParams, soil: SoilParams) -> np.ndarray:
    """Bekker compaction (motion) resistance R_c (N) at sinkage ``z`` (m); 0 for ``z <= 0``.

    ``R_c = b (k_c/b + k_phi) z^(n+1) / (n + 1)``.
    """
    zp = np.maximum(np.asarray(z, dtype=np.float64), 0.0)
    return (soil.k_c + wheel.width_m * soil.k_phi) * zp ** (soil.n + 1.0) / (soil.n + 1.0)


def entry_angle(z, *, wheel: WheelParams) -> np.ndarray:
    """Contact entry angle theta_1 = arccos(1 - z/r) (rad), with z clipped to [0, r]."""
    zc = np.minimum(np.maximum(np.asarray(z, dtype=np.float64), 0.0), wheel.radius_m)
    return np.arccos(1.0 - zc / wheel.radius_m)


def shear_stress(sigma, j, *, soil: SoilParams, K=None) -> np.ndarray:
    """Janosi-Hanamoto shear stress (Pa): ``(c + sigma tan phi)(1 - exp(-|j|/K)) sign(j)``.

    Args:
        sigma: normal stress, Pa (>= 0).
        j: shear displacement, m (signed).
        K: shear deformation modulus, m; default ``soil.K``.
    """
    K = soil.K if K is None else K
    sigma = np.asarray(sigma, dtype=np.float64)
    j = np.asarray(j, dtype=np.float64)
    strength = soil.c + sigma * math.tan(soil.phi)
    return strength * -np.expm1(-np.abs(j) / K) * np.sign(j)


# ------------------------------------------------------------------------- slip kinematics


def slip_ratio(*, omega_r, v, v_eps: float = 1.0e-3) -> np.ndarray:
    """Slip ratio ``(r omega - v) / max(|r omega|, |v|, v_eps)``, clipped to [-1, 1].

    Args:
        omega_r: wheel rim speed r * omega, m/s (positive rolling forward).
        v: hub speed along the wheel heading (contact-frame x), m/s.
        v_eps: regularization speed, m/s (> 0); keeps the ratio continuous at rest.
    """
    wr = np.asarray(omega_r, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    den = np.maximum(np.maximum(np.abs(wr), np.abs(v)), v_eps)
    return np.minimum(np.maximum((wr - v) / den, -1.0), 1.0)


def slip_angle(*, v_x, v_y, v_eps: float = 1.0e-3) -> np.ndarray:
    """Slip angle ``arctan(v_y / max(|v_x|, v_eps))`` (rad), in (-pi/2, pi/2).

    ``v_x``, ``v_y``: hub velocity in the contact frame, m/s. Positive when the wheel
    slides to its left; continuous through zero speed.
    """
    v_x = np.asarray(v_x, dtype=np.float64)
    return np.arctan(np.asarray(v_y, dtype=np.float64) / np.maximum(np.abs(v_x), v_eps))


def travel_direction(v, *, v_eps: float = 1.0e-3) -> np.ndarray:
    """Regularized sign of travel ``clip(v / v_eps, -1, 1)`` for ``wheel_forces(direction=)``."""
    return np.minimum(np.maximum(np.asarray(v, dtype=np.float64) / v_eps, -1.0), 1.0)


# --------------------------------------------------------------------------- wheel forces


@dataclass(frozen=True)
class WheelForces:
    """Per-wheel soil forces in the contact frame (arrays, one entry per wheel).

    Attributes:
        thrust: shear thrust H along +x, N.
        resistance: compaction resistance R_c, N, positive when opposing forward travel
            (acts along -x).
        drawbar_pull: thrust - resistance, the net force along +x, N.
        lateral: side force along +y, N.
        torque: soil moment about the axle, N m, positive when opposing forward rolling.
    """

    thrust: np.ndarray
    resistance: np.ndarray
    drawbar_pull: np.ndarray
    lateral: np.ndarray
    torque: np.ndarray


def _node_pattern(rear_angle_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Constants (A, B) such that, with f = theta_m / theta_1, ``theta_1 (f A + B)``
    holds the 2K quadrature nodes (front segment [theta_m, theta_1] first, then the rear
    segment [theta_2, theta_m]) followed by their 2K weights."""
    rho = rear_angle_ratio
    A = np.concatenate((1.0 - _U, _U, -_WU, _WU))
    B = np.concatenate((_U, -rho * (1.0 - _U), _WU, rho * _WU))
    return A, B


_K = QUADRATURE_NODES_PER_SEGMENT
# Rear node k maps (Wong-Reece) to theta* = theta_1 - u_k (theta_1 - theta_m), which is
# the front node at 1 - u_k: the rear stresses are the front ones reversed.
_SHAPE_INDEX = np.concatenate((np.arange(_K), np.arange(_K)[::-1]))
_PATTERN_CACHE: dict[float, tuple[np.ndarray, np.ndarray]] = {}

if hasattr(np, "vecdot"):  # numpy >= 2.0
    _rowdot = np.vecdot
else:  # pragma: no cover

    def _rowdot(a, b):
        return np.einsum("ij,ij->i", a, b)


def _shear_integrals(s, lateral_rate, W, z, cohesion, wheel: WheelParams, soil: SoilParams):
    """Integrals over the contact for forward travel (1-D arrays over wheels).

    Args:
        s: slip in [-1, 1]; lateral_rate: ``r (1 - s) tan|beta| / K_y``; W: load >= 0;
        z: sinkage in [_MIN_SINKAGE_FRACTION r, r]; cohesion: c (0 out of contact).

    Returns:
        The quadrature sums of ``-|tau| cos(theta)``, ``-|tau|`` and ``-|tau_y|`` over
        the contact angle (multiply by ``-sign(s) r b``, ``-sign(s) r^2 b`` and
        ``-sign(beta) r b`` for thrust, torque and lateral force).
    """
    pattern = _PATTERN_CACHE.get(soil.rear_angle_ratio)
    if pattern is None:
        pattern = _PATTERN_CACHE.setdefault(
            soil.rear_angle_ratio, _node_pattern(soil.rear_angle_ratio)
        )
    A, B = pattern
    r = wheel.radius_m
    cos1 = 1.0 - z * (1.0 / r)
    th1 = np.arccos(cos1)[:, None]
    f = np.maximum(soil.c1 + soil.c2 * s, 0.0)[:, None]  # < 1 since c1 + c2 <= 0.99, s <= 1
    P = th1 * (f * A + B)
    theta = P[:, : 2 * _K]
    wts = P[:, 2 * _K :]
    cos_t = np.cos(theta)
    shape = np.maximum(cos_t[:, _SHAPE_INDEX] - cos1[:, None], 0.0)
    if soil.n != 1.0:
        shape = shape**soil.n
    wc = wts * cos_t
    # Scale the Wong-Reece shape so that its vertical resultant r b sum(sigma cos w) is W.
    amp = W * (math.tan(soil.phi) / (r * wheel.width_m)) / np.maximum(_rowdot(shape, wc), 1e-300)
    strength = cohesion[:, None] + amp[:, None] * shape
    # Janosi-Hanamoto with j = s x, x = r (sin theta_1 - sin theta) >= 0: sign(j) = sign(s).
    mob = strength * np.expm1((np.abs(s) * (-r / soil.K))[:, None] * (np.sin(th1) - np.sin(theta)))
    lat = strength * np.expm1(lateral_rate[:, None] * (theta - th1))
    return _rowdot(mob, wc), _rowdot(mob, wts), _rowdot(lat, wts)


def wheel_forces(
    *,
    slip,
    slip_angle,
    W,
    z,
    wheel: WheelParams,
    soil: SoilParams,
    direction=None,
) -> WheelForces:
    """Soil forces on each wheel for this step (vectorized over wheels; see module docs).

    Args:
        slip: slip ratio s (-), clipped to [-1, 1] (:func:`slip_ratio`).
        slip_angle: slip angle beta, rad (:func:`slip_angle`), in [-pi/2, pi/2].
        W: normal load carried by the wheel this step, N (e.g. :func:`normal_force`);
            the Wong-Reece normal stress is scaled so its vertical resultant equals W.
        z: sinkage, m; sets the contact angles and the compaction resistance. A wheel
            with ``z <= 0`` is out of contact and gets all zeros.
        wheel, soil: parameters.
        direction: optional regularized travel sign in [-1, 1] (:func:`travel_direction`);
            ``None`` means travelling forward. A dynamic simulation should pass it:
            without it the compaction resistance acts even at rest and would push a
            parked rover backward.

    Returns:
        WheelForces of arrays broadcast from the inputs (contact frame). At ``s = 0`` and
        ``beta = 0`` thrust, lateral force and torque are exactly 0 and
        ``drawbar_pull = -resistance`` (rolling resistance).
    """
    s = np.asarray(slip, dtype=np.float64)
    beta = np.asarray(slip_angle, dtype=np.float64)
    W = np.asarray(W, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64)
    shape = s.shape
    if not (beta.shape == shape and W.shape == shape and z.shape == shape):
        s, beta, W, z = np.broadcast_arrays(s, beta, W, z)
        shape = s.shape
    r = wheel.radius_m
    b = wheel.width_m
    s = np.minimum(np.maximum(s.ravel(), -1.0), 1.0)
    beta = beta.ravel()
    z = z.ravel()
    contact = z > 0.0
    # Out of contact: zero load and cohesion give exactly zero shear forces.
    W = np.maximum(W.ravel(), 0.0) * contact
    cohesion = soil.c * contact
    zq = np.minimum(np.maximum(z, _MIN_SINKAGE_FRACTION * r), r)  # for the contact angles
    lat_k = np.abs(np.tan(beta)) * (r / soil.K_y)
    Rc = ((soil.k_c + b * soil.k_phi) / (soil.n + 1.0)) * np.maximum(z, 0.0) ** (soil.n + 1.0)
    if direction is None:
        hc, ht, fy = _shear_integrals(s, (1.0 - s) * lat_k, W, zq, cohesion, wheel, soil)
        sgn = np.sign(s)
    else:
        d = np.asarray(direction, dtype=np.float64)
        if d.shape != shape:
            d = np.broadcast_to(d, shape)
        d = np.minimum(np.maximum(d.ravel(), -1.0), 1.0)
        m = s.size
        # Forward model and its mirror image (travel backward: s -> -s, x -> -x, y kept).
        s2 = np.concatenate((s, -s))
        hc2, ht2, fy2 = _shear_integrals(
            s2,
            (1.0 - s2) * np.concatenate((lat_k, lat_k)),
            np.concatenate((W, W)),
            np.concatenate((zq, zq)),
            np.concatenate((cohesion, cohesion)),
            wheel,
            soil,
        )
        wf = 0.5 * (1.0 + d)
        wb = 0.5 * (1.0 - d)
        # Mirrored thrust -H(-s) = -(-(r b) sign(-s) hc(-s)) = -(r b) sign(s) hc(-s): the
        # same prefactor as the forward term, so the raw integrals blend directly.
        hc = wf * hc2[:m] + wb * hc2[m:]
        ht = wf * ht2[:m] + wb * ht2[m:]
        fy = wf * fy2[:m] + wb * fy2[m:]
        sgn = np.sign(s)
        Rc = d * Rc
    k = -(r * b) * sgn
    H = k * hc
    T = (r * k) * ht
    Fy = (r * b) * np.sign(beta) * fy
    return WheelForces(
        thrust=H.reshape(shape),
        resistance=Rc.reshape(shape),
        drawbar_pull=(H - Rc).reshape(shape),
        lateral=Fy.reshape(shape),
        torque=T.reshape(shape),
    )


# ------------------------------------------------------------ static shear patch (stiction)


@dataclass(frozen=True)
class ShearPatchParams:
    """Numerical parameters of the static shear patch (module docstring, "Static shear
    patch"). Modelling choices, not soil properties.

    Attributes:
        damping_ratio: bristle damping ratio ``zeta_p`` (-), in [0.05, 10]. The patch
            force is applied explicitly: stable for roughly
            ``omega_p h / 2 < zeta_p < 1 / (omega_p h)`` (``omega_p ~ sqrt(g tan(phi) /
            K)``, about 8 rad/s on lunar soil, ``h`` the plant step; module docstring).
            Default 1.
        static_speed_mps: rolling (rim) speed ``|r omega|`` below which only the patch
            acts (m/s), in (0, 1).
        dynamic_speed_mps: rolling speed above which only the Wong-Reece forces act
            (m/s), in (static_speed_mps, 1].
        saturation_moduli: the patch displacement saturates (the patch slides) at
            ``sqrt((j_x/K)^2 + (j_y/K_y)^2) = saturation_moduli`` (-), in [1, 20]; at 4,
            98 % of the Mohr-Coulomb strength is mobilized.
    """

    damping_ratio: float = 1.0
    static_speed_mps: float = 0.01
    dynamic_speed_mps: float = 0.02
    saturation_moduli: float = 4.0

    def __post_init__(self) -> None:
        _check("damping_ratio", self.damping_ratio, 0.05, 10.0)
        _check("static_speed_mps", self.static_speed_mps, 0.0, 1.0, lo_open=True,
               hi_open=True, unit=" m/s")  # fmt: skip
        _check("dynamic_speed_mps", self.dynamic_speed_mps, self.static_speed_mps, 1.0,
               lo_open=True, unit=" m/s (above static_speed_mps)")  # fmt: skip
        _check("saturation_moduli", self.saturation_moduli, 1.0, 20.0)


def patch_length(z, *, wheel: WheelParams, soil: SoilParams) -> np.ndarray:
    """Contact patch length (m) along the rim's chord: ``L = r (sin theta_1 +
    sin(rear_angle_ratio theta_1))``, with ``theta_1`` from :func:`entry_angle`
    (``L ~ sqrt(2 r z)`` for a shallow rut); 0 for ``z <= 0``."""
    r = wheel.radius_m
    th1 = np.arccos(1.0 - np.minimum(np.maximum(z, 0.0), r) * (1.0 / r))
    if soil.rear_angle_ratio == 0.0:
        return r * np.sin(th1)
    return r * (np.sin(th1) + np.sin(soil.rear_angle_ratio * th1))


def patch_strength(N, length, *, wheel: WheelParams, soil: SoilParams) -> np.ndarray:
    """Mohr-Coulomb shear strength of the contact patch (N): ``F_max = c b L + N tan phi``.

    ``length`` is the patch length ``L`` (m, :func:`patch_length`; 0 out of contact):
    cohesion acts over the patch area ``b L``. ``N`` (N), the normal load, is clipped at 0.
    """
    cohesion = (soil.c * wheel.width_m) * np.asarray(length, dtype=np.float64)
    return cohesion + math.tan(soil.phi) * np.maximum(N, 0.0)


def patch_slip_velocity(*, v_x, v_y, omega_r) -> np.ndarray:
    """(n, 2) slip velocity (m/s) of the rim point in contact relative to the ground, in
    the contact frame: ``(v_x - r omega, v_y)`` (hub velocity ``v``, rim speed ``r
    omega``). Zero for a wheel rolling without slip."""
    v_x = np.asarray(v_x, dtype=np.float64)
    u = np.empty((*v_x.shape, 2))
    u[..., 0] = v_x - omega_r
    u[..., 1] = v_y
    return u


def update_patch_displacement(
    j,
    *,
    slip_velocity,
    rolling_speed,
    length,
    dt: float,
    soil: SoilParams,
    saturation_moduli: float = 4.0,
) -> np.ndarray:
    """Patch shear displacement (n, 2) (m) after a step ``dt`` (s); module docstring.

    Exact solution of ``dj/dt = u - (|v_r| / L) j`` with the slip velocity ``u``
    (:func:`patch_slip_velocity`), rolling speed ``v_r = r omega`` and patch length ``L``
    held over the step: ``j' = j e^(-a dt) + u (1 - e^(-a dt)) / a``, ``a = |v_r| / L``
    (``j + u dt`` at ``a = 0``): a wheel at rest integrates its creep, a rolling wheel
    relaxes towards ``u L / |v_r|`` over one patch length of travel. Unconditionally
    stable. Then elasto-plastic: scaled back onto the ellipse
    ``sqrt((j_x/K)^2 + (j_y/K_y)^2) = saturation_moduli`` when outside it (the patch
    slides). A wheel out of contact (``length <= 0``) gets ``j = 0`` (fresh soil).

    Args:
        j: (n, 2) displacement (x forward, y along the axle) at the start of the step.
        slip_velocity: (n, 2) m/s. rolling_speed: (n,) m/s. length: (n,) m.
    """
    L = np.asarray(length, dtype=np.float64)
    on = L > 0.0
    x = np.abs(rolling_speed) * dt / np.maximum(L, 1e-300)  # a dt; huge (not inf) if L = 0
    zero = x == 0.0
    gain = (dt * (zero - np.expm1(-x))) / (x + zero)  # dt (1 - e^-x) / x, = dt at x = 0
    jn = j * np.exp(-x)[:, None] + slip_velocity * gain[:, None]
    rho = np.hypot(jn[:, 0] * (1.0 / soil.K), jn[:, 1] * (1.0 / soil.K_y))
    scale = saturation_moduli / np.maximum(rho, saturation_moduli)
    return jn * (scale * on)[:, None]


def patch_static_force(
    j,
    *,
    slip_velocity,
    N,
    length,
    wheel: WheelParams,
    soil: SoilParams,
    damping_ratio: float = 1.0,
    gravity_mps2: float = GRAVITY_MPS2,
) -> np.ndarray:
    """(n, 2) static patch force on the wheel (N; contact frame x, y); module docstring.

    Janosi-Hanamoto in the patch displacement with a common Mohr-Coulomb envelope::

        rho = sqrt((j_x/K)^2 + (j_y/K_y)^2),
        F = -F_max (1 - exp(-rho)) (j_x/K, j_y/K_y) / rho - (c_x u_x, c_y u_y),

    ``F_max`` = :func:`patch_strength` (``length`` the patch length, 0 out of contact);
    then ``|F|`` is capped at ``F_max``. Along one axis this is exactly
    ``-F_max (1 - exp(-|j|/K)) sign(j)``. The bristle damping
    ``c_x = 2 zeta_p sqrt(k_x m)``, ``k_x = F_max / K`` (the patch's initial stiffness),
    ``m = N / g`` (the mass the wheel carries), likewise ``c_y`` with ``K_y``: a
    numerical damping (modelling choice), see :class:`ShearPatchParams`.
    """
    j = np.asarray(j, dtype=np.float64)
    N = np.maximum(N, 0.0)
    fmax = patch_strength(N, length, wheel=wheel, soil=soil)
    e = j * np.array([1.0 / soil.K, 1.0 / soil.K_y])
    rho = np.hypot(e[:, 0], e[:, 1])
    # F_max (1 - e^-rho) / rho; its value at rho = 0 does not matter (e = 0 there).
    mob = fmax * -np.expm1(-rho) / (rho + (rho == 0.0))
    # (2 zeta)^2 k m K = 4 zeta^2 F_max N / g; c_x = sqrt(that / K), c_y = sqrt(that / K_y).
    c = np.sqrt((4.0 * damping_ratio**2 / gravity_mps2) * fmax * N)
    F = -(mob[:, None] * e) - (c[:, None] * np.array([soil.K**-0.5, soil.K_y**-0.5])) * (
        slip_velocity
    )
    mag = np.hypot(F[:, 0], F[:, 1])
    # Coulomb cap |F| <= F_max (exactly 1 when below it; 0 when F_max = 0 = |F|).
    cap = fmax / np.maximum(np.maximum(mag, fmax), 1e-300)
    return F * cap[:, None]


def static_weight(rolling_speed, *, patch: ShearPatchParams) -> np.ndarray:
    """Weight in [0, 1] of the static patch force against the Wong-Reece forces.

    1 below ``patch.static_speed_mps``, 0 above ``patch.dynamic_speed_mps``, a C1
    smoothstep ``1 - t^2 (3 - 2 t)`` in between (``t`` the fraction of the way); exactly
    0 or 1 outside the band. ``rolling_speed`` = ``r omega`` (m/s; its sign is ignored).
    """
    v0 = patch.static_speed_mps
    t = (np.abs(rolling_speed) - v0) * (1.0 / (patch.dynamic_speed_mps - v0))
    t = np.minimum(np.maximum(t, 0.0), 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


# ------------------------------------------------------------------- steady-state helpers


def drawbar_pull(slip, *, W, wheel: WheelParams, soil: SoilParams) -> np.ndarray:
    """Drawbar pull DP(s) = H - R_c (N) at Bekker's static sinkage for load ``W`` (N).

    Vectorized: ``slip`` and ``W`` broadcast; straight travel (beta = 0), forward.
    """
    z = static_sinkage(W, wheel=wheel, soil=soil)
    return wheel_forces(slip=slip, slip_angle=0.0, W=W, z=z, wheel=wheel, soil=soil).drawbar_pull


@dataclass(frozen=True)
class SlipCurve:
    """Steady straight-line wheel performance vs slip at one load (arrays over ``slip``).

    ``slip`` (-), ``thrust``, ``resistance``, ``drawbar_pull`` (N), ``torque`` (N m),
    ``sinkage`` (m, scalar: Bekker static sinkage for the load), ``load`` (N).
    """

    slip: np.ndarray
    thrust: np.ndarray
    resistance: np.ndarray
    drawbar_pull: np.ndarray
    torque: np.ndarray
    sinkage: float
    load: float


def slip_vs_drawbar_curve(
    *, W: float, wheel: WheelParams, soil: SoilParams, slip=None
) -> SlipCurve:
    """Thrust, resistance, drawbar pull and torque vs slip for one wheel at load ``W`` (N).

    ``slip`` defaults to 100 points on [0, 0.99]. For plots of DP/W vs s (cf. the RP
    single-wheel drawbar pull tests the paper's slip plug-in was tuned on).
    """
    W = _real("W", W)
    if W <= 0.0:
        raise OutOfRangeError(f"W = {W!r} N must be > 0")
    s = np.linspace(0.0, 0.99, 100) if slip is None else np.asarray(slip, dtype=np.float64)
    z = float(static_sinkage(W, wheel=wheel, soil=soil))
    f = wheel_forces(slip=s, slip_angle=0.0, W=W, z=z, wheel=wheel, soil=soil)
    return SlipCurve(
        slip=s,
        thrust=f.thrust,
        resistance=f.resistance,
        drawbar_pull=f.drawbar_pull,
        torque=f.torque,
        sinkage=z,
        load=W,
    )


_SLIP_GRID = np.linspace(0.0, 0.99, 100)


def _wheel_loads(wheel_loads_N) -> np.ndarray:
    loads = np.atleast_1d(np.asarray(wheel_loads_N, dtype=np.float64)).ravel()
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
    slope_normal: bool = True,
) -> float:
    """Steady-state slip of a rover driving straight up (or down) a uniform slope.

    Solves ``sum_i DP(s, N_i) = sum_i W_i sin(slope)`` for ``s`` where ``W_i`` is the
    level-ground static load of wheel ``i`` (m_i g, N) and ``N_i = W_i cos(slope)``
    (``W_i`` if ``slope_normal`` is False). Each wheel sits at its Bekker static sinkage
    for ``N_i``. Uphill (``slope_rad >= 0``, or a downhill so gentle that rolling
    resistance still dominates) the root is searched on [0, 0.99]; downhill, where
    braking is needed, on [-0.99, 0]. The first sign change on a 100-point grid is
    refined with Brent's method (xtol 1e-10).

    Raises:
        ImmobilizedError: no slip in the searched interval balances the load (the rover
            cannot climb the slope, or cannot hold itself on it).
        OutOfRangeError: slope outside (-pi/2, pi/2) or non-positive loads.
    """
    _check("slope_rad", slope_rad, -0.5 * math.pi, 0.5 * math.pi, lo_open=True, hi_open=True)
    loads = _wheel_loads(wheel_loads_N)
    normal = loads * math.cos(slope_rad) if slope_normal else loads
    z = static_sinkage(normal, wheel=wheel, soil=soil)
    demand = float(np.sum(loads)) * math.sin(slope_rad)

    def excess(s):
        s = np.asarray(s, dtype=np.float64)
        f = wheel_forces(
            slip=s[:, None], slip_angle=0.0, W=normal[None, :], z=z[None, :], wheel=wheel, soil=soil
        )
        return np.sum(f.drawbar_pull, axis=1) - demand

    at_zero = float(excess(np.zeros(1))[0])
    if at_zero == 0.0:
        return 0.0
    grid = _SLIP_GRID if at_zero < 0.0 else -_SLIP_GRID
    g = excess(grid)
    want = g > 0.0 if at_zero < 0.0 else g < 0.0
    if not np.any(want):
        deg = math.degrees(slope_rad)
        if at_zero < 0.0:
            raise ImmobilizedError(
                f"cannot climb slope_rad = {slope_rad!r} ({deg:.2f} deg) on {soil.name}: "
                f"the best drawbar pull on slip [0, 0.99] is {g.max() + demand:.4g} N but "
                f"the downslope weight is {demand:.4g} N"
            )
        raise ImmobilizedError(
            f"cannot hold slope_rad = {slope_rad!r} ({deg:.2f} deg) on {soil.name}: the "
            f"strongest braking on slip [-0.99, 0] is {g.min() + demand:.4g} N but the "
            f"downslope weight is {demand:.4g} N"
        )
    k = int(np.argmax(want))
    lo, hi = float(grid[k - 1]), float(grid[k])
    root = brentq(lambda s: float(excess(np.array([s]))[0]), lo, hi, xtol=1e-10, rtol=1e-12)
    return float(root)


def slip_vs_slope_curve(
    *,
    slopes_rad,
    wheel_loads_N,
    wheel: WheelParams,
    soil: SoilParams,
    slope_normal: bool = True,
) -> np.ndarray:
    """:func:`reference_slip` at each slope (rad); NaN where the rover is immobilized.

    The model's counterpart of the paper's slip-vs-slope test (Figs 22-24).
    """
    out = []
    for a in np.atleast_1d(np.asarray(slopes_rad, dtype=np.float64)).ravel():
        try:
            out.append(
                reference_slip(
                    slope_rad=float(a),
                    wheel_loads_N=wheel_loads_N,
                    wheel=wheel,
                    soil=soil,
                    slope_normal=slope_normal,
                )
            )
        except ImmobilizedError:
            out.append(math.nan)
    return np.asarray(out)
