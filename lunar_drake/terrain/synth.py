"""The synthetic-site pipeline (paper section 4), tile by tile.

Steps, each a pure function in its own module:

1. coarse DEM: a source DEM (``from_dem``) or a coarse fractal surface
   (:func:`fractal.coarse_fractal`), split into low and high frequencies;
2. crater and rock catalogs (:func:`catalog.synthesize_catalogs`), with ages, an
   ejecta map and burial;
3. per tile, pass 1: low-frequency upscale + craters stamped on fitted planes +
   diamond-square high-frequency detail -> the pre-rock DEM (a memory-mapped scratch
   grid on disk, so memory stays bounded);
4. per tile, pass 2 (with a 1-pixel halo): rocks from the rock library, rock mask,
   albedo with crater splashes, normals; written by rasterio windows.

Every per-pixel step is keyed by global pixel indices, so the bytes written do not
depend on the tile size or the number of workers (tests pin this). Tiles run on dask's
threaded scheduler (numpy releases the GIL).
"""

from __future__ import annotations

import contextlib
import dataclasses as dc
import hashlib
import json
import os
import shutil
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import dask
import numpy as np

from lunar_drake import rng
from lunar_drake.errors import ConfigError, NoDataError, OutOfRangeError, OutputError
from lunar_drake.files import atomic_path, staged_directory
from lunar_drake.terrain import albedo as albedo_mod
from lunar_drake.terrain import catalog as catalog_mod
from lunar_drake.terrain import craters as craters_mod
from lunar_drake.terrain import fractal, rock_library, surface
from lunar_drake.terrain.crs import (
    lonlat_to_xy,
    moon_north_polar_stereographic,
    moon_south_polar_stereographic,
)
from lunar_drake.terrain.geotiff import GeoTiffWriter
from lunar_drake.terrain.grid import GridSpec
from lunar_drake.terrain.sfd import CraterSFD, RockSFD

PIPELINE_VERSION = 1
NORMAL_SCALE = 32767.0

OUTPUT_FILES = (
    "dem.tif",
    "albedo.tif",
    "rock_mask.tif",
    "normals.tif",
    "craters.csv",
    "rocks.csv",
    "site.json",
    "overview.png",
)


