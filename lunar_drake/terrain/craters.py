"""Crater shapes and their insertion into terrain tiles (paper section 4, paragraph 4).

"Craters are placed by fitting a plane to a patch of terrain, inserting the crater bowl
profile into the plane, and blending the ejecta blanket into the surrounding terrain.
The crater profile is defined by four connected polynomials for which a 'freshness'
parameter controls crater degradation."

Definitions (all heights relative to the crater's fitted pre-impact plane)
-------------------------------------------------------------------------
* ``D`` is the rim-crest diameter (m), ``R = D / 2``, ``s = r / R`` the normalised radius.
* ``d`` is the depth from rim crest to floor, as in Pike (1977); ``h`` is the rim-crest
  height above the plane. So the floor (``r = 0``) lies at ``h - d`` (below the plane
  because ``h < d``) and the rim crest (``r = R``) at ``+h``, the profile's maximum.
* ``d / D`` and ``h / D`` fall linearly from their fresh values (``freshness = 1``) to
  their degraded values (``freshness = 0``): :func:`depth_ratio`, :func:`rim_height_ratio`.

The four polynomial pieces of :func:`crater_profile` (``b`` = bowl fraction, ``c`` =
``rim_flank_radii``, ``e`` = ``ejecta_extent_radii``):

1. bowl floor, ``0 <= s < b``: parabola ``h - d + A s^2`` with ``A = 3 d / (1 + 2 b)``
   (this ``A`` makes the join with piece 2 C2-continuous);
2. inner wall, ``b <= s < 1``: cubic Hermite up to the rim crest, slope 0 at ``s = 1``;
3. outer rim flank, ``1 <= s < c``: cubic Hermite from the crest down to the value and
   slope of the ejecta thickness law ``h s^-3`` (McGetchin et al. 1973) at ``s = c``;
4. ejecta blanket, ``c <= s < e``: cubic Hermite decaying to 0 with slope 0 at ``s = e``.

The profile is C1 everywhere (slope 0 at the centre, the crest and the extent), monotone
on each side of the crest, and exactly 0 for ``s >= e``. A larger bowl fraction pushes
the steep part of the wall towards the rim (a fresh paraboloid-like bowl, upper walls
near 28 deg at d/D = 0.15); a small one gives the sigmoid, cosine-like section of a
diffusively degraded crater.

Insertion (:func:`stamp_craters`): with ``P(x, y)`` the crater's fitted plane,
``dz(r)`` its profile and ``w(r)`` an obliteration weight (1 for ``r <= R``, a cubic
smoothstep down to 0 at ``blend_outer_radii * R``, 0 beyond)::

    z_new = z_old + dz(r) + w(r) * (P - z_old)

Inside the rim (``w = 1``) the old terrain is replaced by ``P + dz`` (older features are
excavated); far out (``w = 0``) the ejecta blanket is deposited on top of the old
terrain (``z_old + dz``); in between, older relief is progressively mantled by the thick
proximal ejecta. Beyond the extent ``dz = w = 0`` and pixels are left unchanged. Every
operation is elementwise on the pixel (+, -, *, sqrt, comparisons, table look-ups), so a
pixel's result does not depend on the tile that contains it. Stamping evaluates the
profile with float32 coefficients (agreeing with :func:`crater_profile` to ~1e-7 D).

Cost: about 10 ns per pixel of each crater's bounding box plus a few tens of
microseconds per crater (small craters are batched); the ~34k craters of an 8192^2,
0.04 m site stamp in roughly 4-6 s of CPU in 1024^2 tiles.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lunar_drake.errors import ConfigError, OutOfRangeError

__all__ = [
    "CraterShapeParams",
    "crater_extent_m",
    "crater_planes",
    "crater_profile",
    "depth_ratio",
    "rim_height_ratio",
    "stamp_craters",
]

# Plane-fit sampling pattern: the centre plus rings at e*k/_FIT_RINGS crater radii
# (k = 1.._FIT_RINGS), each with _FIT_AZIMUTHS equally spaced points.
_FIT_RINGS = 5
_FIT_AZIMUTHS = 12
# Pixels per vectorised block (large craters go in row blocks; keeps arrays in cache).
_CHUNK_PX = 1 << 15
# Window granularity (px) and the largest window side stamped in 3-D batches.
_BLOCK = 8
_BATCH_MAX_SIDE = 64


@dataclass(frozen=True)
class CraterShapeParams:
    """Shape of a simple crater as a function of freshness (ratios are to the diameter D).

    Attributes:
        depth_ratio_fresh: rim-crest-to-floor depth d/D at freshness 1. Default 0.15:
            Stopar et al. (2017, Icarus 298) find d/D ~ 0.11-0.17 for small fresh lunar
            craters; Pike (1977) d/D ~ 0.2 for fresh simple craters (0.196 D^1.01).
        depth_ratio_degraded: d/D at freshness 0. Default 0.03: the most degraded small
            craters are shallow depressions with d/D of a few hundredths (cf. the
            morphologic classes of Basilevsky 1976, Proc. Lunar Sci. Conf. 7).
        rim_height_ratio_fresh: rim-crest height above the pre-impact plane h/D at
            freshness 1. Default 0.036 (Pike 1977, in Impact and Explosion Cratering:
            h = 0.036 D^1.014 for fresh simple lunar craters).
        rim_height_ratio_degraded: h/D at freshness 0. Default 0.004: diffusive
            degradation removes the short-wavelength rim faster than it fills the bowl
            (Fassett & Thomson 2014, JGR Planets 119), leaving a barely raised rim.
        bowl_fraction_fresh, bowl_fraction_degraded: outer radius of the parabolic bowl
            piece (in R) at freshness 1 and 0; the inner-wall cubic spans the rest up to
            the rim. Defaults 0.7 (paraboloid-like fresh bowl) and 0.3 (rounded,
            degraded section). Must lie in [0, 1).
        rim_flank_radii: outer edge of the rim-flank piece (in R). Default 1.25.
        ejecta_extent_radii: where the ejecta blanket reaches zero (in R). Default 2.5:
            the continuous ejecta blanket reaches roughly 1-1.5 radii beyond the rim
            (Melosh 1989, Impact Cratering, ch. 6), its thickness falling as (r/R)^-3
            (McGetchin, Settle & Head 1973, EPSL 20). Must lie in (rim_flank_radii,
            2 * rim_flank_radii] so the last cubic stays monotone and non-negative.
        blend_outer_radii: radius (in R) where the obliteration weight reaches 0; the
            weight is 1 inside the rim. Default 2.0: there the (r/R)^-3 ejecta is only
            h/8 thick and older relief survives. Must lie in (1, ejecta_extent_radii].
    """

    depth_ratio_fresh: float = 0.15
    depth_ratio_degraded: float = 0.03
    rim_height_ratio_fresh: float = 0.036
    rim_height_ratio_degraded: float = 0.004
    bowl_fraction_fresh: float = 0.7
    bowl_fraction_degraded: float = 0.3
    rim_flank_radii: float = 1.25
    ejecta_extent_radii: float = 2.5
    blend_outer_radii: float = 2.0

    def __post_init__(self) -> None:
        for name in (
            "depth_ratio_fresh",
            "depth_ratio_degraded",
            "rim_height_ratio_fresh",
            "rim_height_ratio_degraded",
            "bowl_fraction_fresh",
            "bowl_fraction_degraded",
            "rim_flank_radii",
            "ejecta_extent_radii",
            "blend_outer_radii",
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"{name} = {value!r} must be a real number")
            if not math.isfinite(value):
                raise OutOfRangeError(f"{name} = {value!r} must be finite")
        if not 0.0 < self.depth_ratio_fresh <= 0.5:
            raise OutOfRangeError(
                f"depth_ratio_fresh = {self.depth_ratio_fresh!r} must lie in (0, 0.5]"
            )
        if not 0.0 < self.depth_ratio_degraded <= self.depth_ratio_fresh:
            raise OutOfRangeError(
                f"depth_ratio_degraded = {self.depth_ratio_degraded!r} must lie in "
                f"(0, depth_ratio_fresh = {self.depth_ratio_fresh!r}]"
            )
        if not 0.0 <= self.rim_height_ratio_fresh < self.depth_ratio_fresh:
            raise OutOfRangeError(
                f"rim_height_ratio_fresh = {self.rim_height_ratio_fresh!r} must lie in "
                f"[0, depth_ratio_fresh = {self.depth_ratio_fresh!r}) so the floor lies "
                "below the pre-impact plane"
            )
        if not 0.0 <= self.rim_height_ratio_degraded <= self.rim_height_ratio_fresh:
            raise OutOfRangeError(
                f"rim_height_ratio_degraded = {self.rim_height_ratio_degraded!r} must lie "
                f"in [0, rim_height_ratio_fresh = {self.rim_height_ratio_fresh!r}]"
            )
        if not self.rim_height_ratio_degraded < self.depth_ratio_degraded:
            raise OutOfRangeError(
                f"rim_height_ratio_degraded = {self.rim_height_ratio_degraded!r} must be "
                f"< depth_ratio_degraded = {self.depth_ratio_degraded!r}"
            )
        for name in ("bowl_fraction_fresh", "bowl_fraction_degraded"):
            value = getattr(self, name)
            if not 0.0 <= value < 1.0:
                raise OutOfRangeError(f"{name} = {value!r} must lie in [0, 1)")
        if not 1.0 < self.rim_flank_radii <= 4.0:
            raise OutOfRangeError(
                f"rim_flank_radii = {self.rim_flank_radii!r} must lie in (1, 4] crater radii"
            )
        if not self.rim_flank_radii < self.ejecta_extent_radii <= 2.0 * self.rim_flank_radii:
            raise OutOfRangeError(
                f"ejecta_extent_radii = {self.ejecta_extent_radii!r} must lie in "
                f"(rim_flank_radii, 2 * rim_flank_radii] = ({self.rim_flank_radii!r}, "
                f"{2.0 * self.rim_flank_radii!r}]"
            )
        if not 1.0 < self.blend_outer_radii <= self.ejecta_extent_radii:
            raise OutOfRangeError(
                f"blend_outer_radii = {self.blend_outer_radii!r} must lie in "
                f"(1, ejecta_extent_radii = {self.ejecta_extent_radii!r}]"
            )


# --------------------------------------------------------------------------- validation


def _check_array(name: str, value, *, low: float, high: float, low_open: bool) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    bad = ~np.isfinite(a) | (a > high) | ((a <= low) if low_open else (a < low))
    if np.any(bad):
        idx = np.unravel_index(int(np.argmax(bad)), a.shape) if a.ndim else ()
        where = f"{name}[{', '.join(str(int(i)) for i in idx)}]" if a.ndim else name
        lo = "(" if low_open else "["
        hi = "inf)" if math.isinf(high) else f"{high:g}]"
        raise OutOfRangeError(f"{where} = {a[idx]!r} must be finite and lie in {lo}{low:g}, {hi}")
    return a


def _check_freshness(freshness) -> np.ndarray:
    return _check_array("freshness", freshness, low=0.0, high=1.0, low_open=False)


def _check_diameter(diameter_m) -> np.ndarray:
    return _check_array("diameter_m", diameter_m, low=0.0, high=math.inf, low_open=True)


def _lerp(freshness: np.ndarray, degraded: float, fresh: float):
    out = degraded + (fresh - degraded) * freshness
    return float(out) if out.ndim == 0 else out


# ------------------------------------------------------------------------------- shape


def depth_ratio(freshness, *, params: CraterShapeParams):
    """Rim-crest-to-floor depth over diameter, d/D, at ``freshness`` in [0, 1].

    Linear from ``params.depth_ratio_degraded`` (0) to ``params.depth_ratio_fresh`` (1);
    a float for a scalar input, else an array of the input's shape.
    """
    f = _check_freshness(freshness)
    return _lerp(f, params.depth_ratio_degraded, params.depth_ratio_fresh)


def rim_height_ratio(freshness, *, params: CraterShapeParams):
    """Rim-crest height above the pre-impact plane over diameter, h/D, at ``freshness``.

    Linear from ``params.rim_height_ratio_degraded`` (0) to ``rim_height_ratio_fresh`` (1).
    """
    f = _check_freshness(freshness)
    return _lerp(f, params.rim_height_ratio_degraded, params.rim_height_ratio_fresh)


def crater_extent_m(diameter_m, *, params: CraterShapeParams):
    """Radius (m) beyond which a crater's profile (and its obliteration weight) is 0."""
    d = _check_diameter(diameter_m)
    out = 0.5 * params.ejecta_extent_radii * d
    return float(out) if out.ndim == 0 else out


