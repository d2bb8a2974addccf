"""What the mission has before launch, made from the site outside the flight and ground
software and handed to them when the mission diagram is built.

* the ground's a-priori map (:func:`ground_map_product`): by default the orbital product
  (:mod:`lunar_drake.autonomy.map_product`), the true DEM only when the scenario asks for
  the oracle (``ground.map.source: truth``);
* the flight's slip calibration (:func:`slip_calibration`): from the pre-flight soil the
  scenario names (``flight.estimator.slip_calibration``), never the plant's.

:func:`describe` gives both for ``summary.json``.
"""

from __future__ import annotations

from lunar_drake.scenario import Scenario

#: Sites up to this many pixels get a map of the whole site; larger ones a window round
#: the spawn point and the goals.
WHOLE_SITE_MAX_PX = 4096**2


def map_points(scenario: Scenario, site) -> list:
    """Site points (m) the ground's map must cover: the whole site when it has at most
    :data:`WHOLE_SITE_MAX_PX` pixels, else the spawn point, the goals and the scheduled
    goal actions (``ground.map.margin_m`` is added round them)."""
    g = scenario.ground
    hf = site.heightfield
    if hf.shape[0] * hf.shape[1] <= WHOLE_SITE_MAX_PX:
        b = hf.bounds
        return [(b.left, b.bottom), (b.right, b.top)]
    points = [(scenario.rover.spawn_x_m, scenario.rover.spawn_y_m)]
    points += [(p.x_m, p.y_m) for p in g.goals]
    points += [(a.x_m, a.y_m) for a in g.actions if a.action == "goal"]
    return points


def rock_mask_reader(site):
    """``read(row0, col0, rows, cols) -> bool array`` of the site's rock mask
    (``rock_mask.tif`` of a synthesized site), or None when the site has none."""
    directory = getattr(getattr(site, "site", None), "directory", None)
    if directory is None or not (directory / "rock_mask.tif").is_file():
        return None
    from lunar_drake.terrain.geotiff import read_window

    path = directory / "rock_mask.tif"

    def read(row0, col0, rows, cols):
        return read_window(path, row0=row0, col0=col0, nrows=rows, ncols=cols) > 0

    return read


def ground_map_product(scenario: Scenario, site):
    """The ground's a-priori map (:class:`~lunar_drake.autonomy.map_product.MapProduct`)
    for ``scenario`` on ``site``: ``ground.map`` over :func:`map_points`, the orbital
    noise seeded by the site's seed."""
    from lunar_drake.autonomy.map_product import make_map_product

    return make_map_product(
        heightfield=site.heightfield, points_xy=map_points(scenario, site),
        map_config=scenario.ground.map, seed=scenario.site.seed,
        rock_mask=rock_mask_reader(site),
    )  # fmt: skip


def slip_calibration(scenario: Scenario):
    """The flight's slip calibration (:class:`~lunar_drake.autonomy.slip_calibration.
    SlipCalibration`), or None when the scenario writes its table by hand."""
    from lunar_drake.autonomy.slip_calibration import calibrated_estimator

    _, cal = calibrated_estimator(scenario.flight.estimator,
                                  description=scenario.rover.description)  # fmt: skip
    return cal


def describe(scenario: Scenario, *, map_product=None) -> dict:
    """``summary.json``'s account of the pre-flight products: the ground's map (source,
    resolution, noise, rocks removed; ``oracle`` true for the true DEM) and the flight's
    slip calibration (soil, whether it is the plant's, the table)."""
    out: dict = {}
    if map_product is not None:
        out["ground_map"] = map_product.describe()
    cal = slip_calibration(scenario)
    if cal is None:
        e = scenario.flight.estimator
        out["slip_calibration"] = {
            "slip_calibration": None,
            "note": "written by hand in flight.estimator (slip_prior, slip_vs_slope)",
            "slip_prior": e.slip_prior,
            "slip_vs_slope": [list(r) for r in e.slip_vs_slope],
        }
    else:
        out["slip_calibration"] = cal.describe(plant_soil=scenario.soil)
    return out
