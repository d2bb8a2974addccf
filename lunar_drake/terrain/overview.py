"""overview.png for a synthesized site: hillshade with craters and rocks, and the
catalog's crater SFD against the model.

Drawn with matplotlib's object-oriented API (a :class:`matplotlib.figure.Figure`, no
pyplot, no ``matplotlib.use``), so it never changes the backend of the caller (a
notebook keeps its inline plots).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lunar_drake.files import atomic_path


def write_overview(products, *, config, path: str | Path, max_px: int = 1024) -> Path:
    """Writes the two-panel overview figure atomically and returns its path."""
    import rasterio
    from matplotlib.collections import PatchCollection
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    from lunar_drake.terrain import sfd as sfd_mod
    from lunar_drake.terrain.surface import hillshade

    path = Path(path)
    grid = products.grid
    step = max(1, int(np.ceil(max(grid.nrows, grid.ncols) / max_px)))
    with rasterio.open(products.path("dem.tif")) as ds:
        out_shape = (max(1, grid.nrows // step), max(1, grid.ncols // step))
        z = ds.read(1, out_shape=out_shape, resampling=rasterio.enums.Resampling.average)
    res = grid.resolution_m * grid.nrows / z.shape[0]
    shade = hillshade(z.astype(np.float32), resolution_m=res, azimuth_deg=135.0, altitude_deg=15.0)

    fig = Figure(figsize=(15, 7))
    ax0, ax1 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.1, 1]})
    ext = (grid.x_min, grid.x_min + grid.width_m, grid.y_max - grid.height_m, grid.y_max)
    ax0.imshow(shade, cmap="gray", extent=ext, origin="upper", vmin=0, vmax=1)
    cr = products.craters
    big = cr.diameter_m >= max(4 * res, float(np.percentile(cr.diameter_m, 90)) if len(cr) else 0)
    circles = [
        Circle((x, y), d / 2)
        for x, y, d in zip(cr.x_m[big], cr.y_m[big], cr.diameter_m[big], strict=False)
    ]
    ax0.add_collection(
        PatchCollection(circles, facecolor="none", edgecolor="tab:green", linewidth=0.6, alpha=0.8)
    )
    rk = products.rocks
    for pop, color, label in ((0, "tab:blue", "background rocks"), (1, "tab:red", "ejecta rocks")):
        m = rk.population == pop
        ax0.scatter(
            rk.x_m[m],
            rk.y_m[m],
            s=np.clip(rk.diameter_m[m] * 8, 0.2, 20),
            c=color,
            linewidths=0,
            label=f"{label} ({int(m.sum())})",
        )
    ax0.set_xlim(ext[0], ext[1])
    ax0.set_ylim(ext[2], ext[3])
    ax0.set_xlabel("x east (m)")
    ax0.set_ylabel("y north (m)")
    ax0.set_title(
        f"{grid.nrows}x{grid.ncols} px at {grid.resolution_m:g} m; "
        f"{len(cr)} craters (green: largest 10%), {len(rk)} rocks"
    )
    ax0.legend(loc="lower right", fontsize=8, markerscale=3)

    d = np.sort(cr.diameter_m)[::-1]
    if len(d):
        ax1.loglog(d, np.arange(1, len(d) + 1), "k.", ms=2, label="catalog N(>=D)")
        dd = np.geomspace(d.min(), d.max(), 100)
        # The catalog is truncated at its largest diameter d_max: N(>=D) - N(>=d_max).
        n = sfd_mod.cumulative_density(np.append(dd, d.max()), sfd=config.crater_sfd)
        model = n[:-1] - n[-1] + 1.0 / grid.area_m2
        ax1.loglog(dd, model * grid.area_m2, "r-", label=f"model: {config.crater_sfd.law}")
    ax1.set_xlabel("crater diameter D (m)")
    ax1.set_ylabel("cumulative count N(>=D) in site")
    ax1.set_title("crater size-frequency distribution")
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend()
    fig.tight_layout()
    with atomic_path(path, what="overview figure") as tmp:
        fig.savefig(tmp, dpi=110)
    return path
