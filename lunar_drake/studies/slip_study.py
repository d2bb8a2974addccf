"""Slip versus slope (paper section 6, Figs. 22-24), against an independent reference.

For each rover, slope and seed: a ramp z = x tan(slope) (site frame; planar, or with
seeded fractal roughness, ``roughness_m``), the rover spawned at its base heading
upslope (seed: a small lateral offset and heading error, and the roughness), wheels
driven at a constant commanded speed after a settling pause. Slip over the steady part
of the climb (from 10% of the distance to the end) is

    slip = 1 - ground-truth distance / dead-reckoned distance,

with the ground-truth distance signed along the rover's heading (sliding back gives
slip > 1) and the dead-reckoned distance = mean wheel-encoder angle change x wheel
radius.

``reference_slip`` is the steady-state slip of a rigid rover whose wheels, each at its
own equilibrium sinkage, pull exactly the downslope weight
(:func:`lunar_drake.dynamics.wheel_reference.reference_slip`: the same Wong-Reece wheel
as the simulation, written separately with adaptive quadrature and root finding, so
agreement with it tests the dynamic simulation). It is fed with the static normal
wheel loads on the slope, read with the rover at rest and braked on the ramp during
the settling pause (the front-to-rear load transfer of the suspension included; at
rest the braking force equals the traction of a steady climb); level-ground loads are
recorded too. params.json holds both, with the soil and wheel, so anyone can recompute
it. Where no slip below 0.99 balances the weight, the reference says the rover cannot
climb: ``reference_slip`` is 1 (wheels spin out) and ``immobilized`` is true; the
simulated rover then slides back (slip > 1) or stalls.
"""

from __future__ import annotations

import dataclasses as dc
import json
import math
from pathlib import Path

import numpy as np

from lunar_drake import rng
from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics.soil_io import load_soil
from lunar_drake.errors import ConfigError, OutOfRangeError, SimulationError
from lunar_drake.files import atomic_path, atomic_write_text, ensure_output_dir
from lunar_drake.systems.wheel_regolith_contact import WHEEL_STATE_FIELDS

RAMP_START_M = 8.0
"""Distance (m) from the ramp's downslope edge to the spawn point."""
SLIDE_BACK_STOP_M = 2.0
"""A run stops once the rover has slid this far (m) back down the ramp."""

ROVER_CHOICES = {"skid": "husky_rp", "explicit": "krex2_rp"}
CSV_COLUMNS = (
    "rover",
    "slope_deg",
    "seed",
    "slip",
    "reference_slip",
    "immobilized",
    "sinkage_m",
    "energy_J",
    "distance_m",
    "time_s",
    "stop",
)


@dc.dataclass(frozen=True)
class SlipCase:
    """One run. ``rover`` is skid/explicit or a preset name; speeds in m/s."""

    rover: str
    slope_deg: float
    seed: int
    distance_m: float = 5.0
    speed_mps: float = 0.1
    soil: str = "lunar_regolith"
    time_step_s: float = 0.01
    settle_s: float = 2.0
    roughness_m: float = 0.0

    def __post_init__(self):
        if self.rover not in (*ROVER_CHOICES, *ROVER_CHOICES.values()):
            raise ConfigError(
                f"rover = {self.rover!r} is unknown; choose one of {sorted(ROVER_CHOICES)}"
            )
        if not 0.0 <= self.slope_deg <= 40.0:
            raise OutOfRangeError(f"slope_deg = {self.slope_deg!r}; allowed [0, 40] deg")
        if not 0.2 <= self.distance_m <= 1000.0:
            raise OutOfRangeError(f"distance_m = {self.distance_m!r}; allowed [0.2, 1000] m")
        if not 0.01 <= self.speed_mps <= 2.0:
            raise OutOfRangeError(f"speed_mps = {self.speed_mps!r}; allowed [0.01, 2] m/s")
        load_soil(self.soil)  # a preset name or a soil YAML file; raises ConfigError
        if not 0.0 <= self.roughness_m <= 0.2:
            raise OutOfRangeError(f"roughness_m = {self.roughness_m!r}; allowed [0, 0.2] m")


