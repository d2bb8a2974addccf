"""Typed configuration of the world model: one dataclass per layer, collected in
:class:`WorldConfig` (loadable from YAML with ``yaml_load_typed``).

Defaults and where they come from are in each docstring; every field is checked by
``validate()`` and an out-of-range value raises a one-line
:class:`~lunar_drake.errors.OutOfRangeError` naming it.
"""

# No `from __future__ import annotations`: yaml_load_typed reads real field types.

import dataclasses as dc

from lunar_drake.errors import ConfigError, LunarDrakeError, OutOfRangeError, check_range


@dc.dataclass
class SunEnvelopeConfig:
    """The Sun over a year, sampled to find permanent shadow and maximum temperatures.

    Attributes:
        years: span sampled from the epoch (yr), (0, 20]; 1 = one year (the issue's).
        step_h: sampling step (h), (0, 240]; the polar Sun moves ~0.5 deg/h in azimuth.
        azimuth_bins: azimuth sectors (-), [4, 360]; each is one horizon computation at
            its centre (the Sun's azimuth is quantised to the sector: an approximation
            for shadow edges that run along the Sun's direction).
        horizon_resolution_deg: unused since the hull sweep computes exact horizons
            (deg), (0, 1]; kept so that older scenario files still load, and not part of
            the world model's cache key.
    """

    years: float = 1.0
    step_h: float = 6.0
    azimuth_bins: int = 24
    horizon_resolution_deg: float = 0.2

    def validate(self) -> None:
        check_range("years", self.years, 0.0, 20.0, lo_open=True, unit=" yr")
        check_range("step_h", self.step_h, 0.0, 240.0, lo_open=True, unit=" h")
        _int_range("azimuth_bins", self.azimuth_bins, 4, 360)
        check_range(
            "horizon_resolution_deg",
            self.horizon_resolution_deg,
            0.0,
            1.0,
            lo_open=True,
            unit=" deg",
        )