@dc.dataclass(frozen=True)
class SynthConfig:
    """Everything that determines a synthetic site's bytes, plus how to compute it.

    Attributes:
        size_px: site side (pixels) when synthesizing from scratch.
        resolution_m: pixel size (m) when synthesizing from scratch.
        factor: fractal upscaling factor (power of two).
        seed: random seed.
        crater_sfd: crater size-frequency law.
        min_crater_m, max_crater_m: crater diameter range (m); ``None`` = automatic.
        rock_abundance: Golombek-Rapp k of background rocks (cumulative fractional area);
            0 for none.
        ejecta_rock_abundance: Golombek-Rapp k of ejecta rocks on the rim of a fresh
            ejecta crater (the density elsewhere follows the ejecta map); 0 for none.
        min_rock_m: smallest rock diameter (m).
        from_dem: path of a source DEM to upscale by ``factor``; ``None`` to synthesize.
        existing_craters: (x_m, y_m, diameter_m) of craters already in ``from_dem``.
        fractal, crater_shape, albedo: parameters of those steps.
        center_lat_deg, center_lon_deg: where a synthesized site's centre lies on the IAU
            Moon sphere (deg); it sets the georeferencing (south- or north-polar
            stereographic by hemisphere). Ignored with ``from_dem``.
        tile_px, workers: how to compute; never change the result.
    """

    size_px: int = 1024
    resolution_m: float = 0.1
    factor: int = 32
    seed: int = 0
    crater_sfd: CraterSFD = dc.field(default_factory=CraterSFD)
    min_crater_m: float = 0.5
    max_crater_m: float | None = None
    rock_abundance: float = 0.005
    ejecta_rock_abundance: float = 0.1
    min_rock_m: float = 0.1
    from_dem: str | None = None
    existing_craters: tuple[tuple[float, float, float], ...] = ()
    fractal: fractal.FractalParams = dc.field(default_factory=fractal.FractalParams)
    crater_shape: craters_mod.CraterShapeParams = dc.field(
        default_factory=craters_mod.CraterShapeParams
    )
    albedo: albedo_mod.AlbedoParams = dc.field(default_factory=albedo_mod.AlbedoParams)
    center_lat_deg: float = -90.0
    center_lon_deg: float = 0.0
    tile_px: int = 1024
    workers: int = 2

    def __post_init__(self):
        if not -90.0 <= self.center_lat_deg <= 90.0 or self.center_lat_deg == 0.0:
            raise OutOfRangeError(
                f"center_lat_deg = {self.center_lat_deg!r}; allowed [-90, 0) or (0, 90] "
                "(polar stereographic sites)"
            )
        if not -360.0 <= self.center_lon_deg <= 360.0:
            raise OutOfRangeError(f"center_lon_deg = {self.center_lon_deg!r}; allowed [-360, 360]")
        if self.factor < 1 or self.factor & (self.factor - 1):
            raise ConfigError(f"factor = {self.factor!r} must be a power of two (1, 2, 4, ...)")
        if self.from_dem is None:
            if not 16 <= self.size_px <= 65536:
                raise OutOfRangeError(f"size_px = {self.size_px!r}; allowed [16, 65536]")
            if self.size_px % self.factor:
                raise ConfigError(
                    f"size_px = {self.size_px} must be a multiple of factor = {self.factor}"
                )
            if not self.resolution_m > 0:
                raise OutOfRangeError(f"resolution_m = {self.resolution_m!r} must be > 0 m")
        if not 16 <= self.tile_px <= 16384:
            raise OutOfRangeError(f"tile_px = {self.tile_px!r}; allowed [16, 16384]")
        if not 1 <= self.workers <= 256:
            raise OutOfRangeError(f"workers = {self.workers!r}; allowed [1, 256]")
        if not self.min_crater_m > 0:
            raise OutOfRangeError(f"min_crater_m = {self.min_crater_m!r} must be > 0 m")
        if self.max_crater_m is not None and not self.max_crater_m > self.min_crater_m:
            raise OutOfRangeError(
                f"max_crater_m = {self.max_crater_m!r} must exceed min_crater_m = "
                f"{self.min_crater_m!r}"
            )
        if not 0 <= self.rock_abundance < 1:
            raise OutOfRangeError(f"rock_abundance = {self.rock_abundance!r}; allowed [0, 1)")
        if not 0 <= self.ejecta_rock_abundance < 1:
            raise OutOfRangeError(
                f"ejecta_rock_abundance = {self.ejecta_rock_abundance!r}; allowed [0, 1)"
            )
        if not self.min_rock_m > 0:
            raise OutOfRangeError(f"min_rock_m = {self.min_rock_m!r} must be > 0 m")

    def content_key(self) -> str:
        """Hash of everything that determines the output bytes (not tile_px/workers)."""
        d = dc.asdict(self)
        d.pop("tile_px")
        d.pop("workers")
        if self.from_dem:
            p = Path(self.from_dem)
            d["from_dem_stat"] = [str(p.resolve()), p.stat().st_size, p.stat().st_mtime_ns]
        d["pipeline_version"] = PIPELINE_VERSION
        blob = json.dumps(d, sort_keys=True, default=repr).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


@dc.dataclass
class SiteProducts:
    """What :func:`synthesize_site` made: paths, catalogs and figures."""

    out_dir: Path
    grid: GridSpec
    craters: catalog_mod.CraterCatalog
    rocks: catalog_mod.RockCatalog
    stats: dict

    def path(self, name: str) -> Path:
        return self.out_dir / name


