"""Site-level crater and rock catalogs (paper section 4, paragraphs 3-4).

:func:`synthesize_catalogs` follows the paper's recipe; every random number comes from
:func:`lunar_drake.rng.generator` streams named ``catalog/...`` (never per pixel):

1. **Crater sizes** from the crater SFD over the site area (:mod:`.sfd`), less one
   sampled crater per crater already in a source DEM (``existing_craters``).
2. **Ages.** Crater of diameter D lives ``L(D) = c D^2 / kappa(D)`` years before
   diffusive degradation erases it, with ``kappa(D) = kappa_ref (D / D_ref)^beta``:
   ``kappa_ref = 5.5 m^2/Myr`` measured on 0.8-5 km mare craters (Fassett & Thomson
   2014, JGR Planets 119, 2255), ``c = 0.2`` (with their kappa, kappa t / D^2 = 0.18 left
   a 300 m crater at ~7 % of its fresh depth after 3 Gyr, "beyond recognition" just
   below that size) and ``beta = 1``: small-crater degradation is scale dependent
   (Minton et al. 2019, Icarus 326, 63), and ``L ~ D`` turns the ``~D^-3`` production
   function into the ``D^-2`` equilibrium of Trask (1966). Defaults give ``L = 36 Myr``
   at D = 1 m and ``L = T = 3.5 Gyr`` at ~100 m, the equilibrium onset of the maria.
   Ages are ``U(0, min(T, L(D)))`` (small craters uniformly distributed over their short
   lifetime, large ones over the surface age T -- the paper's ref. [17] scheme), and
   ``freshness = 1 - (1 - min_freshness) * age / L(D)`` in ``[min_freshness, 1]``.
   Craters are then ordered by formation time, oldest first, and flagged ``ejecta``
   when ``D >= ejecta_min_diameter_m``.
3. **Places**: uniform in the site (a crater may extend past the edge).
4. **Ejecta map**: each ejecta crater stencils weights ``w(r / R)``, times its freshness
   f and its rock yield Y (``ejecta_yield_exponent``), onto a coarse
   :class:`EjectaMap`: ``interior`` inside ``(1 - h) R``, ``rim`` on the annulus
   ``|r / R - 1| <= h`` and ``rim * (r / ((1 + h) R))^alpha`` on the blanket out to
   ``blanket_extent * R`` (``alpha = -3``: McGetchin et al. 1973, EPSL 20, 226).
5. **Rocks**, forward in time over ``n_time_steps`` equal steps of ``T / n``.
   Background rocks are born uniformly in time and space from ``rock_sfd_background``.
   Each ejecta crater throws, when it forms, rocks with local density
   ``f Y w(r / R) N_ej(>=D)`` (``N_ej`` = ``rock_sfd_ejecta``, the rock SFD on the rim of
   a fresh full-yield crater), sizes capped at the largest block the crater can make
   (``ejecta_max_rock_coefficient * D_crater^ejecta_max_rock_exponent``) and positions
   drawn from its own stencil -- the same point process as thinning against the ejecta
   map, without the map's cell discretisation. At the start of every later step each
   rock is covered by regolith with probability ``p``; a new crater covers every older
   rock whose centre lies within its rim radius.

Vectorisation: the per-step Bernoulli burial of a rock born in step ``k`` amounts to
surviving ``n - 1 - k`` independent trials, so (Poisson thinning) only the survivors of
those trials are drawn, each population with its Poisson mean multiplied by
``(1 - p)^(n - 1 - k)`` -- the same distribution as simulating every step. Crater
burial compares formation times of rocks and craters through one KD-tree query
(``scipy.spatial.cKDTree``).

The configured background SFD is the present-day (observed) population: with
``compensate_background_burial`` the birth rate is raised by the expected burial loss
(regolith and crater cover, the latter as ``prod (1 - pi R^2 / A)`` over younger
craters), so the surviving background follows the SFD on average. With burial disabled
(``rock_burial_probability_per_step = 0``, ``crater_burial = False``) it follows the SFD
exactly (Poisson counts). Ejecta rocks are not compensated: their loss with crater age
is the point.

Existing craters only remove their counterparts from the sample; they are already in
the DEM, so they are not in the returned catalog and throw no ejecta.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from lunar_drake import rng as rng_mod
from lunar_drake.errors import ConfigError, OutOfRangeError
from lunar_drake.files import atomic_path
from lunar_drake.terrain.grid import GridSpec
from lunar_drake.terrain.sfd import (
    CraterSFD,
    RockSFD,
    largest_expected_diameter,
    sample_diameters,
)

__all__ = [
    "POPULATION_BACKGROUND",
    "POPULATION_EJECTA",
    "CatalogParams",
    "CraterCatalog",
    "EjectaMap",
    "RockCatalog",
    "ejecta_weight",
    "synthesize_catalogs",
]

POPULATION_BACKGROUND = 0
POPULATION_EJECTA = 1
_POPULATION_NAMES = ("background", "ejecta")
_FLOAT_FMT = "{:.9g}"
# Largest temporary array (elements) when stencilling one crater onto the ejecta map.
_MAP_BLOCK_ELEMENTS = 1 << 21


# --------------------------------------------------------------------------- catalogs


class _Catalog:
    """Shared behaviour of the catalogs: equal-length 1-D arrays in a fixed order."""

    def _check(self) -> None:
        n = None
        for f in fields(self):
            a = getattr(self, f.name)
            if a.ndim != 1:
                raise ConfigError(
                    f"{type(self).__name__}.{f.name} must be 1-D; got shape {a.shape}"
                )
            if n is None:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise ConfigError(
                    f"{type(self).__name__}.{f.name} has {a.shape[0]} entries; the other "
                    f"arrays have {n}"
                )

    def __len__(self) -> int:
        return int(self.x_m.shape[0])

    def subset(self, mask):
        """The entries selected by a boolean mask (or integer indices), order kept."""
        m = np.asarray(mask)
        if m.dtype != bool:
            idx = m.astype(np.intp).ravel()
            m = np.zeros(len(self), dtype=bool)
            m[idx] = True
        elif m.shape != (len(self),):
            raise ConfigError(f"mask has shape {m.shape}; expected ({len(self)},)")
        return type(self)(**{f.name: getattr(self, f.name)[m] for f in fields(self)})

    def indices_in_box(
        self,
        x_min: float,
        x_max: float,
        y_min: float,
        y_max: float,
        *,
        margin_fn: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> np.ndarray:
        """Indices (ascending) of entries whose extent ``centre +- margin`` meets the box.

        ``margin_fn(diameter_m) -> margin_m``; default half the diameter.
        """
        d = self.diameter_m
        m = 0.5 * d if margin_fn is None else np.broadcast_to(margin_fn(d), d.shape)
        return np.flatnonzero(
            (self.x_m + m >= x_min)
            & (self.x_m - m <= x_max)
            & (self.y_m + m >= y_min)
            & (self.y_m - m <= y_max)
        )

    def in_box(
        self,
        x_min: float,
        x_max: float,
        y_min: float,
        y_max: float,
        *,
        margin_fn: Callable[[np.ndarray], np.ndarray] | None = None,
    ):
        """The ordered subset of entries whose extent intersects the box (m)."""
        return self.subset(self.indices_in_box(x_min, x_max, y_min, y_max, margin_fn=margin_fn))


def _float_array(a) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64))


@dataclass(frozen=True, eq=False)
class CraterCatalog(_Catalog):
    """Craters of a site, ordered by formation time (oldest first).

    Attributes (equal-length arrays):
        x_m, y_m: centre in site coordinates (m, x east, y north, origin at the site centre).
        diameter_m: rim-crest diameter (m).
        age_yr: time since formation (yr).
        freshness: degradation state in (0, 1], 1 = fresh.
        ejecta: whether the crater threw ejecta rocks (bool).
    """

    x_m: np.ndarray
    y_m: np.ndarray
    diameter_m: np.ndarray
    age_yr: np.ndarray
    freshness: np.ndarray
    ejecta: np.ndarray

    def __post_init__(self):
        for name in ("x_m", "y_m", "diameter_m", "age_yr", "freshness"):
            object.__setattr__(self, name, _float_array(getattr(self, name)))
        object.__setattr__(self, "ejecta", np.asarray(self.ejecta, dtype=bool))
        self._check()

    def to_csv(self, path: str | os.PathLike, *, depth_m) -> Path:
        """Writes ``x_m,y_m,diameter_m,depth_m,age_yr,freshness`` atomically.

        ``depth_m``: rim-to-floor depth of each crater (m), from the crater-shape module.
        """
        depth = _float_array(depth_m)
        if depth.shape != (len(self),):
            raise ConfigError(
                f"depth_m has shape {depth.shape}; expected ({len(self)},), one per crater"
            )
        cols = (self.x_m, self.y_m, self.diameter_m, depth, self.age_yr, self.freshness)
        header = "x_m,y_m,diameter_m,depth_m,age_yr,freshness"
        return _write_csv(path, header, [_fmt_col(c) for c in cols])


@dataclass(frozen=True, eq=False)
class RockCatalog(_Catalog):
    """Rocks of a site, in birth order (oldest first).

    Attributes (equal-length arrays):
        x_m, y_m: centre in site coordinates (m).
        diameter_m: diameter (m).
        height_m: height above the local surface (m).
        population: uint8, 0 = background, 1 = ejecta.
        shape_index: int16, which rock of the height-field library (0 .. n_shapes - 1).
        age_yr: time since the rock was emplaced (yr); zeros when not given.
    """

    x_m: np.ndarray
    y_m: np.ndarray
    diameter_m: np.ndarray
    height_m: np.ndarray
    population: np.ndarray
    shape_index: np.ndarray
    age_yr: np.ndarray | None = None

    def __post_init__(self):
        for name in ("x_m", "y_m", "diameter_m", "height_m"):
            object.__setattr__(self, name, _float_array(getattr(self, name)))
        object.__setattr__(self, "population", np.asarray(self.population, dtype=np.uint8))
        object.__setattr__(self, "shape_index", np.asarray(self.shape_index, dtype=np.int16))
        age = np.zeros(len(self.x_m)) if self.age_yr is None else self.age_yr
        object.__setattr__(self, "age_yr", _float_array(age))
        self._check()

    def to_csv(self, path: str | os.PathLike) -> Path:
        """Writes ``x_m,y_m,diameter_m,height_m,population`` atomically (population as
        the word ``background`` or ``ejecta``)."""
        names = np.array(_POPULATION_NAMES)
        pop = self.population
        if len(pop) and int(pop.max()) >= len(names):
            raise ConfigError(f"population holds {int(pop.max())}; allowed 0 or 1")
        cols = [_fmt_col(c) for c in (self.x_m, self.y_m, self.diameter_m, self.height_m)]
        cols.append(names[pop].tolist())
        return _write_csv(path, "x_m,y_m,diameter_m,height_m,population", cols)


def _fmt_col(a: np.ndarray) -> list[str]:
    return [_FLOAT_FMT.format(v) for v in a.tolist()]


def _write_csv(path, header: str, cols: Sequence[Sequence[str]]) -> Path:
    lines = [header]
    lines.extend(",".join(row) for row in zip(*cols, strict=True))
    return _atomic_write_text(Path(path), "\n".join(lines) + "\n")


def _atomic_write_text(path: Path, text: str) -> Path:
    """Writes ``text`` (UTF-8, ``\n`` line ends) to a temporary file beside ``path`` and
    renames it into place (:func:`lunar_drake.files.atomic_path`)."""
    with (
        atomic_path(path, what="catalog") as tmp,
        open(tmp, "w", encoding="utf-8", newline="") as f,
    ):
        f.write(text)
    return path


# --------------------------------------------------------------------------- ejecta map


@dataclass(frozen=True, eq=False)
class EjectaMap:
    """Coarse map of ejecta-rock probability over the site.

    ``values[row, col]`` (float32, row 0 north) is the sum over ejecta craters of
    ``freshness * yield * w(r / R)`` averaged over the cell (stencils are sub-sampled
    for craters smaller than the cell): the ejecta-rock density at birth is
    ``values * N_ej(>=D)`` per m^2. Cell ``(row, col)`` covers
    ``x in [x_min + col * cell_m, x_min + (col + 1) * cell_m)`` and
    ``y in (y_max - (row + 1) * cell_m, y_max - row * cell_m]``.
    """

    values: np.ndarray
    cell_m: float
    x_min: float
    y_max: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape

    def value_at(self, x, y) -> np.ndarray:
        """Map value of the cell holding each site point ``(x, y)`` (m); 0 outside."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        col = np.floor((x - self.x_min) / self.cell_m)
        row = np.floor((self.y_max - y) / self.cell_m)
        nr, nc = self.values.shape
        inside = (col >= 0) & (col < nc) & (row >= 0) & (row < nr)
        r = np.where(inside, row, 0).astype(np.intp)
        c = np.where(inside, col, 0).astype(np.intp)
        return np.where(inside, self.values[r, c], np.float32(0.0)).astype(np.float32)