@dc.dataclass
class ThermalConfig:
    """Surface temperature: radiative equilibrium (regolith is an excellent insulator).

    ``T = ((Q_sun + Q_env + q_geo) / (emissivity sigma))^(1/4)``, with the absorbed
    direct sunlight ``Q_sun = (1 - bond_albedo) S f cos(i)`` (``S`` the solar constant at
    the Sun's distance, ``f`` the visible fraction of the disk, ``i`` the incidence on the
    DEM's slope), the geothermal heat flow ``q_geo`` and, the approximation that sets
    shadowed temperatures, ``Q_env = F (emissivity M_ir + (1 - bond_albedo) M_vis)``:
    ``F`` the cosine-weighted view factor of the terrain above each cell's horizon
    (``mean sin^2(h)`` over ``view_azimuths`` azimuths), ``M_ir`` and ``M_vis`` the
    thermal emission and scattered sunlight of the terrain averaged over the square of
    half-side ``env_radius_m`` around the cell (not ray-traced: every cell of it counts,
    seen or not).

    Attributes:
        bond_albedo: bolometric Bond albedo (-), [0, 1); 0.12 (Vasavada et al. 2012,
            JGR 117, E00H18).
        emissivity: infrared emissivity (-), (0, 1]; 0.95 (same).
        geothermal_w_m2: interior heat flow (W/m^2), [0, 1]; 0.016 (Langseth et al.
            1976, Apollo 17: 16 mW/m^2). Alone it holds a cell at ~23 K.
        solar_constant_w_m2: at 1 au (W/m^2); 1361 (Kopp & Lean 2011).
        env_radius_m: radius of the terrain that heats a cell (m), (0, 1e4].
        view_azimuths: azimuths of the view-factor horizons (-), [4, 64].
        view_max_deg: horizons are resolved up to this elevation (deg), (0, 80].
        view_resolution_m: the DEM is block-averaged to about this pixel for the view
            factor (m), >= 0 (0: the DEM's own).
        whole_max_mpx: DEMs of at most this many megapixels are held and swept whole
            (exact to the hull sweep; about 45 bytes a pixel: 3 GB at 8192^2), (>= 0).
            Larger ones are built out of core: read a strip of rows at a time, terrain
            beyond ``near_field_m`` from a decimated copy (:mod:`.strips`).
        strip_px: rows of each illumination strip out of core (px), [16, 2^20].
        near_field_m: with strips, terrain at least this far around a strip is swept at
            full resolution (m), (0, 1e4], at least twice ``far_cell_m``.
        far_cell_m: with strips, the pixel of the decimated DEM beyond (m), (0, 100]
            (coarser where its grid would exceed 4 Mpx).
    """

    bond_albedo: float = 0.12
    emissivity: float = 0.95
    geothermal_w_m2: float = 0.016
    solar_constant_w_m2: float = 1361.0
    env_radius_m: float = 10.0
    view_azimuths: int = 8
    view_max_deg: float = 40.0
    view_resolution_m: float = 0.5
    whole_max_mpx: float = 80.0
    strip_px: int = 1024
    near_field_m: float = 10.0
    far_cell_m: float = 0.64

    def validate(self) -> None:
        check_range("bond_albedo", self.bond_albedo, 0.0, 1.0, hi_open=True)
        check_range("emissivity", self.emissivity, 0.0, 1.0, lo_open=True)
        check_range("geothermal_w_m2", self.geothermal_w_m2, 0.0, 1.0, unit=" W/m^2")
        check_range(
            "solar_constant_w_m2", self.solar_constant_w_m2, 0.0, 1e5, lo_open=True, unit=" W/m^2"
        )
        check_range("env_radius_m", self.env_radius_m, 0.0, 1e4, lo_open=True, unit=" m")
        _int_range("view_azimuths", self.view_azimuths, 4, 64)
        check_range("view_max_deg", self.view_max_deg, 0.0, 80.0, lo_open=True, unit=" deg")
        check_range("view_resolution_m", self.view_resolution_m, 0.0, 1e3, unit=" m")
        check_range("whole_max_mpx", self.whole_max_mpx, 0.0, 1e6, unit=" Mpx")
        _int_range("strip_px", self.strip_px, 16, 1 << 20)
        check_range("near_field_m", self.near_field_m, 0.0, 1e4, lo_open=True, unit=" m")
        check_range("far_cell_m", self.far_cell_m, 0.0, 100.0, lo_open=True, unit=" m")
        if self.near_field_m < 2.0 * self.far_cell_m:
            raise ConfigError(
                f"near_field_m = {self.near_field_m!r} must be at least twice far_cell_m = "
                f"{self.far_cell_m!r}: the far field starts a far cell short of the near "
                "field's edge"
            )

    def out_of_core(self, shape) -> bool:
        """Whether a DEM of ``shape`` is built strip by strip (``whole_max_mpx``)."""
        return int(shape[0]) * int(shape[1]) > self.whole_max_mpx * 1e6


@dc.dataclass
class FrostConfig:
    """Surface frost: only in permanent shadow, more in larger patches.

    ``frost = max_area_frac (1 - exp(-A / area_scale_m2))`` in a permanently shadowed
    patch of area ``A`` (8-connected cells) whose maximum temperature is below the ice
    stability temperature, 0 elsewhere. The growth with area is our assumption (Hayne et
    al. 2021, Nature Astronomy 5, 169, find cold traps down to about 1 cm, their
    temperatures set mostly by shape and latitude); the form is ours.

    Attributes:
        max_area_frac: area fraction of the largest patches (-), [0, 1].
        area_scale_m2: patch area at which frost reaches 63 % of the maximum (m^2), > 0.
    """

    max_area_frac: float = 0.1
    area_scale_m2: float = 20.0

    def validate(self) -> None:
        check_range("max_area_frac", self.max_area_frac, 0.0, 1.0)
        check_range("area_scale_m2", self.area_scale_m2, 0.0, 1e12, lo_open=True, unit=" m^2")


