"""The world model of a site: every layer, written as GeoTIFFs and heat maps.

``lunar-drake world build SITE_DIR --out DIR [--utc TIME]`` (:func:`build_world`). Each
layer is computed only from those before it:

==========================  ======  ==================================================
file                        unit    from
==========================  ======  ==================================================
``psr.tif`` (uint8)         1/0     the DEM and the Sun's elevation envelope over a year
                                    (never any of the disk visible: 1)
``lit_fraction.tif``        -       the Sun's disk visible at the epoch (lightmap)
``t_max_K.tif``             K       the highest direct flux over the year, terrain IR
``t_mean_K.tif``            K       the time-mean direct flux, terrain IR
``temperature_K.tif``       K       the Sun at the epoch (lightmap), terrain IR
``frost_area_frac.tif``     -       psr, t_max (patch areas)
``oh_ppm.tif``              ppm     temperature at the epoch
``dry_layer_m.tif``         m       t_max, t_mean
``ice_wt_pct.tif``          wt%     dry layer, crater catalog (rims and ages)
``h_minerals_ppm.tif``      ppm     seeded fractal noise
``minerals.tif``            wt%     seeded fractal noise, one band per mineral (named)
==========================  ======  ==================================================

Plus ``<layer>.png`` heat maps over the hillshade, ``world.png`` (six layers side by
side) and ``world.json`` (the epoch, the
Sun's envelope, per-layer statistics, the configuration), written last: a directory
with ``world.json`` is complete. Every layer is range-checked before it is written
(:func:`check_layer`); each file is written under a temporary name and renamed.

The computation is in memory (the horizons are tiled, bit-identical for any
``tile_px``); out-of-core building of the paper's 30720^2 stack is not done yet.
"""

from __future__ import annotations

import dataclasses as dc
import json
import math
import time
from pathlib import Path

import numpy as np

from lunar_drake.errors import LunarDrakeError, RasterNotFoundError
from lunar_drake.science import minerals as mineral_layers
from lunar_drake.science import thermal, volatiles
from lunar_drake.science.config import MINERALS, WorldConfig
from lunar_drake.science.sun_envelope import SunEnvelope, sun_envelope


class WorldModelError(LunarDrakeError, ValueError):
    """A site the world model cannot be built from, or a layer outside its range."""


#: Layer name -> (unit, physical range (lo, hi), colour map); ``minerals`` is 4 bands.
LAYERS = {
    "psr": ("1 = permanent shadow", (0, 1), "gray_r"),
    "lit_fraction": ("visible fraction of the Sun at the epoch", (0.0, 1.0), "gray"),
    "t_max_K": ("K", (0.0, 450.0), "inferno"),
    "t_mean_K": ("K", (0.0, 450.0), "inferno"),
    "temperature_K": ("K", (0.0, 450.0), "inferno"),
    "frost_area_frac": ("area fraction", (0.0, 1.0), "Blues"),
    "oh_ppm": ("ppm", (0.0, 1e5), "viridis"),
    "dry_layer_m": ("m", (0.0, 100.0), "copper_r"),
    "ice_wt_pct": ("wt%", (0.0, 100.0), "Blues"),
    "h_minerals_ppm": ("ppm", (0.0, 1e5), "magma"),
    "minerals": ("wt%", (0.0, 100.0), "cividis"),
}


def default_utc() -> str:
    """The default scenario's epoch (``site.epoch_utc``)."""
    from lunar_drake.scenario_files import load_scenario

    return load_scenario(scenario_name="default").site.epoch_utc


def check_layer(name: str, values: np.ndarray) -> None:
    """Raises :class:`WorldModelError` naming the layer, its range and the allowed one
    when ``values`` has NaN or leaves the layer's physical range."""
    if name not in LAYERS:
        raise WorldModelError(f"layer {name!r} is unknown; layers are {tuple(LAYERS)}")
    unit, (lo, hi), _ = LAYERS[name]
    v = np.asarray(values, np.float64)
    if v.size == 0:
        raise WorldModelError(f"layer {name!r} is empty")
    vmin, vmax = float(np.min(v)), float(np.max(v))
    if not (math.isfinite(vmin) and math.isfinite(vmax)) or vmin < lo or vmax > hi:
        raise WorldModelError(
            f"layer {name!r} spans [{vmin:g}, {vmax:g}] {unit}, outside its physical range "
            f"[{lo:g}, {hi:g}]"
        )


