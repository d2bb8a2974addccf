"""Rigid-wheel terramechanics core: one Wong-Reece wheel (normal stress and
Janosi-Hanamoto shear integrated over the contact angle), lateral shear and bulldozing,
grousers, and a static shear patch that holds a wheel at rest.

Pure numpy/numba (no Drake). A LeafSystem calls :func:`wheel_forces`,
:func:`normal_force` and the static shear patch functions (:func:`patch_static_force`,
:func:`update_patch_displacement`) once per plant step for all wheels at once: every
per-step function takes arrays (one entry per wheel), uses a fixed 12 + 12 node
Gauss-Legendre quadrature compiled with numba, and has no root finding. The
independent steady-state check of this model (adaptive quadrature and root finding,
written separately) is :mod:`lunar_drake.dynamics.wheel_reference`.

Frames and signs
----------------
Forces are expressed in each wheel's *contact frame* C: ``x`` forward along the wheel
heading projected on the terrain tangent plane, ``y`` to the left (along the axle),
``z`` along the terrain normal (up, out of the soil). The caller rotates them into the
world frame and applies them at the contact point.

* ``z`` (sinkage, m) is the penetration of the wheel's lowest point below the local
  terrain surface along ``C.z``, positive into the soil; ``z_dot`` (m/s) is positive
  while sinking.
* :class:`WheelForces`: ``vertical`` (N, along ``+C.z``: the load the stresses carry),
  ``thrust`` (N, along ``+C.x``), ``resistance`` (N, compaction resistance, positive
  when it opposes forward travel), ``drawbar_pull = thrust - resistance``, ``lateral``
  (N, along ``+C.y``) and ``torque`` (N m, the moment of the soil shear about the axle,
  positive when it opposes forward rolling; as a vector about ``+C.y`` it is
  ``-torque``).
* :func:`normal_force` is the force along ``+C.z``: ``vertical`` plus damping, >= 0.

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
  mirror image (wheel travelling backward: slip ``-s``, x-forces and torque negated)
  are blended with weights ``(1 + d)/2`` and ``(1 - d)/2``. Thus a wheel at rest
  (``v = 0``, ``omega = 0``) feels no tangential force (it still carries its load), and
  everything is continuous through ``v = 0``. Omit it (``None``) for a wheel known to
  travel forward.

Model (per wheel; theta measured from the downward vertical, positive forward)
------------------------------------------------------------------------------
Wong & Reece (1967) with Janosi & Hanamoto (1961) shear, as in Wong (2008), *Theory of
Ground Vehicles*, 4th ed., ch. 2 and 4, and Ishigami, Miwa, Nagatani & Yoshida (2007),
J. Field Robotics 24(3), for the lateral force:

* Entry angle ``theta_1 = arccos(1 - z/r)``, exit angle ``theta_2 = -rear_angle_ratio
  theta_1``, maximum-stress angle ``theta_m = (c1 + c2 s) theta_1`` (clamped to
  ``[0, 0.99] theta_1``).
* Normal stress, ``k = k_c/b + k_phi``: ahead of the peak
  ``sigma = k r^n (cos theta - cos theta_1)^n``; behind it the Wong-Reece mapping
  ``sigma = k r^n (cos(theta_1 - (theta - theta_2)(theta_1 - theta_m)/(theta_m -
  theta_2)) - cos theta_1)^n``.
* Shear on a surface of radius ``r_s = r + lambda h_g`` (grousers of height ``h_g``;
  Ding et al. 2011's equivalent radius, ``lambda`` = ``grouser_ratio``; ``r_s = r``
  without grousers): ``j = r_s[(theta_1 - theta) - (1 - s)(sin theta_1 - sin
  theta)]``, ``tau = (c + sigma tan phi)(1 - exp(-|j|/K)) sign(j)``.
* From the same stresses::

      V  = b int (r sigma cos theta + r_s tau sin theta)    vertical load carried
      H  = r_s b int tau cos theta                           thrust
      R  = r b int sigma sin theta                           compaction resistance
      DP = H - R,   T = r_s^2 b int tau                      drawbar pull, torque

  So the sinkage at which a wheel settles (``V`` = its load) depends on slip: the peak
  moves forward and the rear shear pulls down as ``s`` grows (slip-sinkage), and a
  dynamic simulation finds that sinkage itself (the normal force is ``V`` at the
  current penetration, plus damping). :func:`equilibrium_sinkage` solves it for a
  steady wheel.
* Lateral (Ishigami et al. 2007): ``j_y = r (1 - s)(theta_1 - theta) |tan beta|``,
  ``tau_y = (c + sigma tan phi)(1 - exp(-j_y / K_y))``; side-wall bulldozing
  ``R_b(h) = D1 (c h + D2 rho g h^2 / 2)`` per unit arc with ``h = r (cos theta - cos
  theta_1)``, ``X_c = 45 deg - phi/2``, ``D1 = cot X_c + tan(X_c + phi)``,
  ``D2 = cot X_c + cot^2 X_c tan phi``; ``F_y = -sign(beta)(r b int tau_y +
  |sin beta| int R_b(h)(r - h cos theta))``. The ``|sin beta|`` factor is ours: it
  fades the bulldozing in with the sideways share of the motion (Ishigami et al. switch
  it on for any ``beta != 0``, a step that an explicit dynamic step would chatter on).
  Longitudinal and lateral shear are not coupled through a common strength envelope.
* Compliant contact normal force: ``N = max(0, V + d(z) z_dot)`` with
  ``d(z) = 2 zeta sqrt(W'(z) W(z) / g)`` from Bekker's closed-form rigid-wheel load
  ``W(z) = (3 - n)(k_c + b k_phi) sqrt(2 r) z^((2n + 1)/2) / 3`` (:func:`bekker_load`;
  Bekker 1969): the damping that gives damping ratio ``zeta`` to a mass ``W(z)/g``
  resting at ``z``, a numerical choice (it vanishes at ``z = 0``). Bekker's ``W`` and
  compaction resistance (:func:`compaction_resistance`) are kept as classical closed
  forms; the wheel's load and resistance are the integrals above. At the same sinkage
  the Wong-Reece stresses (peak ahead of the bottom) carry less than Bekker's ``W``, so
  a wheel sits deeper than :func:`static_sinkage` says.

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

import numba
import numpy as np

from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError, check_range
from lunar_drake.moon import GRAVITY_MPS2

__all__ = [
    "GRC1",
    "JSC1A",
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
    "equilibrium_sinkage",
    "normal_force",
    "patch_length",
    "patch_slip_velocity",
    "patch_static_force",
    "patch_strength",
    "shear_radius",
    "shear_stress",
    "slip_angle",
    "slip_ratio",
    "slip_vs_drawbar_curve",
    "soil_preset",
    "static_sinkage",
    "static_weight",
    "travel_direction",
    "update_patch_displacement",
    "wheel_forces",
]


QUADRATURE_NODES_PER_SEGMENT = 12
"""Gauss-Legendre nodes on each of [theta_2, theta_m] and [theta_m, theta_1]."""

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
    """Rigid cylindrical wheel, optionally with grousers.

    Attributes:
        radius_m: rim radius r, m, in (0, 5].
        width_m: wheel (contact) width b, m, in (0, 3].
        grouser_height_m: grouser height h_g, m, in [0, radius_m]; 0 for a smooth rim.
        grouser_ratio: lambda in [0, 1]: the soil shears on a surface of radius
            ``r_s = r + lambda h_g`` (Ding et al. 2011's equivalent shear radius; 1: at
            the grouser tips, 0: grousers ignored).
    """

    radius_m: float = 0.25
    width_m: float = 0.2
    grouser_height_m: float = 0.0
    grouser_ratio: float = 1.0

    def __post_init__(self) -> None:
        _check("radius_m", self.radius_m, 0.0, 5.0, lo_open=True, unit=" m")
        _check("width_m", self.width_m, 0.0, 3.0, lo_open=True, unit=" m")
        _check("grouser_height_m", self.grouser_height_m, 0.0, self.radius_m,
               unit=" m (at most the radius)")  # fmt: skip
        _check("grouser_ratio", self.grouser_ratio, 0.0, 1.0)


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

JSC1A = SoilParams(
    name="jsc1a",
    # JSC-1A lunar mare soil simulant (Orbitec/NASA JSC, a crushed basaltic ash).
    # Verified (abstracts read via search): direct-shear friction angles of 30 to 70 deg
    # depending on relative density and normal load (Iai & Luna 2011, J. Aerospace
    # Engineering, "Direct shear tests on JSC-1A lunar regolith simulant"); peak triaxial
    # friction and dilatancy strongly density- and confinement-dependent (Alshibli &
    # Hasan 2009, J. Geotech. Geoenviron. Eng. 135(5)); Zeng et al. 2010 (J. Aerospace
    # Engineering 23(2), 111-116) and Arslan, Batiste & Sture 2010 (J. Aerospace
    # Engineering 23(1), 70-83) measured cohesion, friction and densities -- their
    # numbers were not at hand. Everything below is from memory or assumed:
    # * n, k_c, k_phi: assumed equal to the lunar nominal set (no verified bevameter
    #   triple for JSC-1A at hand; reported k_phi values for prepared beds scatter by
    #   4x or more with density).
    # * phi = 40 deg: a medium-dense triaxial value (from memory; inside the verified
    #   30-70 deg direct-shear range).
    # * c = 1.0 kPa: the simulant's angular, interlocking grains give more apparent
    #   cohesion than lunar nominal (from memory: ~0.5-3 kPa with density).
    # * K = 1.8 cm, K_y = K: assumed (lunar nominal).
    # * density 1.65 g/cm^3: a typical prepared-bed bulk density (from memory).
    # * c1, c2: Wong & Reece sand coefficients (as the other presets); no rebound.
    n=1.0,
    k_c=1400.0,
    k_phi=820_000.0,
    c=1000.0,
    phi=math.radians(40.0),
    K=0.018,
    c1=0.43,
    c2=0.32,
    rear_angle_ratio=0.0,
    K_y=0.018,
    density=1650.0,
    damping_ratio=0.5,
)
"""JSC-1A lunar simulant (see the inline notes: mostly from memory)."""

SOIL_PRESETS: dict[str, SoilParams] = {
    "lunar_regolith": LUNAR_REGOLITH,
    "grc1": GRC1,
    "jsc1a": JSC1A,
}


def soil_preset(name: str) -> SoilParams:
    """The named soil preset (case-insensitive; ``-`` and ``_`` optional: ``GRC-1``,
    ``JSC-1A``)."""
    key = str(name).strip().lower()
    if key in SOIL_PRESETS:
        return dataclasses.replace(SOIL_PRESETS[key])  # a copy: configs are mutable
    bare = key.replace("-", "").replace("_", "")
    if bare in SOIL_PRESETS:
        return dataclasses.replace(SOIL_PRESETS[bare])
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
    vertical,
    wheel: WheelParams,
    soil: SoilParams,
    gravity_mps2: float = GRAVITY_MPS2,
) -> np.ndarray:
    """Compliant contact normal force (N, along the terrain normal, >= 0).

    ``N = max(0, V + d(z) z_dot)`` with ``V`` the vertical load the Wong-Reece stresses
    carry at this sinkage and slip (``vertical``: :attr:`WheelForces.vertical`) and the
    damping :func:`contact_damping` ``d``. Both vanish at ``z = 0`` so ``N`` is
    continuous at contact onset; ``N = 0`` for ``z <= 0``.

    Args:
        z: penetration (sinkage), m, positive into the soil (array over wheels).
        z_dot: its rate, m/s, positive while sinking.
        vertical: V, N (array over wheels).
    """
    zp = np.maximum(np.asarray(z, dtype=np.float64), 0.0)
    d = contact_damping(zp, wheel=wheel, soil=soil, gravity_mps2=gravity_mps2)
    on = zp > 0.0
    return np.maximum(np.asarray(vertical) + d * np.asarray(z_dot, dtype=np.float64), 0.0) * on


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
        vertical: load the soil stresses carry along +z at this sinkage and slip, N
            (``b int (r sigma cos theta + r_s tau sin theta)``); the plant's normal force
            is this plus the contact damping (:func:`normal_force`).
        thrust: shear thrust ``r_s b int tau cos theta`` along +x, N.
        resistance: compaction resistance ``r b int sigma sin theta``, N, positive when
            opposing forward travel (acts along -x).
        drawbar_pull: thrust - resistance, the net force along +x, N.
        lateral: side force along +y (shear plus side-wall bulldozing), N.
        torque: soil moment about the axle ``r_s^2 b int tau``, N m, positive when
            opposing forward rolling (the torque a drive motor supplies in steady state).
    """

    vertical: np.ndarray
    thrust: np.ndarray
    resistance: np.ndarray
    drawbar_pull: np.ndarray
    lateral: np.ndarray
    torque: np.ndarray