def _description(rover: str):
    from lunar_drake.models.rover_description import rover_preset

    return rover_preset(ROVER_CHOICES.get(rover, rover))


ROUGHNESS_HURST = 0.8
"""Hurst exponent of the ramp roughness (lunar terrain: ~0.7-0.95, Rosenburg et al. 2011)."""


def ramp_heightfield(
    *,
    slope_deg: float,
    length_m: float,
    width_m: float = 8.0,
    resolution_m: float = 0.05,
    roughness_m: float = 0.0,
    seed: int = 0,
):
    """A planar ramp z = x tan(slope) (site frame), ``length_m`` + 14 m long: the rover
    starts :data:`RAMP_START_M` inside the west (downslope) edge.

    ``roughness_m`` > 0 adds a seeded fractal surface (fBm, Hurst
    :data:`ROUGHNESS_HURST`, spectral synthesis by
    :func:`~lunar_drake.terrain.fractal.coarse_fractal`) whose RMS height deviation at a
    1 m baseline is ``roughness_m`` (Shepard et al. 2001's definition, the one the site
    synthesis uses): seeds then differ the way test lanes do.
    """
    from lunar_drake.terrain.heightfield import Heightfield

    nc = math.ceil((length_m + RAMP_START_M + 6.0) / resolution_m)
    nr = math.ceil(width_m / resolution_m)
    x = (np.arange(nc) + 0.5 - 0.5 * nc) * resolution_m
    z = np.tile(x * math.tan(math.radians(slope_deg)), (nr, 1))
    if roughness_m > 0.0:
        from lunar_drake.terrain.fractal import FractalParams, coarse_fractal

        params = FractalParams(hurst=ROUGHNESS_HURST, rms_deviation_m=roughness_m)
        g = rng.generator(seed, "slip_study/roughness")
        z = z + coarse_fractal((nr, nc), resolution_m=resolution_m, rng=g, params=params)
    return Heightfield.from_array(z.astype(np.float32), resolution_m=resolution_m)


def reference_for(case: SlipCase, *, wheel_loads_N, wheel, soil) -> tuple[float, bool]:
    """(reference slip, immobilized) for a case, from the independent steady-state wheel
    (:func:`lunar_drake.dynamics.wheel_reference.reference_slip`); ``wheel_loads_N`` are
    the wheels' normal loads on the slope (N)."""
    from lunar_drake.dynamics import wheel_reference

    try:
        s = wheel_reference.reference_slip(
            slope_rad=math.radians(case.slope_deg),
            wheel_loads_N=wheel_loads_N,
            wheel=wheel,
            soil=soil,
        )
        return float(s), False
    except tm.ImmobilizedError:
        return 1.0, True


def case_scenario(case: SlipCase, *, ramp):
    """The scenario of one case: the rover at the ramp's base heading upslope (seeded
    lateral offset and heading error), a settling pause standing still (brakes on), then
    the commanded speed, sent by the ground over a link without delay."""
    from lunar_drake.scenario import RouteSegment, Scenario

    g = rng.generator(case.seed, "slip_study/spawn")
    y0 = float(g.uniform(-0.5, 0.5))
    yaw0_deg = float(g.normal(0.0, 0.5))
    nominal_t = case.distance_m / case.speed_mps
    t_end = case.settle_s + 3.0 * nominal_t + 10.0
    s = Scenario(name=f"slip {case.rover} {case.slope_deg:g} deg seed {case.seed}")
    s.random_seed = case.seed
    s.simulation_duration = t_end
    s.soil = load_soil(case.soil)
    s.rover.description = _description(case.rover)
    s.rover.spawn_x_m = ramp.bounds.left + RAMP_START_M
    s.rover.spawn_y_m = y0
    s.rover.spawn_yaw_deg = yaw0_deg
    s.ground.route = [
        RouteSegment(duration_s=case.settle_s),
        RouteSegment(duration_s=t_end, vx_mps=case.speed_mps),
    ]
    s.comms.uplink.delay_s = 0.0
    s.comms.downlink.delay_s = 0.0
    s.comms.line_of_sight.enabled = False  # a test lane, not a site: no horizon to model
    s.logging.period_s = 0.05
    s.plant_config.time_step = case.time_step_s
    return s