def _coarse_dem(config: SynthConfig):
    """Coarse DEM (float64), its resolution (m), CRS and CRS centre of the site."""
    if config.from_dem:
        from lunar_drake.terrain.heightfield import Heightfield

        hf = Heightfield.open(config.from_dem)
        rows, cols = hf.shape
        coarse = hf.read_window(0, 0, rows, cols).astype(np.float64)
        bad = np.isnan(coarse)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise NoDataError(
                f"{config.from_dem!r} has {int(bad.sum())} nodata cells (first at row {r}, "
                f"col {c}); fill the holes before upscaling (all cells must be valid)"
            )
        # Point-registered upscaling: fine pixel 0 is centred on coarse pixel 0, so the
        # fine raster's centre sits half a coarse pixel minus half a fine pixel east/south.
        shift = 0.5 * hf.resolution_m * (1.0 - 1.0 / config.factor)
        ox, oy = hf.origin_xy
        return coarse, hf.resolution_m, hf.crs, (ox + shift, oy - shift)
    n = config.size_px // config.factor
    coarse_res = config.resolution_m * config.factor
    coarse = fractal.coarse_fractal(
        (n, n),
        resolution_m=coarse_res,
        rng=rng.generator(config.seed, "terrain/coarse"),
        params=config.fractal,
    )
    if config.center_lat_deg < 0:
        crs = moon_south_polar_stereographic()
    else:
        crs = moon_north_polar_stereographic()
    x, y = lonlat_to_xy(config.center_lon_deg, config.center_lat_deg, crs=crs)
    return coarse, coarse_res, crs, (float(x), float(y))