@numba.njit(cache=True)
def _wong_reece_kernel(s, tan_beta, z, direction, par, U, WU, out):  # pragma: no cover - numba
    """Fills ``out`` (m, 6): vertical, thrust, resistance, torque, lateral shear integral,
    bulldozing integral (see :func:`wheel_forces`; ``par`` packs the wheel and soil)."""
    r, b, rs, n, ksig, c, tphi, K, Ky, c1, c2, rho, D1, D2g = (
        par[0], par[1], par[2], par[3], par[4], par[5], par[6], par[7], par[8], par[9],
        par[10], par[11], par[12], par[13],
    )  # fmt: skip
    m = s.shape[0]
    nq = U.shape[0]
    for i in range(m):
        zi = z[i]
        for q in range(6):
            out[i, q] = 0.0
        if not zi > 0.0:
            continue
        zi = min(max(zi, 1e-12 * r), r)
        cos1 = 1.0 - zi / r
        th1 = math.acos(cos1)
        sin1 = math.sin(th1)
        th2 = -rho * th1
        d = direction[i]
        wf = 0.5 * (1.0 + d)
        wb = 0.5 * (1.0 - d)
        lat_rate = abs(tan_beta[i]) * r / Ky
        for mode in range(2):
            w_mode = wf if mode == 0 else wb
            if w_mode == 0.0:
                continue
            sm = s[i] if mode == 0 else -s[i]  # the mirror image: travelling backward
            f = min(max(c1 + c2 * sm, 0.0), 0.99)
            thm = f * th1
            fz = 0.0
            h = 0.0
            res = 0.0
            tq = 0.0
            fy = 0.0
            fb = 0.0
            for seg in range(2):
                if seg == 0:  # front [theta_m, theta_1]
                    lo = thm
                    span = th1 - thm
                else:  # rear [theta_2, theta_m]
                    lo = th2
                    span = thm - th2
                if span <= 0.0:
                    continue
                for k in range(nq):
                    th = lo + U[k] * span
                    w = WU[k] * span
                    if seg == 0:
                        base = math.cos(th) - cos1
                    else:  # Wong-Reece: theta* = theta_1 - u (theta_1 - theta_m)
                        base = math.cos(th1 - U[k] * (th1 - thm)) - cos1
                    if base <= 0.0:
                        sig = 0.0
                    elif n == 1.0:
                        sig = ksig * base
                    else:
                        sig = ksig * base**n
                    cth = math.cos(th)
                    sth = math.sin(th)
                    strength = c + sig * tphi
                    j = rs * ((th1 - th) - (1.0 - sm) * (sin1 - sth))
                    tau = -strength * math.expm1(-abs(j) / K)
                    if j < 0.0:
                        tau = -tau
                    fz += w * (r * sig * cth + rs * tau * sth)
                    h += w * tau * cth
                    res += w * sig * sth
                    tq += w * tau
                    jy = (1.0 - sm) * (th1 - th) * lat_rate
                    fy += w * -strength * math.expm1(-jy)
                    hb = r * (cth - cos1)
                    fb += w * D1 * hb * (c + D2g * hb) * (r - hb * cth)
            sgn = 1.0 if mode == 0 else -1.0
            out[i, 0] += w_mode * b * fz
            out[i, 1] += sgn * w_mode * (rs * b) * h
            out[i, 2] += sgn * w_mode * (r * b) * res
            out[i, 3] += sgn * w_mode * (rs * rs * b) * tq
            out[i, 4] += w_mode * (r * b) * fy
            out[i, 5] += w_mode * fb