def run_slip_case(case: SlipCase) -> dict:
    """Simulates one case and returns its row (see :data:`CSV_COLUMNS`) and parameters."""
    from lunar_drake.models.rover_sdf import level_wheel_loads
    from lunar_drake.moon import GRAVITY_MPS2
    from lunar_drake.rotations import rotation_matrix_from_rpy
    from lunar_drake.simulation import simulate
    from lunar_drake.site import SiteData

    hf = ramp_heightfield(
        slope_deg=case.slope_deg,
        length_m=case.distance_m + 2.0,
        roughness_m=case.roughness_m,
        seed=case.seed,
    )
    scenario = case_scenario(case, ramp=hf)
    start = {}

    def stop_when(t, pose):
        if not start:
            start["p"] = np.array(pose[:3])
            start["fwd"] = rotation_matrix_from_rpy(pose[3:6])[:, 0]
        p = np.asarray(pose[:3])
        if np.linalg.norm(p - start["p"]) >= case.distance_m:
            return "distance reached"
        if np.dot(p - start["p"], start["fwd"]) < -SLIDE_BACK_STOP_M:
            return "slid back (immobilized)"
        return None

    try:
        logs = simulate(
            scenario=scenario, site=SiteData.from_heightfield(hf, name="ramp"), stop_when=stop_when
        )
        stop = logs.stop_reason
    except SimulationError as exc:  # a diverging case must not take the sweep down
        raise SimulationError(f"slip case {case}: {exc}") from exc
    if stop.startswith("rover left the terrain"):
        stop = "left the ramp"
    elif stop == "duration reached":
        stop = "time limit"
    nf = len(WHEEL_STATE_FIELDS)
    pose_log = logs.vectors["truth.pose"]
    times = pose_log.times
    pose = pose_log.data
    enc = logs.vectors["rover.wheel_encoders"].data
    ws = logs.vectors["truth.wheel_state"].data
    energy = logs.vectors["truth.drive_energy"].data[:, 0]
    start_p = pose[0, :3]
    travelled = np.linalg.norm(pose[:, :3] - start_p, axis=1)
    driving = times >= case.settle_s
    far = driving & (travelled >= 0.1 * case.distance_m)
    i0 = int(np.argmax(far)) if far.any() else int(np.argmax(driving))
    i1 = len(times) - 1
    # Signed progress along the rover's heading at i0 (a rover sliding back counts < 0).
    gt = float(np.dot(pose[i1, :3] - pose[i0, :3], rotation_matrix_from_rpy(pose[i0, 3:6])[:, 0]))
    desc = scenario.rover.description
    dr = float(np.mean(enc[i1] - enc[i0]) * desc.wheel_radius_m)
    slip = 1.0 - gt / dr if dr > 1e-9 else float("nan")
    wheel = tm.WheelParams(radius_m=desc.wheel_radius_m, width_m=desc.wheel_width_m)
    soil = scenario.soil
    # Static normal loads on the slope: the rover at rest, braked, over the last 0.5 s of
    # the settling pause (the same force balance as a steady climb: the braking force
    # equals the traction; load transfer included).
    rest = (times > case.settle_s - 0.5) & (times <= case.settle_s)
    slope_loads = ws[rest][:, WHEEL_STATE_FIELDS.index("normal_force_N") :: nf].mean(axis=0)
    ref, immobilized = reference_for(case, wheel_loads_N=slope_loads, wheel=wheel, soil=soil)
    level_loads = level_wheel_loads(desc)
    row = {
        "rover": case.rover,
        "slope_deg": case.slope_deg,
        "seed": case.seed,
        "slip": slip,
        "reference_slip": ref,
        "immobilized": immobilized,
        "sinkage_m": float(np.mean(ws[i0 : i1 + 1, WHEEL_STATE_FIELDS.index("sinkage_m") :: nf])),
        "energy_J": float(energy[i1] - energy[i0]),
        "distance_m": float(travelled[i1]),
        "time_s": float(times[i1]),
        "stop": stop,
    }
    params = {
        "rover": case.rover,
        "preset": desc.name,
        "soil": dc.asdict(soil),
        "wheel_radius_m": desc.wheel_radius_m,
        "wheel_width_m": desc.wheel_width_m,
        "static_wheel_load_level_N": [float(v) for v in level_loads],
        "wheels": ["fl", "fr", "rl", "rr"],
        "gravity_mps2": GRAVITY_MPS2,
        "speed_mps": case.speed_mps,
        "time_step_s": case.time_step_s,
        "roughness_m": case.roughness_m,
        "roughness_hurst": ROUGHNESS_HURST,
        "reference": "lunar_drake.dynamics.wheel_reference.reference_slip with the "
        "static_wheel_load_on_slope_N of each case (normal loads, N)",
    }
    return {
        "row": row,
        "params": params,
        "slope_loads": {
            "rover": case.rover,
            "slope_deg": case.slope_deg,
            "seed": case.seed,
            "static_wheel_load_on_slope_N": [float(v) for v in slope_loads],
        },
    }