def _hermite_monomial(s0, s1, p0, m0, p1, m1) -> np.ndarray:
    """Coefficients (..., 4) of the cubic in s (ascending powers) with the given end
    values p and slopes m (per unit s) at s0 and s1."""
    length = s1 - s0
    slope = (p1 - p0) / length
    alpha = (3.0 * slope - 2.0 * m0 - m1) / length
    beta = (m0 + m1 - 2.0 * slope) / (length * length)
    c0 = p0 - m0 * s0 + alpha * s0 * s0 - beta * s0 * s0 * s0
    c1 = m0 - 2.0 * alpha * s0 + 3.0 * beta * s0 * s0
    c2 = alpha - 3.0 * beta * s0
    return np.stack(np.broadcast_arrays(c0, c1, c2, beta), axis=-1)


def _profile_pieces(diameter: np.ndarray, freshness: np.ndarray, params: CraterShapeParams):
    """Piecewise-cubic crater profile in ``s = r / R`` for 1-D arrays of craters.

    Returns ``(bowl, coef)``: ``bowl`` (n,) is the bowl/wall break ``b`` (the other
    breaks, 1, c and e, are common to all craters) and ``coef`` (n, 5, 4) holds, for the
    pieces [0, b), [b, 1), [1, c), [c, e), [e, inf), the ascending-power coefficients in
    ``s`` of the height (m) relative to the fitted plane.
    """
    dd = _lerp(freshness, params.depth_ratio_degraded, params.depth_ratio_fresh)
    hh = _lerp(freshness, params.rim_height_ratio_degraded, params.rim_height_ratio_fresh)
    b = _lerp(freshness, params.bowl_fraction_degraded, params.bowl_fraction_fresh)
    c = params.rim_flank_radii
    e = params.ejecta_extent_radii
    zero = np.zeros_like(dd)
    floor = hh - dd
    curv = 3.0 * dd / (1.0 + 2.0 * b)
    v_c = hh * c**-3.0
    m_c = -3.0 * hh * c**-4.0
    coef = np.empty((dd.shape[0], 5, 4))
    coef[:, 0] = np.stack([floor, zero, curv, zero], axis=-1)
    coef[:, 1] = _hermite_monomial(b, 1.0, floor + curv * b * b, 2.0 * curv * b, hh, zero)
    coef[:, 2] = _hermite_monomial(1.0, c, hh, zero, v_c, m_c)
    coef[:, 3] = _hermite_monomial(c, e, v_c, m_c, zero, zero)
    coef[:, 4] = 0.0
    coef *= diameter[:, None, None]
    return b, coef