def _kernel_parameters(wheel: WheelParams, soil: SoilParams, gravity_mps2: float) -> np.ndarray:
    r = wheel.radius_m
    b = wheel.width_m
    xc = 0.25 * math.pi - 0.5 * soil.phi
    cot = 1.0 / math.tan(xc)
    D1 = cot + math.tan(xc + soil.phi)
    D2 = cot + cot * cot * math.tan(soil.phi)
    return np.array(
        [
            r,
            b,
            shear_radius(wheel),
            soil.n,
            (soil.k_c / b + soil.k_phi) * r**soil.n,
            soil.c,
            math.tan(soil.phi),
            soil.K,
            soil.K_y,
            soil.c1,
            soil.c2,
            soil.rear_angle_ratio,
            D1,
            # R_b = D1 (c h + D2 rho g h^2 / 2) = D1 h (c + D2g h)
            0.5 * D2 * soil.density * gravity_mps2,
        ]
    )


def shear_radius(wheel: WheelParams) -> float:
    """Radius of the shear surface r_s = r + grouser_ratio * grouser_height_m (m)."""
    return wheel.radius_m + wheel.grouser_ratio * wheel.grouser_height_m


def wheel_forces(
    *,
    slip,
    slip_angle,
    z,
    wheel: WheelParams,
    soil: SoilParams,
    direction=None,
    gravity_mps2: float = GRAVITY_MPS2,
) -> WheelForces:
    """Soil forces on each wheel for this step (vectorized over wheels; module docstring).

    One Wong-Reece wheel: normal stress and Janosi-Hanamoto shear integrated over the
    contact angle at sinkage ``z`` give the vertical load carried, thrust, compaction
    resistance, torque and (Ishigami et al.) lateral shear plus bulldozing, all from the
    same stresses. 12 + 12 Gauss-Legendre nodes on [theta_2, theta_m] and
    [theta_m, theta_1] (compiled with numba).

    Args:
        slip: slip ratio s (-), clipped to [-1, 1] (:func:`slip_ratio`).
        slip_angle: slip angle beta, rad (:func:`slip_angle`), in [-pi/2, pi/2].
        z: sinkage, m; sets the contact angles. A wheel with ``z <= 0`` is out of
            contact and gets all zeros; ``z`` is capped at ``r``.
        wheel, soil: parameters.
        direction: optional regularized travel sign in [-1, 1] (:func:`travel_direction`);
            ``None`` means travelling forward. The forward model and its mirror image
            (travel backward: slip -s, x-forces and torque negated) are blended with
            weights ``(1 +- direction)/2``, so a wheel at rest feels no tangential force.
        gravity_mps2: gravity for the bulldozing soil weight, m/s^2.

    Returns:
        WheelForces of arrays broadcast from the inputs (contact frame).
    """
    s = np.asarray(slip, dtype=np.float64)
    beta = np.asarray(slip_angle, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64)
    shape = s.shape
    if not (beta.shape == shape and z.shape == shape):
        s, beta, z = np.broadcast_arrays(s, beta, z)
        shape = s.shape
    s = np.minimum(np.maximum(s.ravel(), -1.0), 1.0)
    beta = beta.ravel()
    if direction is None:
        d = np.ones(s.size)
    else:
        d = np.asarray(direction, dtype=np.float64)
        if d.shape != shape:
            d = np.broadcast_to(d, shape)
        d = np.minimum(np.maximum(d.ravel(), -1.0), 1.0)
    out = np.empty((s.size, 6))
    par = _kernel_parameters(wheel, soil, gravity_mps2)
    _wong_reece_kernel(
        s, np.tan(beta), np.ascontiguousarray(z.ravel()), np.ascontiguousarray(d), par,
        _U, _WU, out,
    )  # fmt: skip
    sb = np.sign(beta)
    lateral = -sb * (out[:, 4] + np.abs(np.sin(beta)) * out[:, 5])
    return WheelForces(
        vertical=out[:, 0].reshape(shape),
        thrust=out[:, 1].reshape(shape),
        resistance=out[:, 2].reshape(shape),
        drawbar_pull=(out[:, 1] - out[:, 2]).reshape(shape),
        lateral=lateral.reshape(shape),
        torque=out[:, 3].reshape(shape),
    )