# --------------------------------------------------------------------------- parameters


def _real(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"CatalogParams.{name} = {value!r} must be a real number")
    v = float(value)
    if not math.isfinite(v):
        raise OutOfRangeError(f"CatalogParams.{name} = {value!r} must be finite")
    return v


def _in(name, value, lo=-math.inf, hi=math.inf, *, lo_open=False, hi_open=False, unit=""):
    v = _real(name, value)
    bad = v < lo or v > hi or (lo_open and v == lo) or (hi_open and v == hi)
    if bad:
        lb = "(" if lo_open else "["
        rb = ")" if hi_open else "]"
        raise OutOfRangeError(
            f"CatalogParams.{name} = {value!r}{unit}; allowed {lb}{lo:g}, {hi:g}{rb}{unit}"
        )
    return v


def _int_in(name, value, lo, hi):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConfigError(f"CatalogParams.{name} = {value!r} must be an integer")
    if not lo <= int(value) <= hi:
        raise OutOfRangeError(f"CatalogParams.{name} = {value!r}; allowed [{lo}, {hi}]")
    return int(value)


@dataclass(frozen=True)
class CatalogParams:
    """How a site's crater and rock catalogs are drawn (units: m, yr).

    Craters:
        crater_sfd: crater size-frequency law (default Trask 1966 equilibrium).
        d_min_m: smallest crater diameter (m). Default 0.5.
        d_max_m: largest crater diameter (m); ``None``: the diameter expected once in the
            site (``N(>=D) A = 1``), capped at half the shorter site side (if that is
            below ``d_min_m``, the cap alone).
        existing_craters: ``(x_m, y_m, diameter_m)`` of craters already in a source DEM;
            one sampled crater of similar size is dropped for each whose centre lies in
            the site (see :func:`.sfd.remove_existing`).
    Ages (see the module docstring):
        surface_age_yr: age T of the surface (yr). Default 3.5e9 (mare-like).
        degradation_kappa_m2_per_myr: topographic diffusivity at the reference diameter
            (m^2/Myr). Default 5.5 (Fassett & Thomson 2014).
        degradation_reference_diameter_m: diameter (m) at which that diffusivity holds.
            Default 1000 (their craters were 0.8-5 km).
        degradation_kappa_exponent: beta in ``kappa ~ D^beta``. Default 1 (scale-dependent
            degradation, Minton et al. 2019); 0 gives a constant kappa.
        erasure_kappa_t_over_d2: ``kappa t / D^2`` at which a crater is erased. Default 0.2.
        min_freshness: freshness of a crater at the end of its lifetime, in (0, 1].
    Ejecta craters and stencil (lengths in crater radii R):
        ejecta_min_diameter_m: craters with ``D >=`` this throw ejecta rocks. A crater
            penetrates a surface layer of thickness h, and throws out the coarser
            material below, once ``D >~ 4 h`` (Quaide & Oberbeck 1968, JGR 73, 5247; the
            onset of blocky craters maps regolith depth in Bart et al. 2011, Icarus 215,
            485). Default 2 m: a ~0.5 m block-poor top layer over regolith that already
            holds rock fragments, suited to small sites. The regolith is ~4-5 m thick on
            the maria and ~10-15 m in the highlands (McKay et al. 1991, Lunar Sourcebook,
            ch. 7), so bedrock blocks need D >~ 20-60 m; raise it to model only those.
        ejecta_yield_exponent: an ejecta crater's rock yield is
            ``(1 - ejecta_min_diameter_m / D)^exponent``: with exponent 2 (default) the
            fraction of a paraboloidal cavity (depth proportional to D) lying below the
            layer a crater of ``ejecta_min_diameter_m`` just penetrates. 0: full yield.
        ejecta_interior_density: stencil weight on the crater floor and walls
            (``r < (1 - h) R``). Default 0.5.
        ejecta_rim_density: weight on the rim annulus. Default 1 (defines the scale of
            ``rock_sfd_ejecta``).
        ejecta_rim_half_width: h, half-width of the rim annulus (R). Default 0.2.
        ejecta_blanket_extent: outer radius of the rocky blanket (R). Default 3: the
            continuous ejecta reach about one crater diameter beyond the rim
            (Melosh 1989, Impact Cratering, ch. 6).
        ejecta_blanket_exponent: alpha of the blanket falloff ``(r / (1 + h) R)^alpha``.
            Default -3, the ejecta-thickness decay of McGetchin et al. (1973).
        ejecta_max_rock_coefficient, ejecta_max_rock_exponent: the largest block a
            crater of diameter D throws is ``coef * D^exp`` (m); the largest block grows
            as ~D^(2/3) (Moore 1971, NASA SP-232; Bart & Melosh 2010, Icarus 209, 337).
            Defaults 0.25 and 2/3. ``coef = None`` disables the cap.
        ejecta_map_cell_m: cell size (m) of the :class:`EjectaMap`; ``None``: the larger of
            the pixel size and 1/512 of the longer site side.
    Rocks:
        rock_sfd_background: uniform background population (present day); ``None`` for
            none. Default Golombek-Rapp k = 0.005.
        rock_sfd_ejecta: rock SFD at stencil weight 1 (rim of a fresh full-yield crater);
            ``None`` for no ejecta rocks. Default Golombek-Rapp k = 0.1: 1.9 rocks >= 0.1 m
            per m^2 on the rim against 0.017 per m^2 in the background, and ~10^7 times
            denser at 0.5 m (the paper: the polar background is "several orders of
            magnitude sparser than ejecta"). Gives ~1-3 x 10^4 rocks >= 0.1 m on an
            8192 x 8192 site at 0.04 m.
        rock_d_min_m, rock_d_max_m: rock diameter range (m). Defaults 0.1 and 2.0.
        rock_burial_probability_per_step: chance that a rock is covered by regolith at
            each later time step. Default 0.3: with 100 steps over 3.5 Gyr a rock's median
            survival is ~70 Myr, the 40-80 Myr median lifetime of lunar boulders
            (Basilevsky et al. 2013, PSS 89, 118).
        n_time_steps: number of equal time steps over ``surface_age_yr``. Default 100.
        crater_burial: whether a new crater covers older rocks within its rim radius.
        compensate_background_burial: raise the background birth rate by the expected
            burial losses so survivors follow ``rock_sfd_background`` (module docstring).
        rock_height_ratio_min, rock_height_ratio_max: height/diameter ~ U(min, max).
            Defaults 0.3 and 0.7, around the ~0.5 of Golombek & Rapp (1997) and
            Golombek et al. (2003) (rock height about half the diameter).
        n_rock_shapes: size of the rock height-field library (shape_index range).
    """

    crater_sfd: CraterSFD = field(default_factory=CraterSFD)
    d_min_m: float = 0.5
    d_max_m: float | None = None
    existing_craters: tuple[tuple[float, float, float], ...] = ()
    surface_age_yr: float = 3.5e9
    degradation_kappa_m2_per_myr: float = 5.5
    degradation_reference_diameter_m: float = 1000.0
    degradation_kappa_exponent: float = 1.0
    erasure_kappa_t_over_d2: float = 0.2
    min_freshness: float = 0.05
    ejecta_min_diameter_m: float = 2.0
    ejecta_interior_density: float = 0.5
    ejecta_rim_density: float = 1.0
    ejecta_rim_half_width: float = 0.2
    ejecta_blanket_extent: float = 3.0
    ejecta_blanket_exponent: float = -3.0
    ejecta_yield_exponent: float = 2.0
    ejecta_max_rock_coefficient: float | None = 0.25
    ejecta_max_rock_exponent: float = 2.0 / 3.0
    ejecta_map_cell_m: float | None = None
    rock_sfd_background: RockSFD | CraterSFD | None = field(default_factory=RockSFD)
    rock_sfd_ejecta: RockSFD | CraterSFD | None = field(
        default_factory=lambda: RockSFD(law="golombek_rapp", k=0.1)
    )
    rock_d_min_m: float = 0.1
    rock_d_max_m: float = 2.0
    rock_burial_probability_per_step: float = 0.3
    n_time_steps: int = 100
    crater_burial: bool = True
    compensate_background_burial: bool = True
    rock_height_ratio_min: float = 0.3
    rock_height_ratio_max: float = 0.7
    n_rock_shapes: int = 16

    def __post_init__(self):
        if not isinstance(self.crater_sfd, CraterSFD):
            raise ConfigError(f"CatalogParams.crater_sfd = {self.crater_sfd!r} must be a CraterSFD")
        for name in ("rock_sfd_background", "rock_sfd_ejecta"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, (RockSFD, CraterSFD)):
                raise ConfigError(f"CatalogParams.{name} = {v!r} must be a RockSFD or None")
        _in("d_min_m", self.d_min_m, 0.0, lo_open=True, unit=" m")
        if self.d_max_m is not None:
            dmax = _real("d_max_m", self.d_max_m)
            if not dmax > self.d_min_m:
                raise OutOfRangeError(
                    f"CatalogParams.d_max_m = {self.d_max_m!r} m must exceed d_min_m = "
                    f"{self.d_min_m!r} m"
                )
        object.__setattr__(self, "existing_craters", _check_existing(self.existing_craters))
        _in("surface_age_yr", self.surface_age_yr, 0.0, 1.0e10, lo_open=True, unit=" yr")
        _in("degradation_kappa_m2_per_myr", self.degradation_kappa_m2_per_myr, 0.0, lo_open=True)
        _in(
            "degradation_reference_diameter_m",
            self.degradation_reference_diameter_m,
            0.0,
            lo_open=True,
        )
        _in("degradation_kappa_exponent", self.degradation_kappa_exponent, 0.0, 2.0)
        _in("erasure_kappa_t_over_d2", self.erasure_kappa_t_over_d2, 0.0, lo_open=True)
        _in("min_freshness", self.min_freshness, 0.0, 1.0, lo_open=True)
        _in("ejecta_min_diameter_m", self.ejecta_min_diameter_m, 0.0, lo_open=True, unit=" m")
        _in("ejecta_interior_density", self.ejecta_interior_density, 0.0)
        _in("ejecta_rim_density", self.ejecta_rim_density, 0.0)
        h = _in("ejecta_rim_half_width", self.ejecta_rim_half_width, 0.0, 1.0, hi_open=True)
        ext = _real("ejecta_blanket_extent", self.ejecta_blanket_extent)
        if not ext >= 1.0 + h:
            raise OutOfRangeError(
                f"CatalogParams.ejecta_blanket_extent = {self.ejecta_blanket_extent!r} crater "
                f"radii must be >= 1 + ejecta_rim_half_width = {1.0 + h:g}"
            )
        if ext > 100.0:
            raise OutOfRangeError(
                f"CatalogParams.ejecta_blanket_extent = {self.ejecta_blanket_extent!r}; "
                "allowed <= 100 crater radii"
            )
        _in("ejecta_blanket_exponent", self.ejecta_blanket_exponent, -10.0, 0.0)
        _in("ejecta_yield_exponent", self.ejecta_yield_exponent, 0.0, 10.0)
        if self.ejecta_max_rock_coefficient is not None:
            _in("ejecta_max_rock_coefficient", self.ejecta_max_rock_coefficient, 0.0, lo_open=True)
        _in("ejecta_max_rock_exponent", self.ejecta_max_rock_exponent, 0.0, 2.0, lo_open=True)
        if self.ejecta_map_cell_m is not None:
            _in("ejecta_map_cell_m", self.ejecta_map_cell_m, 0.0, lo_open=True, unit=" m")
        _in("rock_d_min_m", self.rock_d_min_m, 0.0, lo_open=True, unit=" m")
        if not _real("rock_d_max_m", self.rock_d_max_m) > self.rock_d_min_m:
            raise OutOfRangeError(
                f"CatalogParams.rock_d_max_m = {self.rock_d_max_m!r} m must exceed "
                f"rock_d_min_m = {self.rock_d_min_m!r} m"
            )
        _in("rock_burial_probability_per_step", self.rock_burial_probability_per_step, 0.0, 1.0)
        _int_in("n_time_steps", self.n_time_steps, 1, 1_000_000)
        for name in ("crater_burial", "compensate_background_burial"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"CatalogParams.{name} = {getattr(self, name)!r} must be bool")
        lo = _in("rock_height_ratio_min", self.rock_height_ratio_min, 0.0, 2.0, lo_open=True)
        hi = _in("rock_height_ratio_max", self.rock_height_ratio_max, 0.0, 2.0, lo_open=True)
        if hi < lo:
            raise OutOfRangeError(
                f"CatalogParams.rock_height_ratio_max = {self.rock_height_ratio_max!r} must be "
                f">= rock_height_ratio_min = {self.rock_height_ratio_min!r}"
            )
        _int_in("n_rock_shapes", self.n_rock_shapes, 1, 32767)

    # -- derived quantities

    def crater_d_max_for(self, grid: GridSpec) -> float:
        """The crater diameter upper bound (m) used for ``grid`` (resolves ``None``)."""
        if self.d_max_m is not None:
            return float(self.d_max_m)
        cap = 0.5 * min(grid.width_m, grid.height_m)
        d1 = largest_expected_diameter(self.crater_sfd, area_m2=grid.area_m2)
        d = min(d1, cap)
        if d <= self.d_min_m:
            d = cap
        if d <= self.d_min_m:
            raise OutOfRangeError(
                f"CatalogParams.d_min_m = {self.d_min_m!r} m is at least half the site side "
                f"({cap:g} m); lower it or give d_max_m"
            )
        return float(d)

    def crater_lifetime_yr(self, diameter_m) -> np.ndarray:
        """Time (yr) for diffusive degradation to erase a crater of diameter D (m)."""
        d = np.asarray(diameter_m, dtype=np.float64)
        kappa = (
            self.degradation_kappa_m2_per_myr
            * 1e-6
            * (d / self.degradation_reference_diameter_m) ** self.degradation_kappa_exponent
        )
        return self.erasure_kappa_t_over_d2 * d * d / kappa

    def freshness(self, age_yr, diameter_m) -> np.ndarray:
        """Freshness in ``[min_freshness, 1]`` falling linearly with age / lifetime."""
        frac = np.clip(np.asarray(age_yr) / self.crater_lifetime_yr(diameter_m), 0.0, 1.0)
        return 1.0 - (1.0 - self.min_freshness) * frac

    def ejecta_yield(self, crater_diameter_m) -> np.ndarray:
        """Rock yield in [0, 1] of an ejecta crater: ``(1 - D_min / D)^yield_exponent``."""
        d = np.asarray(crater_diameter_m, dtype=np.float64)
        frac = np.clip(1.0 - self.ejecta_min_diameter_m / d, 0.0, 1.0)
        return frac**self.ejecta_yield_exponent

    def max_ejecta_rock_m(self, crater_diameter_m) -> np.ndarray:
        """Largest ejecta rock (m) a crater of diameter D (m) throws (<= rock_d_max_m)."""
        d = np.asarray(crater_diameter_m, dtype=np.float64)
        if self.ejecta_max_rock_coefficient is None:
            return np.full(d.shape, float(self.rock_d_max_m))
        cap = self.ejecta_max_rock_coefficient * d**self.ejecta_max_rock_exponent
        return np.minimum(cap, self.rock_d_max_m)