def crater_profile(r_m, *, diameter_m, freshness, params: CraterShapeParams) -> np.ndarray:
    """Height (m) of a crater relative to its pre-impact plane at radial distance ``r_m``.

    ``r_m`` (m) may be signed (a section through the centre); ``|r_m|`` is used.
    ``r_m``, ``diameter_m`` and ``freshness`` broadcast together. The floor (r = 0) is at
    ``h - d``, the rim crest (r = D/2) at ``+h``, and the height is exactly 0 at and
    beyond :func:`crater_extent_m`. Returns float64 of the broadcast shape.
    """
    r = np.asarray(r_m, dtype=np.float64)
    if not np.all(np.isfinite(r)):
        raise OutOfRangeError("r_m must be finite")
    d = _check_diameter(diameter_m)
    f = _check_freshness(freshness)
    r, d, f = np.broadcast_arrays(r, d, f)
    shape = r.shape
    r, d, f = r.ravel(), d.ravel(), f.ravel()
    bowl, coef = _profile_pieces(d, f, params)
    s = np.abs(r) / (0.5 * d)
    k = (
        (s >= bowl).astype(np.intp)
        + (s >= 1.0)
        + (s >= params.rim_flank_radii)
        + (s >= params.ejecta_extent_radii)
    )
    cf = coef[np.arange(s.size), k]
    out = ((cf[:, 3] * s + cf[:, 2]) * s + cf[:, 1]) * s + cf[:, 0]
    return out.reshape(shape)