def equilibrium_sinkage(
    W, *, wheel: WheelParams, soil: SoilParams, slip=0.0, gravity_mps2: float = GRAVITY_MPS2
) -> np.ndarray:
    """Sinkage z (m) at which :func:`wheel_forces`' vertical load equals ``W`` (N) at slip
    ``slip`` (straight travel, forward); 0 for ``W <= 0``. Vectorized bisection (60
    halvings of [0, r]: ~1e-18 r). Raises ImmobilizedError where even ``z = r`` (the axle
    at the surface) cannot carry the load."""
    W, s = np.broadcast_arrays(np.asarray(W, dtype=np.float64), np.asarray(slip, dtype=float))
    shape = W.shape
    W = W.ravel()
    s = s.ravel()
    r = wheel.radius_m

    def vertical(zz):
        return wheel_forces(
            slip=s, slip_angle=0.0, z=zz, wheel=wheel, soil=soil, gravity_mps2=gravity_mps2
        ).vertical

    top = vertical(np.full(W.shape, r))
    if np.any(top < W):
        k = int(np.argmax(top < W))
        raise ImmobilizedError(
            f"load W = {W[k]:.6g} N sinks the wheel (r = {r:g} m) past its axle on "
            f"{soil.name}: at z = r it carries only {top[k]:.6g} N"
        )
    lo = np.zeros(W.shape)
    hi = np.full(W.shape, r)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = vertical(mid) < W
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    return np.where(W > 0.0, 0.5 * (lo + hi), 0.0).reshape(shape)


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
    """Steady drawbar pull DP(s) (N) of a wheel carrying load ``W`` (N): at the sinkage
    where the vertical load balances ``W`` at that slip (:func:`equilibrium_sinkage`).

    Vectorized: ``slip`` and ``W`` broadcast; straight travel (beta = 0), forward.
    """
    s, W = np.broadcast_arrays(np.asarray(slip, dtype=np.float64), np.asarray(W, dtype=float))
    z = equilibrium_sinkage(W, wheel=wheel, soil=soil, slip=s)
    return wheel_forces(slip=s, slip_angle=0.0, z=z, wheel=wheel, soil=soil).drawbar_pull


