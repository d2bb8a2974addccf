"""Size-frequency distributions (SFDs) of craters and rocks (paper section 4).

Every law is a cumulative areal density ``N(>=D)`` (number per m^2 of objects with
diameter at least ``D``, D in m). A law truncated to ``[d_min, d_max]`` holds
``N(d_min) - N(d_max)`` objects per m^2; :func:`sample_diameters` draws a Poisson count
with that mean (times the site area) and each diameter by inverting the truncated
cumulative law, ``D = N^-1(N(d_max) + u (N(d_min) - N(d_max)))`` with ``u ~ U[0, 1)``.

Crater laws (:class:`CraterSFD`)
--------------------------------
* ``"trask"``: the lunar equilibrium ("steady-state") population,
  ``N(>=D) = 10^-1.1 D^-2`` per m^2 (Trask 1966, Ranger photographs; Shoemaker's
  ``10^10.9 D^-2`` per 10^6 km^2). The default.
* ``"viper"``: the piecewise fit of the VIPER environmental specification,
  ``N = 29174 D^-1.92`` per km^2 for ``D <= 80 m`` and ``156228 D^-2.389`` per km^2 above
  (converted here to per m^2). The two pieces do not meet at 80 m: the cumulative law
  drops from 6.48 to 4.44 km^-2 there. Read literally, a cumulative step is a finite
  number of craters of exactly that diameter, so the inverse-CDF sampler maps the
  quantiles inside the step to D = 80 m. That keeps every count in the sample consistent
  with :meth:`CraterSFD.cumulative_density` (sampling each piece separately over its own
  range would lose the 2.04 km^-2 in the step; splicing the differential laws would
  change N for all D < 80 m).
* ``"powerlaw"``: ``N(>=D) = coefficient * D^exponent`` per m^2, ``exponent < 0``.

``sigma_log10`` lets the coefficient of a site vary lognormally: each call of
:func:`sample_diameters` multiplies the law by ``10^(sigma_log10 * z)``, ``z ~ N(0, 1)``
drawn once from the generator (the paper estimates this sigma from fit residuals).

Rock laws (:class:`RockSFD`)
----------------------------
* ``"golombek_rapp"``: cumulative fractional area ``F(D) = k exp(-q D)`` covered by rocks
  of diameter >= D, ``q = 1.79 + 0.152 / k`` (Golombek & Rapp 1997, JGR 102(E2),
  4117-4129; Golombek et al. 2003, JGR 108(E12), 8072). With a rock's area
  ``pi s^2 / 4``, the number density is
  ``N(>=D) = int_D^inf k q e^(-q s) / (pi s^2 / 4) ds = 4 k q E_2(q D) / (pi D)``, with
  ``E_2`` the generalised exponential integral (exact closed form).
* ``"powerlaw"``: ``N(>=D) = coefficient * D^exponent`` per m^2.

Craters already present in a source DEM (:func:`sample_diameters`,
``existing_diameters_m``) are removed from the sample, see :func:`remove_existing`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import special

from lunar_drake.errors import ConfigError, OutOfRangeError

__all__ = [
    "CRATER_LAWS",
    "ROCK_LAWS",
    "TRASK_COEFFICIENT_PER_M2",
    "VIPER_BREAK_M",
    "CraterSFD",
    "RockSFD",
    "cumulative_density",
    "expected_count",
    "largest_expected_diameter",
    "remove_existing",
    "sample_diameters",
]

CRATER_LAWS = ("trask", "viper", "powerlaw")
ROCK_LAWS = ("golombek_rapp", "powerlaw")

#: Trask (1966) equilibrium coefficient, N(>=D) = 10^-1.1 D^-2 per m^2 (D in m).
TRASK_COEFFICIENT_PER_M2 = 10.0**-1.1
TRASK_EXPONENT = -2.0
#: Break diameter (m) of the VIPER environmental-specification crater law.
VIPER_BREAK_M = 80.0
_VIPER_SMALL = (29174.0e-6, -1.92)  # per m^2 (29174 per km^2), D <= 80 m
_VIPER_LARGE = (156228.0e-6, -2.389)  # per m^2 (156228 per km^2), D > 80 m

# Number of table points and Newton steps of the numerical inverse (Golombek-Rapp).
_TABLE_POINTS = 1024
_NEWTON_STEPS = 3
_TINY = 1e-300


def _fmt(value) -> str:
    return repr(value)


def _check_finite(owner: str, name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"{owner}.{name} = {_fmt(value)} must be a real number")
    v = float(value)
    if not math.isfinite(v):
        raise OutOfRangeError(f"{owner}.{name} = {_fmt(value)} must be finite")
    return v


@dataclass(frozen=True)
class _Piece:
    """``N(>=D) = c D^e`` per m^2 on ``(lo, hi]`` (m)."""

    lo: float
    hi: float
    c: float
    e: float


def _pieces_cumulative(pieces: tuple[_Piece, ...], d: np.ndarray) -> np.ndarray:
    out = np.empty_like(d)
    with np.errstate(divide="ignore", over="ignore"):
        for i, p in enumerate(pieces):
            sel = d <= p.hi if i == 0 else (d > p.lo) & (d <= p.hi)
            out[sel] = p.c * d[sel] ** p.e
    return out


def _pieces_differential(pieces: tuple[_Piece, ...], d: np.ndarray) -> np.ndarray:
    out = np.empty_like(d)
    with np.errstate(divide="ignore", over="ignore"):
        for i, p in enumerate(pieces):
            sel = d <= p.hi if i == 0 else (d > p.lo) & (d <= p.hi)
            out[sel] = -p.e * p.c * d[sel] ** (p.e - 1.0)
    return out


def _pieces_inverse(pieces: tuple[_Piece, ...], v: np.ndarray) -> np.ndarray:
    """``sup{D : N(D) >= v}`` of a decreasing piecewise power law (steps -> atoms)."""
    best = np.full(v.shape, -np.inf)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        for p in pieces:
            s = (v / p.c) ** (1.0 / p.e)
            ok = s >= p.lo  # N(lo) >= v: the piece holds D with N(D) >= v
            best = np.where(ok, np.maximum(best, np.minimum(s, p.hi)), best)
    return best


def _as_float_array(d_m) -> np.ndarray:
    return np.asarray(d_m, dtype=np.float64)


@dataclass(frozen=True)
class CraterSFD:
    """Cumulative crater size-frequency law ``N(>=D)`` per m^2 (D in m).

    Attributes:
        law: ``"trask"`` (Trask 1966 equilibrium, ``10^-1.1 D^-2``; default),
            ``"viper"`` (VIPER environmental spec, piecewise at 80 m) or ``"powerlaw"``.
        coefficient: ``c`` of ``N = c D^exponent`` per m^2 (``"powerlaw"`` only; > 0).
        exponent: cumulative slope (``"powerlaw"`` only; < 0).
        sigma_log10: standard deviation of the site-to-site variation of log10 of the
            coefficient (>= 0); drawn once per :func:`sample_diameters` call.
    """

    law: str = "trask"
    coefficient: float | None = None
    exponent: float | None = None
    sigma_log10: float = 0.0

    def __post_init__(self):
        owner = "CraterSFD"
        if self.law not in CRATER_LAWS:
            raise ConfigError(
                f"{owner}.law = {_fmt(self.law)} is unknown; choose one of {list(CRATER_LAWS)}"
            )
        if self.law == "powerlaw":
            if self.coefficient is None or self.exponent is None:
                raise ConfigError(
                    f"{owner}(law='powerlaw') needs coefficient and exponent; got "
                    f"coefficient = {_fmt(self.coefficient)}, exponent = {_fmt(self.exponent)}"
                )
            _check_powerlaw(owner, self.coefficient, self.exponent)
        elif self.coefficient is not None or self.exponent is not None:
            raise ConfigError(
                f"{owner}.coefficient = {_fmt(self.coefficient)} / exponent = "
                f"{_fmt(self.exponent)} only apply to law='powerlaw', not {self.law!r}"
            )
        s = _check_finite(owner, "sigma_log10", self.sigma_log10)
        if not 0.0 <= s <= 3.0:
            raise OutOfRangeError(
                f"{owner}.sigma_log10 = {_fmt(self.sigma_log10)}; allowed [0, 3] (decades)"
            )

    @property
    def pieces(self) -> tuple[_Piece, ...]:
        """The law as power-law pieces ``(lo, hi, c per m^2, exponent)``."""
        if self.law == "trask":
            return (_Piece(0.0, math.inf, TRASK_COEFFICIENT_PER_M2, TRASK_EXPONENT),)
        if self.law == "viper":
            return (
                _Piece(0.0, VIPER_BREAK_M, *_VIPER_SMALL),
                _Piece(VIPER_BREAK_M, math.inf, *_VIPER_LARGE),
            )
        return (_Piece(0.0, math.inf, float(self.coefficient), float(self.exponent)),)

    def cumulative_density(self, d_m) -> np.ndarray:
        """``N(>=D)`` per m^2 for diameters ``d_m`` (m, > 0; array-like)."""
        return _pieces_cumulative(self.pieces, _as_float_array(d_m))

    def differential_density(self, d_m) -> np.ndarray:
        """``-dN/dD`` per m^2 per m (the Dirac mass of a step of the law is not included)."""
        return _pieces_differential(self.pieces, _as_float_array(d_m))

    def inverse_cumulative(self, n_per_m2, *, d_min_m: float, d_max_m) -> np.ndarray:
        """Largest ``D`` in ``[d_min_m, d_max_m]`` with ``N(>=D) >= n_per_m2`` (m).

        ``d_max_m`` may be an array broadcast against ``n_per_m2``. A step down of the
        cumulative law (VIPER at 80 m) maps every ``n`` inside the step to the step's
        diameter.
        """
        d = _pieces_inverse(self.pieces, _as_float_array(n_per_m2))
        return np.clip(d, d_min_m, d_max_m)


def _check_powerlaw(owner: str, coefficient, exponent) -> None:
    c = _check_finite(owner, "coefficient", coefficient)
    e = _check_finite(owner, "exponent", exponent)
    if not c > 0:
        raise OutOfRangeError(f"{owner}.coefficient = {_fmt(coefficient)} must be > 0 (per m^2)")
    if not -10.0 <= e < 0:
        raise OutOfRangeError(
            f"{owner}.exponent = {_fmt(exponent)}; a cumulative power law needs an exponent "
            "in [-10, 0)"
        )


@dataclass(frozen=True)
class RockSFD:
    """Cumulative rock size-frequency law ``N(>=D)`` per m^2 (D in m).

    Attributes:
        law: ``"golombek_rapp"`` (default) or ``"powerlaw"``.
        k: Golombek-Rapp total fractional area covered by rocks, in (0, 1). Default
            0.005 (0.5 %), a sparse background between craters; the rocky Viking and
            Pathfinder landing sites on Mars have k up to ~0.2 (Golombek & Rapp 1997).
        coefficient, exponent: ``N = coefficient * D^exponent`` per m^2 (``"powerlaw"``
            only; coefficient > 0, exponent < 0).
    """

    law: str = "golombek_rapp"
    k: float = 0.005
    coefficient: float | None = None
    exponent: float | None = None

    def __post_init__(self):
        owner = "RockSFD"
        if self.law not in ROCK_LAWS:
            raise ConfigError(
                f"{owner}.law = {_fmt(self.law)} is unknown; choose one of {list(ROCK_LAWS)}"
            )
        if self.law == "golombek_rapp":
            k = _check_finite(owner, "k", self.k)
            if not 0.0 < k < 1.0:
                raise OutOfRangeError(
                    f"{owner}.k = {_fmt(self.k)}; the rock-covered area fraction must lie in (0, 1)"
                )
            if self.coefficient is not None or self.exponent is not None:
                raise ConfigError(
                    f"{owner}.coefficient = {_fmt(self.coefficient)} / exponent = "
                    f"{_fmt(self.exponent)} only apply to law='powerlaw'"
                )
        else:
            if self.coefficient is None or self.exponent is None:
                raise ConfigError(
                    f"{owner}(law='powerlaw') needs coefficient and exponent; got "
                    f"coefficient = {_fmt(self.coefficient)}, exponent = {_fmt(self.exponent)}"
                )
            _check_powerlaw(owner, self.coefficient, self.exponent)

    @property
    def q(self) -> float:
        """Golombek-Rapp decay rate ``q = 1.79 + 0.152 / k`` (1/m)."""
        return 1.79 + 0.152 / self.k

    def cumulative_fractional_area(self, d_m) -> np.ndarray:
        """``F(>=D)``: fraction of the surface covered by rocks of diameter >= D."""
        d = _as_float_array(d_m)
        if self.law == "golombek_rapp":
            return self.k * np.exp(-self.q * d)
        c, e = float(self.coefficient), float(self.exponent)
        if e >= -2.0:
            raise OutOfRangeError(
                f"RockSFD.exponent = {_fmt(self.exponent)}: the covered area of a power law "
                "diverges unless exponent < -2"
            )
        # F = int_D^inf (pi s^2 / 4) (-e c s^(e-1)) ds
        return np.pi / 4.0 * (-e) * c * d ** (e + 2.0) / (-(e + 2.0))

    def cumulative_density(self, d_m) -> np.ndarray:
        """``N(>=D)`` per m^2 for diameters ``d_m`` (m, > 0; array-like)."""
        d = _as_float_array(d_m)
        if self.law == "powerlaw":
            with np.errstate(divide="ignore", over="ignore"):
                return float(self.coefficient) * d ** float(self.exponent)
        q = self.q
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return 4.0 * self.k * q * special.expn(2, q * d) / (np.pi * d)

    def differential_density(self, d_m) -> np.ndarray:
        """``-dN/dD`` per m^2 per m."""
        d = _as_float_array(d_m)
        with np.errstate(divide="ignore", over="ignore"):
            if self.law == "powerlaw":
                c, e = float(self.coefficient), float(self.exponent)
                return -e * c * d ** (e - 1.0)
            q = self.q
            return self.k * q * np.exp(-q * d) / (np.pi * d * d / 4.0)

    def inverse_cumulative(self, n_per_m2, *, d_min_m: float, d_max_m) -> np.ndarray:
        """Largest ``D`` in ``[d_min_m, d_max_m]`` with ``N(>=D) >= n_per_m2`` (m).

        Power law: closed form. Golombek-Rapp: interpolation in a log-log table of the
        exact law, then Newton steps on ``ln N(ln D)`` (relative error ~1e-12).
        """
        v = _as_float_array(n_per_m2)
        if v.size == 0:
            return np.zeros(v.shape)
        if self.law == "powerlaw":
            with np.errstate(divide="ignore", over="ignore"):
                d = (v / float(self.coefficient)) ** (1.0 / float(self.exponent))
            return np.clip(d, d_min_m, d_max_m)
        d_hi = float(np.max(d_max_m))
        lo, hi = math.log(d_min_m), math.log(d_hi)
        grid = np.linspace(lo, hi, _TABLE_POINTS)
        ln_n = np.log(np.maximum(self.cumulative_density(np.exp(grid)), _TINY))
        y = np.log(np.maximum(v, _TINY))
        u = np.interp(y, ln_n[::-1], grid[::-1])
        u_max = np.log(np.broadcast_to(np.asarray(d_max_m, dtype=np.float64), u.shape))
        u = np.clip(u, lo, u_max)
        for _ in range(_NEWTON_STEPS):
            dd = np.exp(u)
            n = self.cumulative_density(dd)
            dn = self.differential_density(dd)
            good = (n > _TINY) & (dn > 0)
            with np.errstate(divide="ignore", invalid="ignore"):
                step = (np.log(np.where(good, n, 1.0)) - y) / np.where(good, -dd * dn / n, 1.0)
            u = np.clip(np.where(good, u - step, u), lo, u_max)
        return np.exp(u)


SFD = CraterSFD | RockSFD


def cumulative_density(d_m, *, sfd: SFD) -> np.ndarray:
    """``N(>=D)`` per m^2 of ``sfd`` at diameters ``d_m`` (m)."""
    return sfd.cumulative_density(d_m)


def _check_sfd(sfd) -> None:
    if not isinstance(sfd, (CraterSFD, RockSFD)):
        raise ConfigError(f"sfd = {sfd!r} must be a CraterSFD or RockSFD")


def _check_range(d_min_m, d_max_m, *, what: str = "") -> tuple[float, float]:
    lo = _check_finite("sfd", f"{what}d_min_m", d_min_m)
    hi = _check_finite("sfd", f"{what}d_max_m", d_max_m)
    if not lo > 0:
        raise OutOfRangeError(f"{what}d_min_m = {_fmt(d_min_m)} must be > 0 m")
    if not hi > lo:
        raise OutOfRangeError(
            f"{what}d_max_m = {_fmt(d_max_m)} must exceed {what}d_min_m = {_fmt(d_min_m)} (m)"
        )
    return lo, hi


def _check_area(area_m2) -> float:
    a = _check_finite("sfd", "area_m2", area_m2)
    if not a >= 0:
        raise OutOfRangeError(f"area_m2 = {_fmt(area_m2)} must be >= 0 m^2")
    return a


def expected_count(sfd: SFD, *, area_m2: float, d_min_m: float, d_max_m: float) -> float:
    """Expected number of objects with ``d_min_m <= D <= d_max_m`` in ``area_m2`` (m^2).

    Uses the nominal law (no ``sigma_log10`` variation).
    """
    _check_sfd(sfd)
    lo, hi = _check_range(d_min_m, d_max_m)
    a = _check_area(area_m2)
    n = sfd.cumulative_density(np.array([lo, hi]))
    return float(a * (n[0] - n[1]))


def largest_expected_diameter(sfd: SFD, *, area_m2: float) -> float:
    """Diameter ``D`` (m) with ``N(>=D) * area_m2 = 1``: the largest object expected once."""
    _check_sfd(sfd)
    a = _check_area(area_m2)
    if a == 0:
        raise OutOfRangeError("area_m2 = 0 holds no object; it must be > 0 m^2")
    return float(sfd.inverse_cumulative(np.array([1.0 / a]), d_min_m=1e-6, d_max_m=1e7)[0])


def remove_existing(
    diameters_m, *, existing_diameters_m: Sequence[float], d_min_m: float, d_max_m: float
) -> np.ndarray:
    """Mask (True = keep) that drops one sampled crater per existing crater.

    Rule: diameters are binned in factor-of-2 bins anchored at ``d_min_m``
    (bin ``floor(log2(D / d_min_m))``). Existing craters outside ``[d_min_m, d_max_m]``
    are ignored; the others are taken largest first, and each removes the still-kept
    sampled crater of its own bin that is nearest in ``ln D`` (the earliest drawn on a
    tie). An existing crater whose bin has no sampled crater left removes nothing; the
    deficit is not carried to other bins.
    """
    d = _as_float_array(diameters_m)
    keep = np.ones(d.shape, dtype=bool)
    e = _as_float_array(list(existing_diameters_m)).ravel()
    e = e[np.isfinite(e) & (e >= d_min_m) & (e <= d_max_m)]
    if e.size == 0 or d.size == 0:
        return keep
    ln_d = np.log(d)
    bins = np.floor(np.log2(d / d_min_m))
    for ei in np.sort(e, kind="stable")[::-1]:
        cand = np.flatnonzero(keep & (bins == math.floor(math.log2(ei / d_min_m))))
        if cand.size:
            j = cand[np.argmin(np.abs(ln_d[cand] - math.log(ei)))]
            keep[j] = False
    return keep


def sample_diameters(
    rng: np.random.Generator,
    *,
    sfd: SFD,
    area_m2: float,
    d_min_m: float,
    d_max_m: float,
    existing_diameters_m: Sequence[float] = (),
) -> np.ndarray:
    """Diameters (m, float64, in draw order) of one random population in ``area_m2``.

    Draws, in this order from ``rng``: the site factor ``10^(sigma_log10 z)`` (only when
    ``sfd.sigma_log10 > 0``), a Poisson count with mean
    ``factor * area_m2 * (N(d_min) - N(d_max))``, and one uniform per object that is
    mapped through the inverse truncated cumulative law. Then
    :func:`remove_existing` drops one sampled crater per ``existing_diameters_m`` entry
    (craters already in a source DEM), so nothing is counted twice.
    """
    _check_sfd(sfd)
    lo, hi = _check_range(d_min_m, d_max_m)
    a = _check_area(area_m2)
    factor = 1.0
    sigma = float(getattr(sfd, "sigma_log10", 0.0))
    if sigma > 0:
        factor = 10.0 ** (sigma * rng.standard_normal())
    n_lo, n_hi = sfd.cumulative_density(np.array([lo, hi]))
    count = int(rng.poisson(factor * a * max(float(n_lo - n_hi), 0.0)))
    u = rng.random(count)
    d = sfd.inverse_cumulative(n_hi + u * (n_lo - n_hi), d_min_m=lo, d_max_m=hi)
    if len(existing_diameters_m):
        d = d[remove_existing(d, existing_diameters_m=existing_diameters_m, d_min_m=lo, d_max_m=hi)]
    return d