def parse_slopes(text: str) -> list[float]:
    """'A:B:STEP' (inclusive) or a comma list -> slopes in degrees."""
    try:
        if ":" in text:
            a, b, step = (float(v) for v in text.split(":"))
            if step <= 0 or b < a:
                raise ValueError
            n = math.floor((b - a) / step + 1e-9) + 1
            return [round(a + k * step, 9) for k in range(n)]
        return [float(v) for v in text.split(",")]
    except ValueError as exc:
        raise ConfigError(
            f"--slopes {text!r} must be A:B:STEP with STEP > 0 and B >= A, or a comma list"
        ) from exc


def run_slip_study(
    *,
    rovers,
    slopes_deg,
    distance_m: float,
    seeds: int,
    out_dir,
    soil: str = "lunar_regolith",
    speed_mps: float = 0.1,
    roughness_m: float = 0.0,
    data=None,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool = True,
) -> list[dict]:
    """Runs every (rover, slope, seed) case and writes slip.csv, params.json and slip.png.

    Cases run on the trade-study engine (dask.distributed:
    :func:`lunar_drake.trade.engine.map_on_cluster`) when ``workers > 1`` or with a
    ``scheduler`` address, else in this process; results do not depend on the worker
    count. ``data``: optional measured (slope_deg, slip) arrays drawn on
    slip.png (e.g. the data a soil was fitted to).
    """
    if seeds < 1:
        raise OutOfRangeError(f"seeds = {seeds!r}; must be >= 1")
    cases = [
        SlipCase(
            rover=r,
            slope_deg=s,
            seed=k,
            distance_m=distance_m,
            speed_mps=speed_mps,
            soil=str(soil),
            roughness_m=roughness_m,
        )
        for r in rovers
        for s in slopes_deg
        for k in range(seeds)
    ]
    out_dir = ensure_output_dir(out_dir, what="--out directory")
    from lunar_drake.trade.engine import map_cases

    results = map_cases(run_slip_case, cases, workers=workers, scheduler=scheduler,
                        progress=progress, desc="slip study")  # fmt: skip
    rows = [r["row"] for r in results]
    params = {}
    for r in results:
        params.setdefault(r["params"]["rover"], r["params"])
    _write_csv(out_dir / "slip.csv", rows)
    doc = {
        "rovers": params,
        "slope_loads": [r["slope_loads"] for r in results],
        "method": __doc__.strip(),
    }
    atomic_write_text(out_dir / "params.json", json.dumps(doc, indent=2) + "\n")
    plot_slip(rows, path=out_dir / "slip.png", data=data)
    return rows