# --------------------------------------------------------------------------- plane fit


def _fit_pattern(params: CraterShapeParams) -> tuple[np.ndarray, np.ndarray]:
    """Sample offsets (u, v) in crater radii: the centre plus the fit rings."""
    rho = params.ejecta_extent_radii * np.arange(1, _FIT_RINGS + 1) / _FIT_RINGS
    theta = 2.0 * np.pi * np.arange(_FIT_AZIMUTHS) / _FIT_AZIMUTHS
    u = np.concatenate([[0.0], (rho[:, None] * np.cos(theta)[None, :]).ravel()])
    v = np.concatenate([[0.0], (rho[:, None] * np.sin(theta)[None, :]).ravel()])
    return u, v


def crater_planes(
    low_surface_at: Callable[[np.ndarray, np.ndarray], np.ndarray],
    *,
    x_m,
    y_m,
    diameter_m,
    params: CraterShapeParams,
) -> np.ndarray:
    """Least-squares pre-impact planes for craters centred at ``(x_m, y_m)`` (m, site frame).

    Each plane is ``z = a + b (x - xc) + c (y - yc)`` (m; b, c dimensionless slopes),
    fitted to ``low_surface_at`` sampled at a fixed pattern scaled by the crater radius:
    the centre plus rings at ``ejecta_extent_radii * k / 5`` radii (k = 1..5), 12
    azimuths each (61 points, equal weights). ``low_surface_at(x, y)`` receives two 1-D
    float64 arrays of site coordinates (all craters' samples in one call, possibly
    beyond the site edge by up to the crater extent) and returns their heights (m).
    Returns float64 (n, 3) rows ``(a, b, c)``.
    """
    xc = np.asarray(x_m, dtype=np.float64).reshape(-1)
    yc = np.asarray(y_m, dtype=np.float64).reshape(-1)
    d = _check_diameter(np.asarray(diameter_m, dtype=np.float64).reshape(-1))
    if not (xc.shape == yc.shape == d.shape):
        raise ConfigError(
            f"x_m, y_m and diameter_m must have equal lengths, got {xc.size}, {yc.size}, {d.size}"
        )
    if not (np.all(np.isfinite(xc)) and np.all(np.isfinite(yc))):
        raise OutOfRangeError("crater centres x_m, y_m must be finite")
    n = d.size
    if n == 0:
        return np.zeros((0, 3))
    u, v = _fit_pattern(params)
    design = np.stack([np.ones_like(u), u, v], axis=1)
    solve = np.linalg.pinv(design)  # (3, m): exact least squares for this fixed pattern
    radius = 0.5 * d
    px = xc[:, None] + radius[:, None] * u[None, :]
    py = yc[:, None] + radius[:, None] * v[None, :]
    z = np.asarray(low_surface_at(px.ravel(), py.ravel()), dtype=np.float64)
    if z.size != px.size:
        raise ConfigError(f"low_surface_at returned {z.size} values for {px.size} sample points")
    z = z.reshape(px.shape)
    if not np.all(np.isfinite(z)):
        raise OutOfRangeError("low_surface_at returned non-finite heights")
    planes = z @ solve.T
    planes[:, 1] /= radius
    planes[:, 2] /= radius
    return planes