def _check_existing(existing) -> tuple[tuple[float, float, float], ...]:
    out = []
    for i, e in enumerate(existing):
        try:
            x, y, d = (float(v) for v in e)
        except (TypeError, ValueError) as err:
            raise ConfigError(
                f"CatalogParams.existing_craters[{i}] = {e!r} must be (x_m, y_m, diameter_m)"
            ) from err
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(d) and d > 0):
            raise OutOfRangeError(
                f"CatalogParams.existing_craters[{i}] = {e!r}: coordinates must be finite "
                "and the diameter > 0 m"
            )
        out.append((x, y, d))
    return tuple(out)


# --------------------------------------------------------------------------- ejecta stencil


@dataclass(frozen=True)
class _Stencil:
    """Radial ejecta weight in crater radii, with its integral and region masses."""

    interior: float
    rim: float
    h: float
    extent: float
    alpha: float

    @property
    def masses(self) -> np.ndarray:
        """Integral of the weight over the interior, rim and blanket (units R^2)."""
        a, b, e = 1.0 - self.h, 1.0 + self.h, self.extent
        m_int = self.interior * math.pi * a * a
        m_rim = self.rim * math.pi * (b * b - a * a)
        beta = self.alpha + 2.0
        if e <= b:
            m_bl = 0.0
        elif abs(beta) < 1e-12:
            m_bl = self.rim * 2.0 * math.pi * b * b * math.log(e / b)
        else:
            m_bl = self.rim * 2.0 * math.pi * b ** (-self.alpha) * (e**beta - b**beta) / beta
        return np.array([m_int, m_rim, m_bl])

    def weight(self, rho: np.ndarray) -> np.ndarray:
        a, b = 1.0 - self.h, 1.0 + self.h
        with np.errstate(divide="ignore", over="ignore"):
            blanket = self.rim * (np.maximum(rho, b) / b) ** self.alpha
        return np.where(
            rho < a,
            self.interior,
            np.where(rho <= b, self.rim, np.where(rho <= self.extent, blanket, 0.0)),
        )

    def sample_radius(self, g: np.random.Generator, n: int) -> np.ndarray:
        """``n`` radii (crater radii) with density proportional to ``w(rho) rho``."""
        m = self.masses
        region = np.searchsorted(np.cumsum(m) / m.sum(), g.random(n), side="right")
        region = np.minimum(region, 2)
        u = g.random(n)
        a, b, e = 1.0 - self.h, 1.0 + self.h, self.extent
        r_int = a * np.sqrt(u)
        r_rim = np.sqrt(a * a + u * (b * b - a * a))
        beta = self.alpha + 2.0
        if abs(beta) < 1e-12:
            r_bl = b * (e / b) ** u
        else:
            with np.errstate(invalid="ignore"):
                r_bl = (b**beta + u * (e**beta - b**beta)) ** (1.0 / beta)
        return np.choose(region, (r_int, r_rim, r_bl))