@dc.dataclass(frozen=True)
class Craters:
    """The parts of a site's crater catalog the world model reads (site metres, yr)."""

    x_m: np.ndarray
    y_m: np.ndarray
    diameter_m: np.ndarray
    age_yr: np.ndarray


def read_craters(path) -> Craters:
    """``craters.csv`` of a synthesized site (``x_m,y_m,diameter_m,...,age_yr``)."""
    p = Path(path)
    if not p.is_file():
        raise WorldModelError(
            f"site {str(p.parent)!r} has no crater catalog ({p.name}); the ice layer needs "
            "one: synthesize the site with 'lunar-drake terrain synth'"
        )
    with open(p) as f:
        header = f.readline().strip().split(",")
    need = ("x_m", "y_m", "diameter_m", "age_yr")
    missing = [c for c in need if c not in header]
    if missing:
        raise WorldModelError(f"{str(p)!r} lacks column(s) {missing}; it has {header}")
    try:
        data = np.loadtxt(p, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise WorldModelError(f"{str(p)!r} is not a numeric crater table: {exc}") from None
    cols = {c: data[:, header.index(c)] if data.size else np.zeros(0) for c in need}
    bad = ~np.isfinite(np.column_stack(list(cols.values()))).all(axis=1) if data.size else []
    if np.any(bad) or (data.size and (cols["diameter_m"] <= 0).any()):
        row = int(np.argmax(bad)) if np.any(bad) else int(np.argmax(cols["diameter_m"] <= 0))
        raise WorldModelError(
            f"{str(p)!r} row {row + 2}: crater values must be finite with diameter_m > 0"
        )
    return Craters(**cols)


#: Every file a world directory may hold (a rebuild may replace a directory of only these).
WORLD_FILES = frozenset(
    [*(f"{n}.tif" for n in LAYERS), *(f"{n}.png" for n in LAYERS), "world.png", "world.json"]
)


@dc.dataclass(frozen=True)
class World:
    """Layers of a site (arrays, row 0 north) and where they sit.

    Attributes:
        layers: name -> array (``minerals``: ``(bands, rows, cols)``).
        resolution_m: pixel (m). transform, crs: the DEM's (GeoTIFF georeferencing).
        utc: the epoch of ``temperature_K`` and ``oh_ppm``. envelope: the Sun's.
        sun_azimuth_deg, sun_elevation_deg: the Sun at the epoch (grid frame, deg).
    """

    layers: dict
    resolution_m: float
    transform: object
    crs: object
    utc: str
    envelope: SunEnvelope
    sun_azimuth_deg: float
    sun_elevation_deg: float


def compute_world(
    z: np.ndarray,
    *,
    resolution_m: float,
    craters: Craters,
    seed: int,
    envelope: SunEnvelope,
    sun_azimuth_deg: float,
    sun_elevation_deg: float,
    sun_distance_au: float = 1.0,
    config: WorldConfig | None = None,
    horizon_mask=None,
    progress=None,
) -> dict:
    """Every layer of DEM ``z`` (row 0 north, site origin at its centre) as arrays.

    ``progress(stage, fraction)`` is called as stages complete.
    """
    cfg = config or WorldConfig()
    cfg.validate()
    z = np.asarray(z, np.float64)
    rows, cols = z.shape
    t = cfg.thermal

    def report(stage, frac):
        if progress is not None:
            progress(stage, frac)

    illum = thermal.illumination(
        z,
        resolution_m=resolution_m,
        envelope=envelope,
        config=t,
        horizon_mask=horizon_mask,
        horizon_resolution_deg=cfg.sun.horizon_resolution_deg,
        tile_px=cfg.tile_px,
        workers=cfg.workers,
        progress=lambda i, n: report("sun over a year", 0.6 * i / n),
    )
    view = thermal.view_factor(
        z, resolution_m=resolution_m, config=t, tile_px=cfg.tile_px, workers=cfg.workers
    )
    report("view factors", 0.75)
    q_now, lit_now = thermal.direct_flux_at(
        z,
        resolution_m=resolution_m,
        sun_azimuth_deg=sun_azimuth_deg,
        sun_elevation_deg=sun_elevation_deg,
        distance_au=sun_distance_au,
        config=t,
        horizon_mask=horizon_mask,
        tile_px=cfg.tile_px,
        workers=cfg.workers,
        with_lit_fraction=True,
    )
    out = {"psr": (~illum.ever_lit).astype(np.uint8), "lit_fraction": lit_now}
    out["t_max_K"] = thermal.temperature(
        illum.q_max_w_m2, view=view, resolution_m=resolution_m, config=t
    )
    out["t_mean_K"] = np.minimum(
        thermal.temperature(illum.q_mean_w_m2, view=view, resolution_m=resolution_m, config=t),
        out["t_max_K"],
    )
    out["temperature_K"] = thermal.temperature(
        q_now, view=view, resolution_m=resolution_m, config=t
    )
    report("temperatures", 0.85)
    out["frost_area_frac"] = volatiles.frost_area_fraction(
        out["psr"],
        out["t_max_K"],
        resolution_m=resolution_m,
        config=cfg.frost,
        stable_k=cfg.ice.stable_K,
    )
    out["oh_ppm"] = volatiles.oh_ppm(out["temperature_K"], config=cfg.oh)
    out["dry_layer_m"] = volatiles.dry_layer_m(out["t_max_K"], out["t_mean_K"], config=cfg.ice)
    rim = volatiles.rim_factor(
        z.shape,
        resolution_m=resolution_m,
        x0_m=-0.5 * cols * resolution_m,
        y1_m=0.5 * rows * resolution_m,
        craters=craters,
        config=cfg.ice,
    )
    out["ice_wt_pct"] = volatiles.ice_wt_pct(out["dry_layer_m"], rim, config=cfg.ice)
    report("volatiles", 0.95)
    window = (0, 0, rows, cols)
    out["h_minerals_ppm"] = mineral_layers.h_minerals_ppm(
        seed, window=window, resolution_m=resolution_m, config=cfg.minerals
    )
    out["minerals"] = mineral_layers.minerals_wt_pct(
        seed, window=window, resolution_m=resolution_m, config=cfg.minerals
    )
    for name, v in out.items():
        if name != "psr":
            out[name] = np.asarray(v, np.float32)
        check_layer(name, out[name])
    report("done", 1.0)
    return out


def _site_seed(site_dir: Path) -> int:
    try:
        meta = json.loads((site_dir / "site.json").read_text())
        return int(meta.get("config", {}).get("seed", 0))
    except (OSError, ValueError):
        return 0


def build_world(
    *,
    site_dir,
    out_dir,
    utc: str | None = None,
    config: WorldConfig | None = None,
    seed: int | None = None,
    png: bool = True,
    progress: bool = True,
) -> dict:
    """Builds the world model of ``site_dir`` (a synthesized site: ``dem.tif`` and
    ``craters.csv``) into ``out_dir``; returns the ``world.json`` summary.

    Raises:
        WorldModelError: no crater catalog, or a layer out of its physical range.
        RasterNotFoundError / RasterError / CRSError: a missing or bad DEM.
    """
    from lunar_drake.ephemeris.sun_earth import SiteLocation, enu_basis, sun_earth_enu
    from lunar_drake.render.lightmap import site_and_grid_north
    from lunar_drake.science.sun_envelope import AU_KM
    from lunar_drake.terrain.heightfield import Heightfield

    cfg = config or WorldConfig()
    cfg.validate()
    site_dir = Path(site_dir)
    dem = site_dir / "dem.tif"
    if not dem.is_file():
        raise RasterNotFoundError(
            f"site {str(site_dir)!r} has no dem.tif; a site directory from 'lunar-drake "
            "terrain synth' is needed"
        )
    craters = read_craters(site_dir / "craters.csv")
    utc = utc or default_utc()
    seed = _site_seed(site_dir) if seed is None else int(seed)
    t0 = time.perf_counter()
    bar = _progress_bar(progress)
    hf = Heightfield.open(dem)
    try:
        z = hf.read_window(0, 0, *hf.shape)
        holes = int(np.count_nonzero(~np.isfinite(z)))
        if holes:
            raise WorldModelError(
                f"{str(dem)!r} has {holes} nodata cells; the world model needs a complete DEM"
            )
        env = sun_envelope(hf, utc=utc, config=cfg.sun)
        site, beta = site_and_grid_north(hf, enu_basis=enu_basis, SiteLocation=SiteLocation)
        se = sun_earth_enu(utc=utc, site=site)
        az = (float(se.sun_azimuth_deg) + beta) % 360.0
        el = float(se.sun_elevation_deg)
        layers = compute_world(
            z,
            resolution_m=hf.resolution_m,
            craters=craters,
            seed=seed,
            envelope=env,
            sun_azimuth_deg=az,
            sun_elevation_deg=el,
            sun_distance_au=float(se.sun_distance_km) / AU_KM,
            config=cfg,
            progress=bar,
        )
        transform, crs, res = hf.transform, hf.crs, hf.resolution_m
    finally:
        hf.close()
        if bar is not None:
            bar(None, None)
    world = World(
        layers=layers,
        resolution_m=res,
        transform=transform,
        crs=crs,
        utc=utc,
        envelope=env,
        sun_azimuth_deg=az,
        sun_elevation_deg=el,
    )
    return write_world(
        world,
        out_dir=out_dir,
        z=z,
        config=cfg,
        png=png,
        extra={
            "site_dir": str(site_dir),
            "seed": seed,
            "seconds": round(time.perf_counter() - t0, 2),
        },
    )


def write_world(
    world: World,
    *,
    out_dir,
    z=None,
    config: WorldConfig | None = None,
    png: bool = True,
    extra: dict | None = None,
) -> dict:
    """Writes every layer's GeoTIFF (and heat map), then ``world.json``; returns it."""
    from lunar_drake.files import atomic_write_text
    from lunar_drake.terrain.geotiff import write_geotiff

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stats = {}
    for name, arr in world.layers.items():
        path = out / f"{name}.tif"
        if name == "minerals":
            write_named_bands(path, arr, names=MINERALS, transform=world.transform, crs=world.crs)
        else:
            write_geotiff(path, arr, transform=world.transform, crs=world.crs)
        a = np.asarray(arr, np.float64)
        stats[name] = {
            "unit": LAYERS[name][0],
            "min": float(a.min()),
            "max": float(a.max()),
            "mean": float(a.mean()),
        }
        if png:
            heat_map(out / f"{name}.png", arr, name=name, resolution_m=world.resolution_m, z=z)
    if png:
        overview(
            out / "world.png",
            world.layers,
            resolution_m=world.resolution_m,
            z=z,
            title=f"World model at {world.utc}",
        )
    env = world.envelope
    summary = {
        "utc": world.utc,
        "resolution_m": world.resolution_m,
        "shape": list(np.shape(world.layers["psr"])),
        "sun_at_epoch": {
            "azimuth_deg": world.sun_azimuth_deg,
            "elevation_deg": world.sun_elevation_deg,
        },
        "sun_envelope": {
            "samples": env.samples,
            "azimuth_bins": int(env.azimuth_deg.size),
            "max_elevation_deg": env.max_elevation_deg,
            "el_max_deg": [round(float(v), 4) for v in env.el_max_deg],
        },
        "psr_fraction": float(np.mean(world.layers["psr"])),
        "layers": stats,
        "minerals": list(MINERALS),
        "config": dc.asdict(config or WorldConfig()),
        **(extra or {}),
    }
    atomic_write_text(out / "world.json", json.dumps(summary, indent=2) + "\n")
    return summary


def write_named_bands(path, arr, *, names, transform, crs, nodata=None) -> None:
    """A GeoTIFF (atomic, :func:`~lunar_drake.terrain.geotiff.write_geotiff`) whose bands
    carry ``names`` as their descriptions."""
    import rasterio

    from lunar_drake.files import atomic_path
    from lunar_drake.terrain.geotiff import write_geotiff

    with atomic_path(path, what="raster") as tmp:
        write_geotiff(tmp, arr, transform=transform, crs=crs, nodata=nodata)
        with rasterio.open(tmp, "r+") as ds:
            for k, n in enumerate(names, start=1):
                ds.set_band_description(k, n)


def world_key(site_dir, *, utc: str, config: WorldConfig) -> str:
    """Cache key of a site's world model: its ``site.json`` (what determines the site's
    bytes), the epoch and the configuration (tile size and workers excluded: they never
    change a byte)."""
    import hashlib

    site_dir = Path(site_dir)
    try:
        site_text = (site_dir / "site.json").read_text()
    except OSError:
        raise WorldModelError(
            f"site {str(site_dir)!r} has no site.json; the world model needs a site from "
            "'lunar-drake terrain synth'"
        ) from None
    cfg = dc.asdict(config)
    cfg.pop("tile_px"), cfg.pop("workers")
    text = json.dumps(
        {"site": site_text, "utc": utc, "config": cfg, "layers": list(LAYERS)}, sort_keys=True
    )
    return hashlib.blake2b(text.encode(), digest_size=8).hexdigest()


def cached_world(
    site_dir, *, utc: str, config: WorldConfig | None = None, names=None, progress: bool = False
) -> dict:
    """The layers ``names`` (default all) of a site's world model at ``utc``, built on
    first use into ``<cache>/worlds/<key>`` (see :func:`world_key`; ``cache`` as for
    sites, $LUNAR_DRAKE_CACHE) and read from there afterwards (range-checked)."""
    from lunar_drake.files import staged_directory
    from lunar_drake.site import cache_root

    cfg = config or WorldConfig()
    d = cache_root() / "worlds" / world_key(site_dir, utc=utc, config=cfg)
    if not (d / "world.json").is_file():
        d.parent.mkdir(parents=True, exist_ok=True)
        with staged_directory(d) as tmp:
            build_world(
                site_dir=site_dir, out_dir=tmp, utc=utc, config=cfg, png=False, progress=progress
            )
    return {n: read_world_layer(d, n) for n in (names or LAYERS)}


def site_layers(*, scenario, site, names, who: str, progress: bool = False) -> dict:
    """Layers ``names`` of a run's site at its epoch (the world model, built on first
    use and cached: :func:`cached_world`); ``who`` names the instrument in the error a
    site without a crater catalog raises."""
    directory = site.site.directory
    if directory is None or not (Path(directory) / "craters.csv").is_file():
        raise WorldModelError(
            f"{who} needs a synthesized site with a crater catalog; the site "
            f"{str(site.site.dem)!r} has none (set terrain to synthesize one)"
        )
    return cached_world(directory, utc=scenario.site.epoch_utc, config=scenario.science,
                        names=names, progress=progress)  # fmt: skip


def hydrogen_map(*, scenario, site, progress: bool = False):
    """The :class:`~lunar_drake.science.nss.HydrogenMap` of a run's site at its epoch."""
    from lunar_drake.science.nss import HydrogenMap

    layers = site_layers(scenario=scenario, site=site, who="sensors.nss", progress=progress,
                         names=("dry_layer_m", "ice_wt_pct", "h_minerals_ppm"))  # fmt: skip
    return HydrogenMap.centred(**layers, resolution_m=site.heightfield.resolution_m)


def surface_map(*, scenario, site, progress: bool = False):
    """The :class:`~lunar_drake.science.nirvss.SurfaceMap` of a run's site at its epoch."""
    from lunar_drake.science.nirvss import LAYERS as NIRVSS_LAYERS
    from lunar_drake.science.nirvss import SurfaceMap

    layers = site_layers(scenario=scenario, site=site, who="sensors.nirvss",
                         names=NIRVSS_LAYERS, progress=progress)  # fmt: skip
    return SurfaceMap.centred(layers, resolution_m=site.heightfield.resolution_m)


def read_world_layer(out_dir, name: str) -> np.ndarray:
    """One layer of a built world (checked against its physical range)."""
    from lunar_drake.terrain.geotiff import open_raster

    path = Path(out_dir) / f"{name}.tif"
    if name not in LAYERS:
        raise WorldModelError(f"layer {name!r} is unknown; layers are {tuple(LAYERS)}")
    if not path.is_file():
        raise RasterNotFoundError(f"world layer {str(path)!r} does not exist")
    with open_raster(path) as ds:
        a = ds.read()
    a = a[0] if a.shape[0] == 1 else a
    check_layer(name, a)
    return a


def heat_map(path, arr, *, name: str, resolution_m: float, z=None, max_px: int = 1024) -> None:
    """A PNG of a layer (first band of ``minerals``) over the hillshade, with a colour bar
    and site-metre axes; written atomically."""
    from matplotlib.figure import Figure

    from lunar_drake.files import atomic_path

    a = np.asarray(arr, np.float64)
    title = name
    if a.ndim == 3:
        a, title = a[0], f"{name}: {MINERALS[0]}"
    step = max(1, math.ceil(max(a.shape) / max_px))
    a = a[::step, ::step]
    rows, cols = a.shape
    ext = [
        -0.5 * cols * step * resolution_m,
        0.5 * cols * step * resolution_m,
        -0.5 * rows * step * resolution_m,
        0.5 * rows * step * resolution_m,
    ]
    unit, _, cmap = LAYERS[name]
    fig = Figure(figsize=(7.5, 6.2), dpi=110)
    ax = fig.add_subplot(1, 1, 1)
    if z is not None:
        ax.imshow(
            hillshade(np.asarray(z, np.float64)[::step, ::step], resolution_m * step),
            cmap="gray",
            extent=ext,
            vmin=0,
            vmax=1,
        )
    alpha = 0.75 if z is not None else 1.0
    im = ax.imshow(a, cmap=cmap, extent=ext, alpha=alpha, interpolation="nearest")
    fig.colorbar(im, ax=ax, label=unit, shrink=0.85)
    ax.set_xlabel("x (m, east)")
    ax.set_ylabel("y (m, north)")
    ax.set_title(title)
    with atomic_path(path, what="figure") as tmp:
        fig.savefig(tmp, format="png")


#: The panels of ``world.png``.
OVERVIEW_LAYERS = ("psr", "temperature_K", "dry_layer_m", "frost_area_frac", "ice_wt_pct", "oh_ppm")


def overview(
    path, layers: dict, *, resolution_m: float, z=None, title: str = "", max_px: int = 512
) -> None:
    """``world.png``: the six main layers side by side over the hillshade."""
    from matplotlib.figure import Figure

    from lunar_drake.files import atomic_path

    fig = Figure(figsize=(15, 9.6), dpi=90)
    for k, name in enumerate(OVERVIEW_LAYERS):
        a = np.asarray(layers[name], np.float64)
        step = max(1, math.ceil(max(a.shape) / max_px))
        a = a[::step, ::step]
        rows, cols = a.shape
        half_x, half_y = 0.5 * cols * step * resolution_m, 0.5 * rows * step * resolution_m
        ext = [-half_x, half_x, -half_y, half_y]
        ax = fig.add_subplot(2, 3, k + 1)
        if z is not None:
            zz = np.asarray(z, np.float64)[::step, ::step]
            ax.imshow(hillshade(zz, resolution_m * step), cmap="gray", extent=ext, vmin=0, vmax=1)
        unit, _, cmap = LAYERS[name]
        im = ax.imshow(
            a, cmap=cmap, extent=ext, alpha=0.75 if z is not None else 1.0, interpolation="nearest"
        )
        fig.colorbar(im, ax=ax, label=unit, shrink=0.8)
        ax.set_title(name)
        ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path, what="figure") as tmp:
        fig.savefig(tmp, format="png")


def hillshade(z: np.ndarray, res: float, az_deg: float = 315.0, el_deg: float = 35.0):
    """Shaded relief in [0, 1] of DEM ``z`` (pixel ``res`` m) lit from ``az_deg``, ``el_deg``."""
    n = thermal.surface_normals(z, res)
    return np.clip(np.tensordot(thermal.sun_vector(az_deg, el_deg), n, axes=1), 0.0, 1.0)


def _progress_bar(enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    bar = tqdm(total=100, desc="world model", unit="%", leave=False)
    state = {"n": 0}

    def update(stage, frac):
        if stage is None:
            bar.close()
            return
        n = round(100 * frac)
        bar.set_postfix_str(stage)
        bar.update(max(0, n - state["n"]))
        state["n"] = max(state["n"], n)

    return update


__all__ = [
    "LAYERS",
    "WORLD_FILES",
    "Craters",
    "World",
    "WorldModelError",
    "build_world",
    "cached_world",
    "check_layer",
    "compute_world",
    "default_utc",
    "heat_map",
    "hillshade",
    "hydrogen_map",
    "overview",
    "read_craters",
    "read_world_layer",
    "surface_map",
    "world_key",
    "write_named_bands",
    "write_world",
]