# ----------------------------------------------------------------------------- stamping


def _index_range(coord: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Index bounds [i0, i1) of the pixels whose centre lies in [lo, hi] along a monotone
    coordinate array (increasing or decreasing)."""
    if coord.size > 1 and coord[0] > coord[-1]:
        i0 = np.searchsorted(-coord, -hi, side="left")
        i1 = np.searchsorted(-coord, -lo, side="right")
    else:
        i0 = np.searchsorted(coord, lo, side="left")
        i1 = np.searchsorted(coord, hi, side="right")
    return i0, i1


def _check_axis(name: str, coord) -> np.ndarray:
    a = np.asarray(coord, dtype=np.float64)
    if a.ndim != 1 or a.size == 0:
        raise ConfigError(f"{name} must be a non-empty 1-D array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise OutOfRangeError(f"{name} must be finite")
    step = np.diff(a)
    if a.size > 1 and not (np.all(step > 0) or np.all(step < 0)):
        raise ConfigError(f"{name} must be strictly monotone (pixel-centre coordinates)")
    return a


def stamp_craters(
    z: np.ndarray,
    *,
    x,
    y,
    craters_x,
    craters_y,
    diameters,
    freshness,
    planes,
    params: CraterShapeParams,
) -> None:
    """Insert craters into the height tile ``z`` (m, shape (nrows, ncols)) in place.

    ``x`` (ncols,) and ``y`` (nrows,) are the site coordinates (m) of the tile's pixel
    centres. Craters (centres ``craters_x``, ``craters_y`` in m, rim diameters
    ``diameters`` in m, ``freshness`` in [0, 1], ``planes`` (n, 3) from
    :func:`crater_planes`) are applied in the order given, oldest first, each as
    ``z = z + dz(r) + w(r) * (P - z)`` (see the module docstring). Work is confined to
    the bounding box of each crater's extent intersected with the tile (small craters:
    a square window a few pixels wider, whose extra pixels keep their
    values); craters without overlap are skipped. Only elementwise arithmetic is used,
    so results are bit-identical whatever the tiling. ``z`` must be float32 or float64;
    the profile is evaluated in float32.
    """
    if not isinstance(z, np.ndarray) or z.ndim != 2:
        raise ConfigError("z must be a 2-D numpy array (nrows, ncols)")
    if z.dtype not in (np.float32, np.float64):
        raise ConfigError(f"z must be float32 or float64, got dtype {z.dtype}")
    xs = _check_axis("x", x)
    ys = _check_axis("y", y)
    if z.shape != (ys.size, xs.size):
        raise ConfigError(f"z has shape {z.shape} but (len(y), len(x)) = {(ys.size, xs.size)}")
    cx = np.asarray(craters_x, dtype=np.float64).reshape(-1)
    cy = np.asarray(craters_y, dtype=np.float64).reshape(-1)
    dia = _check_diameter(np.asarray(diameters, dtype=np.float64).reshape(-1))
    fr = _check_freshness(np.asarray(freshness, dtype=np.float64).reshape(-1))
    pl = np.asarray(planes, dtype=np.float64)
    n = dia.size
    if not (cx.size == cy.size == fr.size == n) or pl.shape != (n, 3):
        raise ConfigError(
            "craters_x, craters_y, diameters, freshness must have one entry per crater and "
            f"planes shape (n, 3); got {cx.size}, {cy.size}, {n}, {fr.size} and {pl.shape}"
        )
    if n == 0:
        return
    if not (np.all(np.isfinite(cx)) and np.all(np.isfinite(cy)) and np.all(np.isfinite(pl))):
        raise OutOfRangeError("crater centres and planes must be finite")

    _stamp_all(z, xs, ys, cx, cy, dia, fr, pl, params)


def _stamp_all(z, xs, ys, cx, cy, dia, fr, pl, params: CraterShapeParams) -> None:
    """Schedule and apply validated craters (see :func:`stamp_craters`).

    Craters are grouped into waves: a crater's wave is one more than the latest wave of
    any earlier crater whose window overlaps its own (on an 8-pixel block map), so
    overlapping craters are applied in catalog order while the craters of one wave are
    pairwise disjoint. In a wave, small craters are stamped together in 3-D batches of
    equal square windows (side a multiple of 8 px) and large ones one at a time in row
    blocks. The arithmetic per pixel is the same on both paths, and pixels of a window
    outside the crater's extent are left unchanged, so the result does not depend on
    the grouping (hence not on the tiling).
    """
    nrows, ncols = z.shape
    # Box margin: every pixel outside the box has s >= extent even after float32 rounding.
    ext = crater_extent_m(dia, params=params) * (1.0 + 1e-6)
    c0, c1 = _index_range(xs, cx - ext, cx + ext)
    r0, r1 = _index_range(ys, cy - ext, cy + ext)
    hit = np.flatnonzero((c1 > c0) & (r1 > r0))
    if hit.size == 0:
        return
    cx, cy, pl, reach = cx[hit], cy[hit], pl[hit], ext[hit]
    c0, c1, r0, r1 = c0[hit], c1[hit], r0[hit], r1[hit]
    bowl, coef = _profile_pieces(dia[hit], fr[hit], params)
    # (n, 4, 5): for each crater, the coefficients of s^p (p = 0..3) over the 5 pieces
    coef32 = np.ascontiguousarray(coef.transpose(0, 2, 1), dtype=np.float32)
    bowl32 = bowl.astype(np.float32)
    inv_radius = 2.0 / dia[hit]
    ztype = z.dtype.type
    f32 = np.float32
    consts = (
        (f32(1.0), f32(params.rim_flank_radii), f32(params.ejecta_extent_radii)),
        # 1e-6 relative margin: w is exactly 0 for s >= blend_outer_radii despite rounding
        f32((1.0 + 1e-6) / (params.blend_outer_radii - 1.0)),
    )

    # Windows: a square of side `side` (multiple of 8) for small craters, else the box.
    side = -(-np.maximum(r1 - r0, c1 - c0) // _BLOCK) * _BLOCK
    small = (side <= _BATCH_MAX_SIDE) & (side <= nrows) & (side <= ncols)
    wr0 = np.where(small, np.minimum(r0, nrows - side), r0)
    wc0 = np.where(small, np.minimum(c0, ncols - side), c0)
    wr1 = np.where(small, wr0 + side, r1)
    wc1 = np.where(small, wc0 + side, c1)
    wave = _waves(wr0, wr1, wc0, wc1, nrows, ncols)
    group = np.where(small, side, 0)
    order = np.lexsort((group, wave))

    work = _Workspace(_CHUNK_PX, ztype)
    zflat = z.reshape(-1) if z.flags.c_contiguous else None
    i = 0
    n = order.size
    while i < n:
        j = int(order[i])
        if not small[j]:
            _stamp_large(
                z,
                j,
                xs,
                ys,
                cx,
                cy,
                inv_radius,
                pl,
                bowl32,
                coef32,
                (int(r0[j]), int(r1[j]), int(c0[j]), int(c1[j])),
                float(reach[j]),
                consts,
                work,
            )
            i += 1
            continue
        s_side = int(side[j])
        cap = max(1, _CHUNK_PX // (s_side * s_side))
        k = i + 1
        while k < n and k - i < cap:
            jj = order[k]
            if wave[jj] != wave[j] or group[jj] != s_side:
                break
            k += 1
        members = order[i:k]
        _stamp_batch(
            z,
            zflat,
            members,
            s_side,
            wr0[members],
            wc0[members],
            xs,
            ys,
            cx,
            cy,
            inv_radius,
            pl,
            bowl32,
            coef32,
            consts,
            work,
        )
        i = k


def _waves(wr0, wr1, wc0, wc1, nrows, ncols) -> np.ndarray:
    """Wave of each window (1-based): one more than the latest earlier overlapping wave."""
    blk = _BLOCK
    level = np.zeros(((nrows + blk - 1) // blk, (ncols + blk - 1) // blk), np.int64)
    out = np.empty(wr0.size, np.int64)
    for j, (a0, a1, b0, b1) in enumerate(
        zip(
            (wr0 // blk).tolist(),
            ((wr1 - 1) // blk + 1).tolist(),
            (wc0 // blk).tolist(),
            ((wc1 - 1) // blk + 1).tolist(),
            strict=True,
        )
    ):
        cells = level[a0:a1, b0:b1]
        lev = int(cells.max()) + 1
        cells[...] = lev
        out[j] = lev
    return out


def _axis_factors(coord, centre, inv_radius, offset, slope, ztype):
    """Elementwise per-axis factors of a crater at pixel-centre coordinates ``coord``:
    ((coord - centre) / R)^2 in float32, and offset + slope * (coord - centre) in the
    tile dtype. Both stamping paths use this, so their per-pixel arithmetic agrees."""
    delta = coord - centre
    su = (delta * inv_radius).astype(np.float32)
    su *= su
    lin = (offset + slope * delta).astype(ztype)
    return su, lin


def _stamp_large(z, j, xs, ys, cx, cy, inv_radius, pl, bowl32, coef32, box, reach, consts, work):
    """One crater over its bounding box, in row blocks of at most _CHUNK_PX pixels, each
    cut to the columns of the disc of radius ``reach`` (m) that its rows cross."""
    ra, rb, ca, cb = box
    ztype = z.dtype.type
    sx2, plane_x = _axis_factors(xs[ca:cb], cx[j], inv_radius[j], pl[j, 0], pl[j, 1], ztype)
    sy2, plane_y = _axis_factors(ys[ra:rb], cy[j], inv_radius[j], 0.0, pl[j, 2], ztype)
    adx = np.abs(xs[ca:cb] - cx[j])
    ady = np.abs(ys[ra:rb] - cy[j])
    step = max(1, _CHUNK_PX // (cb - ca))
    for q0 in range(0, rb - ra, step):
        q1 = min(q0 + step, rb - ra)
        # Columns left out lie beyond `reach` (> extent by 1e-6 relative): no-op pixels.
        dmin = float(ady[q0:q1].min())
        half2 = reach * reach - dmin * dmin
        if half2 <= 0.0:
            continue
        cols = np.flatnonzero(adx <= math.sqrt(half2) * (1.0 + 1e-6))
        if cols.size == 0:
            continue
        k0, k1 = int(cols[0]), int(cols[-1]) + 1
        _stamp_block(
            z[ra + q0 : ra + q1, ca + k0 : ca + k1],
            sy2[q0:q1, None],
            sx2[None, k0:k1],
            plane_y[q0:q1, None],
            plane_x[None, k0:k1],
            bowl32[j],
            coef32[j],
            None,
            consts,
            work,
        )


def _stamp_batch(
    z, zflat, members, side, wr0, wc0, xs, ys, cx, cy, inv_radius, pl, bowl32, coef32, consts, work
):
    """Pairwise-disjoint small craters at once, each on a side x side window."""
    ztype = z.dtype.type
    span = np.arange(side)
    rows = wr0[:, None] + span  # (B, side)
    cols = wc0[:, None] + span
    m = members[:, None]
    sx2, plane_x = _axis_factors(xs[cols], cx[m], inv_radius[m], pl[m, 0], pl[m, 1], ztype)
    sy2, plane_y = _axis_factors(ys[rows], cy[m], inv_radius[m], 0.0, pl[m, 2], ztype)
    nb = members.size
    cf = coef32[members].transpose(1, 0, 2).reshape(4, nb * 5)
    k_base = (5 * np.arange(nb, dtype=np.intp))[:, None, None]
    if zflat is not None:
        idx = (rows * z.shape[1])[:, :, None] + cols[:, None, :]
        zw = zflat.take(idx)
    else:
        zw = z[rows[:, :, None], cols[:, None, :]]
    _stamp_block(
        zw,
        sy2[:, :, None],
        sx2[:, None, :],
        plane_y[:, :, None],
        plane_x[:, None, :],
        bowl32[members][:, None, None],
        cf,
        k_base,
        consts,
        work,
    )
    if zflat is not None:
        zflat[idx] = zw
    else:
        z[rows[:, :, None], cols[:, None, :]] = zw


class _Workspace:
    """Flat scratch buffers for one block of at most ``size`` pixels."""

    def __init__(self, size: int, ztype) -> None:
        self.size = size
        self.s = np.empty(size, np.float32)
        self.dz = np.empty(size, np.float32)
        self.tmp = np.empty(size, np.float32)
        self.w = np.empty(size, np.float32)
        self.k8 = np.empty(size, np.int8)
        self.mask = np.empty(size, np.bool_)
        self.k = np.empty(size, np.intp)
        self.plane = np.empty(size, ztype)

    def view(self, name: str, shape):
        return getattr(self, name)[: math.prod(shape)].reshape(shape)


_ONE = np.float32(1.0)
_TWO = np.float32(2.0)
_ZERO = np.float32(0.0)


def _stamp_block(zt, sy2, sx2, plane_y, plane_x, bowl, cf, k_base, consts, work):
    """Apply craters to the block ``zt`` in place, elementwise: z += dz(s) + w(s) (P - z).

    ``sy2 + sx2`` (broadcast to ``zt.shape``) is s^2 in float32, ``plane_y + plane_x`` the
    fitted plane; ``cf`` (4, m) holds the piece coefficients of s^0..s^3, indexed by the
    piece number k (+ ``k_base`` when several craters share the block).
    """
    shape = zt.shape
    breaks, blend_scale = consts
    s = work.view("s", shape)
    np.add(sy2, sx2, out=s)
    np.sqrt(s, out=s)
    # piece index k = #{breaks <= s}, breaks = (bowl, 1, rim_flank, extent)
    k8 = work.view("k8", shape)
    mask = work.view("mask", shape)
    np.greater_equal(s, bowl, out=k8.view(np.bool_))
    for brk in breaks:
        np.greater_equal(s, brk, out=mask)
        k8 += mask.view(np.int8)
    k = work.view("k", shape)
    np.copyto(k, k8)
    if k_base is not None:
        k += k_base
    dz = work.view("dz", shape)
    tmp = work.view("tmp", shape)
    np.take(cf[3], k, out=dz, mode="wrap")
    for power in (2, 1, 0):
        dz *= s
        np.take(cf[power], k, out=tmp, mode="wrap")
        dz += tmp
    # obliteration weight w = (1 - t)^2 (1 + 2 t), t = clip((s - 1) / (blend - 1), 0, 1)
    t = s
    t -= _ONE
    t *= blend_scale
    np.maximum(t, _ZERO, out=t)
    np.minimum(t, _ONE, out=t)
    w = work.view("w", shape)
    np.subtract(_ONE, t, out=w)
    w *= w
    t *= _TWO
    t += _ONE
    w *= t
    plane = work.view("plane", shape)
    np.add(plane_y, plane_x, out=plane)
    plane -= zt
    plane *= w
    plane += dz
    zt += plane