def ejecta_weight(rho, *, params: CatalogParams) -> np.ndarray:
    """Ejecta stencil weight at ``rho = r / R`` (crater radii) for a fresh crater."""
    return _stencil(params).weight(np.asarray(rho, dtype=np.float64))


def _stencil(p: CatalogParams) -> _Stencil:
    return _Stencil(
        interior=float(p.ejecta_interior_density),
        rim=float(p.ejecta_rim_density),
        h=float(p.ejecta_rim_half_width),
        extent=float(p.ejecta_blanket_extent),
        alpha=float(p.ejecta_blanket_exponent),
    )


def _ejecta_map(grid: GridSpec, p: CatalogParams, st: _Stencil, cx, cy, d, f) -> EjectaMap:
    """Cell-averaged sum of ``f w(r / R)`` over the ejecta craters (catalog order)."""
    cell = p.ejecta_map_cell_m
    if cell is None:
        cell = max(grid.resolution_m, max(grid.width_m, grid.height_m) / 512.0)
    cell = float(cell)
    nc = max(1, math.ceil(grid.width_m / cell - 1e-9))
    nr = max(1, math.ceil(grid.height_m / cell - 1e-9))
    acc = np.zeros((nr, nc), dtype=np.float64)
    x0, y1 = grid.x_min, grid.y_max
    for xc, yc, dc, fc in zip(cx.tolist(), cy.tolist(), d.tolist(), f.tolist(), strict=True):
        radius = 0.5 * dc
        reach = st.extent * radius
        c0 = max(0, math.floor((xc - reach - x0) / cell))
        c1 = min(nc, math.floor((xc + reach - x0) / cell) + 1)
        r0 = max(0, math.floor((y1 - (yc + reach)) / cell))
        r1 = min(nr, math.floor((y1 - (yc - reach)) / cell) + 1)
        if c0 >= c1 or r0 >= r1:
            continue
        s = min(8, max(1, math.ceil(2.0 * cell / radius)))  # sub-samples per cell side
        off = ((np.arange(s) + 0.5) / s) * cell
        xs = (x0 + np.arange(c0, c1)[:, None] * cell + off[None, :]).ravel() - xc
        ncols = c1 - c0
        rows_per_block = max(1, _MAP_BLOCK_ELEMENTS // (s * s * ncols))
        for ra in range(r0, r1, rows_per_block):
            rb = min(r1, ra + rows_per_block)
            ys = (y1 - np.arange(ra, rb)[:, None] * cell - off[None, :]).ravel() - yc
            rho = np.sqrt(ys[:, None] ** 2 + xs[None, :] ** 2) / radius
            w = st.weight(rho).reshape(rb - ra, s, ncols, s).mean(axis=(1, 3))
            acc[ra:rb, c0:c1] += fc * w
    return EjectaMap(values=acc.astype(np.float32), cell_m=cell, x_min=x0, y_max=y1)


# --------------------------------------------------------------------------- synthesis


def _report(progress, stage: str, fraction: float) -> None:
    if progress is not None:
        progress(stage, fraction)


def _birth_steps(ages: np.ndarray, surface_age: float, n_steps: int) -> np.ndarray:
    """Time step (0 = oldest) in which something of the given age formed."""
    dt = surface_age / n_steps
    return np.clip(np.floor((surface_age - ages) / dt), 0, n_steps - 1).astype(np.int64)


def _crater_cover_log(ages: np.ndarray, diam: np.ndarray, area: float):
    """Crater ages sorted ascending and ``sum log(1 - pi R^2 / A)`` over younger craters."""
    order = np.argsort(ages, kind="stable")
    frac = np.minimum(np.pi * 0.25 * diam[order] ** 2 / area, 0.999)
    cum = np.concatenate(([0.0], np.cumsum(np.log1p(-frac))))
    return ages[order], cum


def _mean_background_survival(p: CatalogParams, crater_age, crater_d, area) -> float:
    """Expected fraction of background rocks born uniformly in time that survive burial."""
    t_end = p.surface_age_yr
    n = p.n_time_steps
    q = 1.0 - p.rock_burial_probability_per_step
    edges = np.linspace(0.0, t_end, n + 1)
    if p.crater_burial and len(crater_age):
        sorted_age, cum = _crater_cover_log(crater_age, crater_d, area)
        brk = np.unique(np.concatenate((edges, np.clip(sorted_age, 0.0, t_end))))
    else:
        sorted_age, cum = np.zeros(0), np.zeros(1)
        brk = edges
    mid = 0.5 * (brk[1:] + brk[:-1])
    width = np.diff(brk)
    steps = _birth_steps(mid, t_end, n)
    stoch = q ** (n - 1 - steps).astype(np.float64)
    cover = np.exp(cum[np.searchsorted(sorted_age, mid, side="left")])
    return float(np.sum(width * stoch * cover) / t_end)


def _step_survival(p: CatalogParams) -> np.ndarray:
    """Chance that a rock born in step k escapes regolith burial to the present."""
    n = p.n_time_steps
    k = np.arange(n)
    q = 1.0 - p.rock_burial_probability_per_step
    if q <= 0.0:
        return (k == n - 1).astype(np.float64)
    return q ** (n - 1 - k).astype(np.float64)


def _uniform_xy(g: np.random.Generator, grid: GridSpec, n: int) -> tuple[np.ndarray, np.ndarray]:
    u = g.random((n, 2))
    x = grid.x_min + u[:, 0] * grid.width_m
    y = grid.y_max - u[:, 1] * grid.height_m
    return x, y


def _attributes(g: np.random.Generator, p: CatalogParams, n: int):
    ratio = g.uniform(p.rock_height_ratio_min, p.rock_height_ratio_max, n)
    shape = g.integers(0, p.n_rock_shapes, n)
    return ratio, shape


def _background_rocks(grid, seed, p: CatalogParams, survival, crater_age, crater_d):
    """Background rocks that escape regolith burial: (x, y, d, age, ratio, shape)."""
    sfd = p.rock_sfd_background
    empty = (np.zeros(0),) * 4 + (np.zeros(0), np.zeros(0, dtype=np.int64))
    if sfd is None:
        return empty
    g = rng_mod.generator(seed, "catalog/rocks/background")
    mean_stoch = float(np.mean(survival))
    if p.compensate_background_burial:
        fbar = _mean_background_survival(p, crater_age, crater_d, grid.area_m2)
        factor = mean_stoch / fbar if fbar > 0 else 0.0
    else:
        factor = mean_stoch
    d = sample_diameters(
        g, sfd=sfd, area_m2=grid.area_m2 * factor, d_min_m=p.rock_d_min_m, d_max_m=p.rock_d_max_m
    )
    n = len(d)
    cdf = np.cumsum(survival) / np.sum(survival)
    step = np.minimum(np.searchsorted(cdf, g.random(n), side="right"), p.n_time_steps - 1)
    dt = p.surface_age_yr / p.n_time_steps
    age = p.surface_age_yr - (step + g.random(n)) * dt
    x, y = _uniform_xy(g, grid, n)
    ratio, shape = _attributes(g, p, n)
    return x, y, d, age, ratio, shape


def _ejecta_rocks(grid, seed, p: CatalogParams, st: _Stencil, survival, cr):
    """Ejecta rocks that escape regolith burial: (x, y, d, age, ratio, shape)."""
    sfd = p.rock_sfd_ejecta
    sel = np.flatnonzero(cr.ejecta)
    if sfd is None or sel.size == 0:
        return (np.zeros(0),) * 4 + (np.zeros(0), np.zeros(0, dtype=np.int64))
    g = rng_mod.generator(seed, "catalog/rocks/ejecta")
    dc = cr.diameter_m[sel]
    radius = 0.5 * dc
    cap = p.max_ejecta_rock_m(dc)
    n_lo = float(sfd.cumulative_density(p.rock_d_min_m))
    n_cap = np.where(cap > p.rock_d_min_m, sfd.cumulative_density(cap), n_lo)
    steps = _birth_steps(cr.age_yr[sel], p.surface_age_yr, p.n_time_steps)
    weight = cr.freshness[sel] * p.ejecta_yield(dc)
    mu = (n_lo - n_cap) * weight * st.masses.sum() * radius**2 * survival[steps]
    counts = g.poisson(np.maximum(mu, 0.0))
    owner = np.repeat(np.arange(sel.size), counts)
    n = owner.size
    if n == 0:
        return (np.zeros(0),) * 4 + (np.zeros(0), np.zeros(0, dtype=np.int64))
    u = g.random(n)
    d = sfd.inverse_cumulative(
        n_cap[owner] + u * (n_lo - n_cap[owner]), d_min_m=p.rock_d_min_m, d_max_m=cap[owner]
    )
    rho = st.sample_radius(g, n)
    theta = g.random(n) * (2.0 * np.pi)
    x = cr.x_m[sel][owner] + rho * radius[owner] * np.cos(theta)
    y = cr.y_m[sel][owner] + rho * radius[owner] * np.sin(theta)
    ratio, shape = _attributes(g, p, n)
    age = cr.age_yr[sel][owner]
    x_max, y_min = grid.x_min + grid.width_m, grid.y_max - grid.height_m
    keep = (x >= grid.x_min) & (x < x_max) & (y > y_min) & (y <= grid.y_max)
    return x[keep], y[keep], d[keep], age[keep], ratio[keep], shape[keep]


def _crater_buried(x, y, age, cr: CraterCatalog) -> np.ndarray:
    """Rocks covered by a younger crater (centre within its rim radius)."""
    buried = np.zeros(x.shape, dtype=bool)
    if x.size == 0 or len(cr) == 0:
        return buried
    tree = cKDTree(np.column_stack((x, y)))
    hits = tree.query_ball_point(
        np.column_stack((cr.x_m, cr.y_m)), r=0.5 * cr.diameter_m, return_sorted=False
    )
    lengths = np.fromiter((len(h) for h in hits), dtype=np.intp, count=len(hits))
    total = int(lengths.sum())
    if total == 0:
        return buried
    rock = np.fromiter((i for h in hits for i in h), dtype=np.intp, count=total)
    crater = np.repeat(np.arange(len(cr)), lengths)
    older = age[rock] > cr.age_yr[crater]
    buried[rock[older]] = True
    return buried


def synthesize_catalogs(
    *,
    grid: GridSpec,
    seed: int,
    params: CatalogParams,
    progress: Callable[[str, float], None] | None = None,
) -> tuple[CraterCatalog, RockCatalog, EjectaMap]:
    """Draws a site's craters, rocks and ejecta map (see the module docstring).

    Args:
        grid: the site grid (extent in site coordinates, m).
        seed: scenario seed; streams ``catalog/craters/...`` and ``catalog/rocks/...``.
        params: catalog parameters.
        progress: optional ``progress(stage, fraction)`` callback.

    Returns:
        craters (oldest first), rocks (birth order, oldest first), ejecta map.
    """
    if not isinstance(params, CatalogParams):
        raise ConfigError(f"params = {params!r} must be a CatalogParams")
    if not isinstance(grid, GridSpec):
        raise ConfigError(f"grid = {grid!r} must be a GridSpec")
    p = params
    _report(progress, "craters", 0.0)

    # 1-3. craters: sizes, ages, places.
    d_max = p.crater_d_max_for(grid)
    x_max, y_min = grid.x_min + grid.width_m, grid.y_max - grid.height_m
    existing = [
        d
        for (x, y, d) in p.existing_craters
        if grid.x_min <= x <= x_max and y_min <= y <= grid.y_max
    ]
    diam = sample_diameters(
        rng_mod.generator(seed, "catalog/craters/diameter"),
        sfd=p.crater_sfd,
        area_m2=grid.area_m2,
        d_min_m=p.d_min_m,
        d_max_m=d_max,
        existing_diameters_m=existing,
    )
    n_c = diam.size
    x, y = _uniform_xy(rng_mod.generator(seed, "catalog/craters/place"), grid, n_c)
    life = p.crater_lifetime_yr(diam)
    u = rng_mod.generator(seed, "catalog/craters/age").random(n_c)
    age = u * np.minimum(p.surface_age_yr, life)
    fresh = p.freshness(age, diam)
    order = np.argsort(-age, kind="stable")
    craters = CraterCatalog(
        x_m=x[order],
        y_m=y[order],
        diameter_m=diam[order],
        age_yr=age[order],
        freshness=fresh[order],
        ejecta=diam[order] >= p.ejecta_min_diameter_m,
    )

    # 4. ejecta map.
    _report(progress, "ejecta map", 0.25)
    st = _stencil(p)
    ej = craters.ejecta
    emap = _ejecta_map(
        grid,
        p,
        st,
        craters.x_m[ej],
        craters.y_m[ej],
        craters.diameter_m[ej],
        craters.freshness[ej] * p.ejecta_yield(craters.diameter_m[ej]),
    )

    # 5. rocks.
    _report(progress, "rocks", 0.5)
    survival = _step_survival(p)
    bg = _background_rocks(grid, seed, p, survival, craters.age_yr, craters.diameter_m)
    ejr = _ejecta_rocks(grid, seed, p, st, survival, craters)
    rx, ry, rd, rage, ratio, shape = (np.concatenate((a, b)) for a, b in zip(bg, ejr, strict=True))
    pop = np.concatenate(
        (
            np.full(bg[0].size, POPULATION_BACKGROUND, dtype=np.uint8),
            np.full(ejr[0].size, POPULATION_EJECTA, dtype=np.uint8),
        )
    )
    _report(progress, "burial", 0.75)
    alive = ~_crater_buried(rx, ry, rage, craters) if p.crater_burial else np.ones(rx.size, bool)
    idx = np.flatnonzero(alive)
    idx = idx[np.argsort(-rage[idx], kind="stable")]
    rocks = RockCatalog(
        x_m=rx[idx],
        y_m=ry[idx],
        diameter_m=rd[idx],
        height_m=rd[idx] * ratio[idx],
        population=pop[idx],
        shape_index=shape[idx],
        age_yr=rage[idx],
    )
    _report(progress, "done", 1.0)
    return craters, rocks, emap