@dc.dataclass
class OHConfig:
    """Surface OH: more on colder ground, a logistic in the temperature at the epoch.

    ``OH = min_ppm + (max_ppm - min_ppm) / (1 + exp((T - half_K) / width_K))``: Li &
    Milliken (2017, Sci. Adv. 3, e1701471) find hydration of 500-750 ppm at high
    latitudes, falling where and when the surface is warmer; the form is ours.

    Attributes:
        min_ppm, max_ppm: warm and cold limits (ppm), 0 <= min <= max <= 1e5.
        half_K: temperature halfway between them (K), (0, 500]. width_K: its width (K).
    """

    min_ppm: float = 100.0
    max_ppm: float = 750.0
    half_K: float = 300.0
    width_K: float = 30.0

    def validate(self) -> None:
        check_range("min_ppm", self.min_ppm, 0.0, 1e5, unit=" ppm")
        check_range("max_ppm", self.max_ppm, 0.0, 1e5, unit=" ppm")
        if self.min_ppm > self.max_ppm:
            raise OutOfRangeError(
                f"min_ppm = {self.min_ppm!r} is above max_ppm = {self.max_ppm!r}; "
                "allowed min_ppm <= max_ppm (ppm)"
            )
        check_range("half_K", self.half_K, 0.0, 500.0, lo_open=True, unit=" K")
        check_range("width_K", self.width_K, 0.0, 500.0, lo_open=True, unit=" K")


@dc.dataclass
class IceConfig:
    """The dry layer and the ice below it.

    **Dry layer** (Paige et al. 2010, Science 330, 479: ice is stable for billions of
    years where the maximum temperature stays below ~``stable_K`` = 110 K, at the
    surface or at depth). The temperature wave decays into the regolith with the skin
    depth: ``T_max(z) = T_mean + (T_max - T_mean) exp(-z / skin_depth_m)``, so the depth
    where ``T_max(z) = stable_K`` is ``z = skin_depth ln((T_max - T_mean) / (stable_K -
    T_mean))`` (0 where ``T_max <= stable_K``; ``max_depth_m`` where even the mean is too
    warm). ``T_mean`` comes from the time-weighted mean flux (an upper bound on the mean
    temperature: the mean of ``T`` is at most ``T`` of the mean flux).

    **Ice** below it: after the paper (a model of impact gardening, a function of the
    distance to the rims of craters above a size): ``ice = background_wt_pct +
    rim_wt_pct (1 - prod_k (1 - a_k exp(-d_k / (falloff_radii R_k))))`` over craters
    ``k`` of diameter >= ``min_crater_m``, ``d_k`` the distance to the rim, ``a_k =
    exp(-age_k / age_scale_yr)``; 0 where the dry layer reaches ``max_depth_m`` (no ice
    within reach of the drill). The form is ours.

    Attributes:
        stable_K: ice stability temperature (K), (0, 300].
        skin_depth_m: thermal skin depth of the lunar day (m), (0, 10]; 0.05 (4-7 cm,
            Vasavada et al. 2012).
        max_depth_m: dry layer where ice is not stable within reach (m), (0, 100].
        background_wt_pct, rim_wt_pct: ice far from and at fresh rims (wt%), >= 0, sum
            <= 100.
        min_crater_m: smallest crater that gardens (m), > 0.
        falloff_radii: e-folding distance from the rim (crater radii), > 0.
        age_scale_yr: e-folding age of a crater's effect (yr), > 0.
    """

    stable_K: float = 110.0
    skin_depth_m: float = 0.05
    max_depth_m: float = 1.5
    background_wt_pct: float = 0.5
    rim_wt_pct: float = 4.5
    min_crater_m: float = 5.0
    falloff_radii: float = 1.0
    age_scale_yr: float = 1.0e9

    def validate(self) -> None:
        check_range("stable_K", self.stable_K, 0.0, 300.0, lo_open=True, unit=" K")
        check_range("skin_depth_m", self.skin_depth_m, 0.0, 10.0, lo_open=True, unit=" m")
        check_range("max_depth_m", self.max_depth_m, 0.0, 100.0, lo_open=True, unit=" m")
        check_range("background_wt_pct", self.background_wt_pct, 0.0, 100.0, unit=" wt%")
        check_range(
            "rim_wt_pct",
            self.rim_wt_pct,
            0.0,
            100.0 - self.background_wt_pct,
            unit=" wt% (background + rim <= 100)",
        )
        check_range("min_crater_m", self.min_crater_m, 0.0, 1e6, lo_open=True, unit=" m")
        check_range("falloff_radii", self.falloff_radii, 0.0, 1e3, lo_open=True)
        check_range("age_scale_yr", self.age_scale_yr, 0.0, 1e11, lo_open=True, unit=" yr")