def _in_box(cat, reach: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices (in catalog order) of entries whose reach overlaps the pixel-centre box."""
    return np.flatnonzero(
        (cat.x_m + reach >= x[0])
        & (cat.x_m - reach <= x[-1])
        & (cat.y_m + reach >= y[-1])
        & (cat.y_m - reach <= y[0])
    )


def _tiles(nrows: int, ncols: int, tile: int):
    for r0 in range(0, nrows, tile):
        for c0 in range(0, ncols, tile):
            yield r0, c0, min(tile, nrows - r0), min(tile, ncols - c0)


def _run_tasks(tasks, *, workers: int, desc: str, progress: bool):
    """Runs dask delayed tasks on the threaded scheduler with a tqdm bar.

    The tasks run on a thread pool of their own that is shut down before this returns or
    raises: after an error or a Ctrl-C (``KeyboardInterrupt`` in the main thread) the
    running tiles finish and the queued ones are dropped, so no worker still writes
    when the caller closes the GeoTIFF writers and removes the partial site.
    """
    pool = ThreadPoolExecutor(workers, thread_name_prefix="lunar-drake-synth")
    bar = None
    try:
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=len(tasks), desc=desc, unit="tile", leave=False)

            class _Bar(dask.callbacks.Callback):
                def _posttask(self, key, result, dsk, state, id):
                    if isinstance(key, tuple) and str(key[0]).startswith("tile-"):
                        bar.update(1)
                    elif isinstance(key, str) and key.startswith("tile-"):
                        bar.update(1)

            with _Bar():
                dask.compute(*tasks, scheduler="threads", pool=pool)
        else:
            dask.compute(*tasks, scheduler="threads", pool=pool)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if bar is not None:
            bar.close()


_LEFTOVER_PREFIXES = (".synth-",)


def _check_site_dir(out_dir: Path) -> None:
    """A site directory is replaced as a whole on success, so an existing ``out_dir``
    may hold only site outputs (a previous site) and leftovers of interrupted builds;
    anything else (``--out .``, a data folder) is refused before any work starts."""
    if not out_dir.is_dir():
        return
    allowed = set(OUTPUT_FILES) | {f"{f}.aux.xml" for f in OUTPUT_FILES}
    try:
        names = os.listdir(out_dir)
    except OSError as exc:
        raise OutputError(
            f"cannot write site directory {str(out_dir)!r}: {exc.strerror or exc}"
        ) from None
    foreign = sorted(
        n
        for n in names
        if n not in allowed
        and not (n.startswith(_LEFTOVER_PREFIXES) or (n.startswith(".") and ".tmp" in n))
    )
    if foreign:
        shown = ", ".join(repr(n) for n in foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        raise OutputError(
            f"cannot write site directory {str(out_dir)!r}: it exists and holds "
            f"{len(foreign)} {'entry that is' if len(foreign) == 1 else 'entries that are'} "
            f"not a site output ({shown}); a site directory "
            "is replaced as a whole, so give a new or empty directory"
        )


def synthesize_site(
    *, config: SynthConfig, out_dir: str | Path, progress: bool = True, overview: bool = True
) -> SiteProducts:
    """Builds a synthetic site into ``out_dir`` (parents created if needed).

    Writes dem.tif (float32 m), albedo.tif (float32, normal albedo), rock_mask.tif
    (uint8), normals.tif (3 x int16, unit normal x/y/z times 32767, site frame),
    craters.csv, rocks.csv, site.json and overview.png (unless ``overview`` is False).

    The site is built in a temporary sibling directory and renamed to ``out_dir`` only
    when every file is written: a failed or interrupted (Ctrl-C) synthesis leaves no
    ``out_dir`` and no temporary files, and an existing ``out_dir`` untouched; a
    successful one replaces an existing ``out_dir`` as a whole.

    Raises:
        OutputError: before any work, if ``out_dir`` cannot be written (a parent is a
            file, no permission, ...) or exists holding files that are not site outputs.
    """
    t_start = time.perf_counter()
    out_dir = Path(out_dir)
    _check_site_dir(out_dir)
    # "--out ." or "..": stage beside the directory's real name.
    target = Path(os.path.abspath(out_dir)) if out_dir.name in ("", "..") else out_dir
    with staged_directory(target, what="site directory") as stage:
        products = _synthesize_into(
            stage, config=config, progress=progress, overview=overview, t_start=t_start
        )
    products.out_dir = out_dir
    products.stats["timing_s"]["total"] = time.perf_counter() - t_start
    return products


def _synthesize_into(
    out_dir: Path, *, config: SynthConfig, progress: bool, overview: bool, t_start: float
) -> SiteProducts:
    """The pipeline of :func:`synthesize_site`, writing into the staging ``out_dir``."""
    import dask.callbacks

    coarse, coarse_res, crs, origin = _coarse_dem(config)
    F = config.factor
    res = coarse_res / F
    nrows, ncols = coarse.shape[0] * F, coarse.shape[1] * F
    grid = GridSpec(nrows, ncols, res)
    low, high = fractal.split_frequencies(coarse, params=config.fractal)

    # Catalogs (site level, sequential rng streams).
    cat_params = catalog_mod.CatalogParams(
        crater_sfd=config.crater_sfd,
        d_min_m=config.min_crater_m,
        d_max_m=config.max_crater_m,
        rock_sfd_background=RockSFD(law="golombek_rapp", k=config.rock_abundance)
        if config.rock_abundance > 0
        else None,
        rock_sfd_ejecta=RockSFD(law="golombek_rapp", k=config.ejecta_rock_abundance)
        if config.ejecta_rock_abundance > 0
        else None,
        rock_d_min_m=config.min_rock_m,
        existing_craters=config.existing_craters,
    )
    craters, rocks, _ejecta = catalog_mod.synthesize_catalogs(
        grid=grid, seed=config.seed, params=cat_params
    )
    t_catalog = time.perf_counter()

    # Crater planes from the smooth low-frequency surface (tile independent).
    def low_surface_xy(x, y):
        r, c = grid.to_pixel(x, y)
        return fractal.low_surface_at(
            low, factor=F, rows=r, cols=c, method=config.fractal.low_interpolation
        )

    shape = config.crater_shape
    planes = craters_mod.crater_planes(
        low_surface_xy,
        x_m=craters.x_m,
        y_m=craters.y_m,
        diameter_m=craters.diameter_m,
        params=shape,
    )
    library = rock_library.make_rock_library(seed=config.seed)
    key_high = rng.stream_key(config.seed, "terrain/high")
    key_albedo = rng.stream_key(config.seed, "terrain/albedo")

    # How far (m) each object reaches from its centre, for selecting it per tile.
    crater_reach = craters_mod.crater_extent_m(craters.diameter_m, params=shape) + res
    splash_reach = (
        albedo_mod.splash_extent_m(
            craters.diameter_m, params=config.albedo, freshness=craters.freshness
        )
        + res
    )
    rock_reach = 0.75 * rocks.diameter_m + 2.0 * res

    scratch_dir = Path(tempfile.mkdtemp(prefix=".synth-", dir=out_dir))
    try:
        prerock = np.lib.format.open_memmap(
            scratch_dir / "prerock.npy", mode="w+", dtype=np.float32, shape=(nrows, ncols)
        )

        def pass1(r0, c0, h, w):
            x, y = grid.pixel_centers(r0, c0, h, w)
            z = fractal.upscale_low(
                low, factor=F, window=(r0, c0, h, w), method=config.fractal.low_interpolation
            )
            sel = _in_box(craters, crater_reach, x, y)
            craters_mod.stamp_craters(
                z,
                x=x,
                y=y,
                craters_x=craters.x_m[sel],
                craters_y=craters.y_m[sel],
                diameters=craters.diameter_m[sel],
                freshness=craters.freshness[sel],
                planes=planes[sel],
                params=shape,
            )
            z += fractal.upscale_high(
                high,
                factor=F,
                window=(r0, c0, h, w),
                key=key_high,
                params=config.fractal,
                coarse_resolution_m=coarse_res,
            )
            prerock[r0 : r0 + h, c0 : c0 + w] = z

        tasks = [
            dask.delayed(pass1, pure=False)(*t, dask_key_name=f"tile-1-{t[0]}-{t[1]}")
            for t in _tiles(nrows, ncols, config.tile_px)
        ]
        _run_tasks(tasks, workers=config.workers, desc="terrain", progress=progress)
        prerock.flush()
        t_pass1 = time.perf_counter()

        # Rock seats: the pre-rock surface at the pixel nearest each rock centre.
        rr, cc = grid.to_pixel(rocks.x_m, rocks.y_m)
        rr = np.clip(np.rint(rr).astype(np.int64), 0, nrows - 1)
        cc = np.clip(np.rint(cc).astype(np.int64), 0, ncols - 1)
        base_z = np.asarray(prerock[rr, cc], dtype=np.float32) if len(rocks) else np.zeros(0)

        transform = _transform(grid, origin)
        writers = {
            "dem": GeoTiffWriter(
                out_dir / "dem.tif",
                height=nrows,
                width=ncols,
                count=1,
                dtype="float32",
                transform=transform,
                crs=crs,
                nodata=np.nan,
            ),
            "albedo": GeoTiffWriter(
                out_dir / "albedo.tif",
                height=nrows,
                width=ncols,
                count=1,
                dtype="float32",
                transform=transform,
                crs=crs,
            ),
            "mask": GeoTiffWriter(
                out_dir / "rock_mask.tif",
                height=nrows,
                width=ncols,
                count=1,
                dtype="uint8",
                transform=transform,
                crs=crs,
            ),
            "normals": GeoTiffWriter(
                out_dir / "normals.tif",
                height=nrows,
                width=ncols,
                count=3,
                dtype="int16",
                transform=transform,
                crs=crs,
            ),
        }
        stats_lock = __import__("threading").Lock()
        zrange = [np.inf, -np.inf]
        rock_px = [0]

        def pass2(r0, c0, h, w):
            # Window with a 1-pixel halo, clamped at the site edge (edge rows repeat).
            ra, rb = max(r0 - 1, 0), min(r0 + h + 1, nrows)
            ca, cb = max(c0 - 1, 0), min(c0 + w + 1, ncols)
            z = np.array(prerock[ra:rb, ca:cb], dtype=np.float32)
            mask = np.zeros(z.shape, dtype=np.uint8)
            x, y = grid.pixel_centers(ra, ca, rb - ra, cb - ca)
            sel = _in_box(rocks, rock_reach, x, y)
            rock_library.stamp_rocks(
                z,
                mask,
                x=x,
                y=y,
                rocks_x=rocks.x_m[sel],
                rocks_y=rocks.y_m[sel],
                diameters=rocks.diameter_m[sel],
                heights=rocks.height_m[sel],
                shape_index=rocks.shape_index[sel],
                base_z=base_z[sel],
                library=library,
                resolution_m=res,
                rock_ids=sel,
            )
            zh = np.pad(
                z,
                ((int(r0 == ra), int(rb == r0 + h)), (int(c0 == ca), int(cb == c0 + w))),
                mode="edge",
            )
            inner = (slice(r0 - ra, r0 - ra + h), slice(c0 - ca, c0 - ca + w))
            zt = z[inner]
            mt = mask[inner]
            xt, yt = x[inner[1]], y[inner[0]]
            csel = _in_box(craters, splash_reach, xt, yt)
            alb = albedo_mod.albedo_tile(
                x=xt,
                y=yt,
                row0=r0,
                col0=c0,
                key=key_albedo,
                craters_x=craters.x_m[csel],
                craters_y=craters.y_m[csel],
                diameters=craters.diameter_m[csel],
                freshness=craters.freshness[csel],
                rock_mask=mt,
                params=config.albedo,
            )
            nrm = surface.normals_from_dem(zh, resolution_m=res)
            nrm16 = np.rint(nrm * NORMAL_SCALE).astype(np.int16)
            writers["dem"].write(zt, row0=r0, col0=c0)
            writers["albedo"].write(alb, row0=r0, col0=c0)
            writers["mask"].write(mt, row0=r0, col0=c0)
            writers["normals"].write(nrm16, row0=r0, col0=c0)
            with stats_lock:
                zrange[0] = min(zrange[0], float(zt.min()))
                zrange[1] = max(zrange[1], float(zt.max()))
                rock_px[0] += int(mt.sum(dtype=np.int64))

        # Every writer is closed (committed on success, removed on an error) even when
        # another one fails; the first error is the one raised.
        with contextlib.ExitStack() as stack:
            for wtr in writers.values():
                stack.enter_context(wtr)
            tasks = [
                dask.delayed(pass2, pure=False)(*t, dask_key_name=f"tile-2-{t[0]}-{t[1]}")
                for t in _tiles(nrows, ncols, config.tile_px)
            ]
            _run_tasks(tasks, workers=config.workers, desc="rocks+albedo", progress=progress)
        t_pass2 = time.perf_counter()
    finally:
        shutil.rmtree(scratch_dir, ignore_errors=True)

    depth = craters_mod.depth_ratio(craters.freshness, params=shape) * craters.diameter_m
    craters.to_csv(out_dir / "craters.csv", depth_m=depth)
    rocks.to_csv(out_dir / "rocks.csv")
    stats = {
        "size_px": [nrows, ncols],
        "resolution_m": res,
        "extent_m": [grid.width_m, grid.height_m],
        "craters": len(craters),
        "rocks": len(rocks),
        "ejecta_rocks": int(np.sum(rocks.population == 1)),
        "rock_pixels": rock_px[0],
        "z_min_m": zrange[0],
        "z_max_m": zrange[1],
        "content_key": config.content_key(),
    }
    _write_json(out_dir / "site.json", {"config": _config_json(config), "stats": stats})
    products = SiteProducts(out_dir=out_dir, grid=grid, craters=craters, rocks=rocks, stats=stats)
    if overview:
        from lunar_drake.terrain.overview import write_overview

        write_overview(products, config=config, path=out_dir / "overview.png")
    t_end = time.perf_counter()
    products.stats["timing_s"] = {
        "catalog": t_catalog - t_start,
        "pass1": t_pass1 - t_catalog,
        "pass2": t_pass2 - t_pass1,
        "total": t_end - t_start,
    }
    return products


def _transform(grid: GridSpec, origin):
    from rasterio.transform import Affine

    return Affine(
        grid.resolution_m,
        0.0,
        origin[0] + grid.x_min,
        0.0,
        -grid.resolution_m,
        origin[1] + grid.y_max,
    )


def _config_json(config: SynthConfig) -> dict:
    """The config as JSON, without tile_px/workers (they never change the bytes)."""
    d = dc.asdict(config)
    d.pop("tile_px")
    d.pop("workers")
    return json.loads(json.dumps(d, default=repr))


def _write_json(path: Path, data) -> None:
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        json.dump(data, f, indent=2, sort_keys=True)
        f.write("\n")