def _write_csv(path: Path, rows) -> None:
    with atomic_path(path, what="slip table") as tmp, open(tmp, "w") as f:
        f.write(",".join(CSV_COLUMNS) + "\n")
        for r in rows:
            vals = []
            for c in CSV_COLUMNS:
                v = r[c]
                vals.append(
                    f"{v:.6f}"
                    if isinstance(v, float)
                    else str(v).lower()
                    if isinstance(v, bool)
                    else str(v)
                )
            f.write(",".join(vals) + "\n")


def summarize(rows) -> list[dict]:
    """Per (rover, slope): mean, min, max slip across seeds and the reference."""
    out = []
    keys = sorted({(r["rover"], r["slope_deg"]) for r in rows})
    for rover, slope in keys:
        s = np.array([r["slip"] for r in rows if r["rover"] == rover and r["slope_deg"] == slope])
        first = next(r for r in rows if r["rover"] == rover and r["slope_deg"] == slope)
        ref = first["reference_slip"]
        out.append(
            {
                "rover": rover,
                "slope_deg": slope,
                "mean": float(s.mean()),
                "std": float(s.std(ddof=1)) if s.size > 1 else 0.0,
                "min": float(s.min()),
                "max": float(s.max()),
                "reference": ref,
                "immobilized": bool(first["immobilized"]),
            }
        )
    return out


def plot_slip(rows, *, path, data=None) -> Path:
    """slip.png: mean and spread of simulated slip versus slope per rover, the independent
    reference (dashed; a triangle at the top where it says the rover cannot climb) and,
    if given, measured data (``data``: (slope_deg, slip) arrays, e.g. a slip-fit's input)."""
    from matplotlib.figure import Figure

    path = Path(path)
    summ = summarize(rows)
    fig = Figure(figsize=(7, 4.5))
    ax = fig.subplots()
    for k, rover in enumerate(sorted({r["rover"] for r in summ})):
        ss = [r for r in summ if r["rover"] == rover]
        x = np.array([r["slope_deg"] for r in ss])
        m = np.array([r["mean"] for r in ss]) * 100
        lo = np.array([r["min"] for r in ss]) * 100
        hi = np.array([r["max"] for r in ss]) * 100
        stuck = np.array([r["immobilized"] for r in ss])
        ref = np.where(stuck, np.nan, np.array([r["reference"] for r in ss]) * 100)
        color = f"C{k}"
        climb = m <= 100.0
        ax.errorbar(
            x[climb],
            m[climb],
            yerr=[np.maximum(m - lo, 0)[climb], np.maximum(hi - m, 0)[climb]],
            fmt="o",
            color=color,
            capsize=3,
            label=f"{rover}: simulated (mean, min-max over seeds)",
        )
        if (~climb).any():  # spun out and slid back (slip > 100 %): drawn at the top
            ax.plot(
                x[~climb],
                np.full((~climb).sum(), 100.0),
                "x",
                color=color,
                ms=9,
                label=f"{rover}: simulated, slides back (slip > 100 %)",
            )
        ax.plot(x, ref, "--", color=color, label=f"{rover}: independent steady-state reference")
        if stuck.any():
            ax.plot(
                x[stuck],
                np.full(stuck.sum(), 103.0),
                "v",
                mfc="none",
                color=color,
                ms=8,
                label=f"{rover}: reference says it cannot climb",
            )
    if data is not None:
        dx, dy = (np.asarray(v, dtype=float) for v in data)
        ax.plot(dx, dy * 100, "s", color="k", ms=4, alpha=0.6, label="measured data")
    ax.set_xlabel("slope (deg)")
    ax.set_ylabel("slip (%)")
    ax.set_ylim(0, 106)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("Wheel slip vs slope (planar ramps)")
    fig.tight_layout()
    with atomic_path(path, what="plot") as tmp:
        fig.savefig(tmp, dpi=110)
    return path