#: Minerals of ``minerals.tif``, one band each (band descriptions carry the names).
MINERALS = ("plagioclase", "pyroxene", "olivine", "ilmenite")


@dc.dataclass
class MineralConfig:
    """Hydrogen-bearing minerals and minerals: seeded fractal (Perlin-like value) noise,
    as the paper did, tile-invariant (:mod:`.minerals`).

    Attributes:
        h_mean_ppm: mean hydrogen in hydrogen-bearing minerals (ppm), [0, 1e4].
        h_amplitude: log-normal spread of it (-), [0, 3].
        abundances_wt_pct: mean wt% of :data:`MINERALS` (polar highlands; renormalised to
            100).
        mineral_amplitude: log-normal spread of each (-), [0, 3].
        scales_m: noise octaves (m), each > 0; the coarsest first.
    """

    h_mean_ppm: float = 50.0
    h_amplitude: float = 0.4
    abundances_wt_pct: list[float] = dc.field(default_factory=lambda: [75.0, 15.0, 8.0, 2.0])
    mineral_amplitude: float = 0.3
    scales_m: list[float] = dc.field(default_factory=lambda: [50.0, 12.0, 3.0])

    def validate(self) -> None:
        check_range("h_mean_ppm", self.h_mean_ppm, 0.0, 1e4, unit=" ppm")
        check_range("h_amplitude", self.h_amplitude, 0.0, 3.0)
        if len(self.abundances_wt_pct) != len(MINERALS):
            raise ConfigError(
                f"abundances_wt_pct has {len(self.abundances_wt_pct)} values; one per mineral "
                f"{MINERALS} is required"
            )
        for name, v in zip(MINERALS, self.abundances_wt_pct, strict=True):
            check_range(f"abundances_wt_pct[{name}]", v, 0.0, 100.0, lo_open=True, unit=" wt%")
        check_range("mineral_amplitude", self.mineral_amplitude, 0.0, 3.0)
        if not self.scales_m:
            raise ConfigError("scales_m is empty; give at least one noise scale (m)")
        for v in self.scales_m:
            check_range("scales_m", v, 0.0, 1e6, lo_open=True, unit=" m")


@dc.dataclass
class WorldConfig:
    """The world model (:mod:`lunar_drake.science`).

    Attributes:
        sun, thermal, frost, oh, ice, minerals: one section per layer (see each).
        tile_px: tile edge of the lazy computation (px), [64, 16384]; never changes a byte.
        workers: threads (-), [1, 64].
        compress: the GeoTIFFs' compression: ``none``, ``zstd``, ``deflate`` or ``lzw``
            (lossless, with a predictor; ``zstd`` halves a 30720^2 stack's 50 GB).
    """

    sun: SunEnvelopeConfig = dc.field(default_factory=SunEnvelopeConfig)
    thermal: ThermalConfig = dc.field(default_factory=ThermalConfig)
    frost: FrostConfig = dc.field(default_factory=FrostConfig)
    oh: OHConfig = dc.field(default_factory=OHConfig)
    ice: IceConfig = dc.field(default_factory=IceConfig)
    minerals: MineralConfig = dc.field(default_factory=MineralConfig)
    tile_px: int = 2048
    workers: int = 2
    compress: str = "none"

    def validate(self) -> None:
        """Raises the section's error, its message prefixed with the section's name."""
        for name in ("sun", "thermal", "frost", "oh", "ice", "minerals"):
            try:
                getattr(self, name).validate()
            except LunarDrakeError as exc:
                raise type(exc)(f"{name}.{exc}") from None
        _int_range("tile_px", self.tile_px, 64, 16384)
        _int_range("workers", self.workers, 1, 64)
        if self.compress not in ("none", "zstd", "deflate", "lzw"):
            raise ConfigError(
                f"compress = {self.compress!r} is unknown; allowed: none, zstd, deflate, lzw"
            )


def _int_range(name: str, value, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{name} = {value!r} must be an integer in [{lo}, {hi}]")
    check_range(name, value, lo, hi)