@dataclass(frozen=True)
class SlipCurve:
    """Steady straight-line wheel performance vs slip at one load (arrays over ``slip``).

    ``slip`` (-), ``thrust``, ``resistance``, ``drawbar_pull`` (N), ``torque`` (N m),
    ``sinkage`` (m, the equilibrium sinkage at each slip), ``load`` (N).
    """

    slip: np.ndarray
    thrust: np.ndarray
    resistance: np.ndarray
    drawbar_pull: np.ndarray
    torque: np.ndarray
    sinkage: np.ndarray
    load: float


def slip_vs_drawbar_curve(
    *, W: float, wheel: WheelParams, soil: SoilParams, slip=None
) -> SlipCurve:
    """Thrust, resistance, drawbar pull, torque and sinkage vs slip for one wheel at load
    ``W`` (N), each slip at its own equilibrium sinkage (slip-sinkage included).

    ``slip`` defaults to 100 points on [0, 0.99]. For plots of DP/W vs s (cf. the RP
    single-wheel drawbar pull tests the paper's slip plug-in was tuned on).
    """
    W = _real("W", W)
    if W <= 0.0:
        raise OutOfRangeError(f"W = {W!r} N must be > 0")
    s = np.linspace(0.0, 0.99, 100) if slip is None else np.asarray(slip, dtype=np.float64)
    z = equilibrium_sinkage(np.full(s.shape, W), wheel=wheel, soil=soil, slip=s)
    f = wheel_forces(slip=s, slip_angle=0.0, z=z, wheel=wheel, soil=soil)
    return SlipCurve(
        slip=s,
        thrust=f.thrust,
        resistance=f.resistance,
        drawbar_pull=f.drawbar_pull,
        torque=f.torque,
        sinkage=z,
        load=W,
    )
