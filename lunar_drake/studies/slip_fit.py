"""Fit soil strength parameters to measured slip-versus-slope data (``lunar-drake slip-fit``).

Input: a CSV with columns ``slope_deg,slip`` (one measurement a row, repeats allowed;
slip a fraction in [0, 1), slope in degrees) for one rover, ``skid`` (husky_rp) or
``explicit`` (krex2_rp). Model: the independent Wong-Reece reference
(:func:`lunar_drake.dynamics.wheel_reference.reference_slip`) at the quasi-static slope
loads of that rover (:func:`~lunar_drake.dynamics.wheel_reference.slope_wheel_loads`),
where the rover cannot climb it predicts slip 1 (spin-out).

Fitted parameters: the friction angle ``phi`` and the shear deformation modulus ``K``;
every other field keeps the base soil's value (``lunar_regolith`` by default). Why these
two: slip vs slope is the slip at which drawbar pull / weight reaches ``tan(slope)``,
which is set by the soil's shear strength (mostly ``tan phi``: where the curve turns up
towards immobilization) and by how fast the shear mobilizes with slip (``K``: the slope of
the curve at low slopes). Measured numerically (finite-difference sensitivities of the
slip curve at 0-17 deg for both rovers on lunar regolith, 1 pp noise, one measurement per
slope): ``(phi, K)`` is well conditioned (condition number 10-14; standard errors about
1-2 % in ``phi`` and 3-4 % in ``K``, though the two are correlated, |r| ~ 0.98-0.99).
Adding the cohesion ``c`` makes it ill-posed (condition 270-620, ``c`` unresolved by a
factor e^5 or more): at these loads ``c`` is a few per cent of the strength and acts like a
small change of ``phi``. Adding a Bekker modulus (``k_phi``, ``n``) or ``c1`` is likewise
ill-conditioned (condition 58-450), so sinkage parameters need plate-sinkage data, not
slip curves.

Method: ``scipy.optimize.least_squares`` (trust-region reflective, bounds
:data:`BOUNDS`) on the residuals ``model(slope_i) - slip_i``, in the variables
(``phi`` in degrees, ``K`` in cm), from the base soil; if that ends above the acceptance
threshold, once more from the best point of a coarse grid over the bounds. The fit is
rejected (:class:`~lunar_drake.errors.ConfigError`) when its RMS residual exceeds
:data:`MAX_RMS_PP` percentage points, or when the fitted soil cannot climb a slope at
which the data has a slip below 1 (a fit that reaches high slips only by immobilizing
the rover): then no soil within the bounds reproduces the data (e.g. slips far above
what the weakest soil gives on gentle slopes, or climbs of slopes that even the
strongest soil cannot climb). Standard errors come from the Jacobian at the solution
(``s^2 (J^T J)^-1``, ``s^2`` = residual variance), valid only when the model fits.

Outputs (``--out DIR``): ``soil.yaml`` (the fitted soil as a ``soil:`` section: loadable
as a scenario's ``soil``, by ``run --soil``, and by :func:`~lunar_drake.dynamics.soil_io.
load_soil`), ``fit.csv`` (``slope_deg,measured_slip,fitted_slip``, one row a measurement;
fitted 1 where the fitted soil immobilizes the rover) and ``fit.png`` (data, fitted curve,
base-soil curve).
"""

from __future__ import annotations

import csv
import dataclasses as dc
import math
from pathlib import Path

import numpy as np

from lunar_drake.dynamics import wheel_reference as wr
from lunar_drake.dynamics.soil_io import load_soil, soil_yaml
from lunar_drake.dynamics.terramechanics import ImmobilizedError, SoilParams, WheelParams
from lunar_drake.errors import ConfigError
from lunar_drake.files import atomic_path, atomic_write_text, ensure_output_dir

__all__ = [
    "BOUNDS",
    "FIT_PARAMETERS",
    "MAX_RMS_PP",
    "ROVER_CHOICES",
    "SlipData",
    "SlipFit",
    "fit_soil",
    "model_slips",
    "read_slip_data",
    "run_slip_fit",
    "write_fit",
]

ROVER_CHOICES = {"skid": "husky_rp", "explicit": "krex2_rp"}
FIT_PARAMETERS = ("phi", "K")
BOUNDS = {"phi": (math.radians(15.0), math.radians(55.0)), "K": (0.0005, 0.10)}
"""Bounds of the fitted fields (SI: rad, m): phi 15-55 deg, K 0.5 mm-10 cm."""
MAX_RMS_PP = 10.0
"""A fit whose RMS residual exceeds this (percentage points of slip) is rejected."""
MIN_SLOPES = 3
_SCALE = np.array([math.degrees(1.0), 100.0])  # SI -> optimizer variables (deg, cm)


@dc.dataclass(frozen=True)
class SlipData:
    """Measurements: ``slope_deg`` (deg) and ``slip`` (fraction), parallel arrays."""

    slope_deg: np.ndarray
    slip: np.ndarray


@dc.dataclass(frozen=True)
class SlipFit:
    """Result of :func:`fit_soil`.

    Attributes:
        soil: base soil with the fitted fields. base_soil: the base soil.
        rover: ``skid`` or ``explicit``. data: the measurements.
        fitted_slip: model slip at each measurement's slope (1 where immobilized).
        base_slip: the base soil's model slip there (1 where immobilized).
        rms_pp: RMS of ``fitted_slip - slip`` (percentage points).
        stderr: standard error of each fitted field (SI units; NaN if undetermined).
        evaluations: model evaluations (residual vectors) the optimizer used.
    """

    soil: SoilParams
    base_soil: SoilParams
    rover: str
    data: SlipData
    fitted_slip: np.ndarray
    base_slip: np.ndarray
    rms_pp: float
    stderr: dict
    evaluations: int


# ----------------------------------------------------------------------------- input


def _number(text: str, *, path: Path, line: int, column: str) -> float:
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise ConfigError(
            f"{str(path)!r} line {line}: {column} = {text!r} is not a number"
        ) from None
    if not math.isfinite(v):
        raise ConfigError(f"{str(path)!r} line {line}: {column} = {text!r} must be finite")
    return v


def read_slip_data(path) -> SlipData:
    """Reads and checks a ``slope_deg,slip`` CSV (extra columns ignored, blank lines
    skipped).

    Raises:
        ConfigError: missing file, missing column, non-numeric or non-finite value, slope
            outside [0, 60) deg, slip outside [0, 1), fewer than three distinct slopes.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"slip data {str(path)!r} does not exist")
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:  # a BOM is tolerated
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ConfigError(f"slip data {str(path)!r} cannot be read: {exc}") from None
    rows = [(k + 1, r) for k, r in enumerate(rows) if any(c.strip() for c in r)]
    if not rows:
        raise ConfigError(f"slip data {str(path)!r} is empty; expected columns slope_deg,slip")
    header = [c.strip() for c in rows[0][1]]
    for col in ("slope_deg", "slip"):
        if col not in header:
            raise ConfigError(
                f"slip data {str(path)!r} has no column {col!r} (header: {','.join(header)}); "
                "expected columns slope_deg,slip"
            )
    i_a, i_s = header.index("slope_deg"), header.index("slip")
    slopes, slips = [], []
    for line, r in rows[1:]:
        if len(r) <= max(i_a, i_s):
            raise ConfigError(f"{str(path)!r} line {line}: expected {len(header)} columns")
        a = _number(r[i_a].strip(), path=path, line=line, column="slope_deg")
        s = _number(r[i_s].strip(), path=path, line=line, column="slip")
        if not 0.0 <= a < 60.0:
            raise ConfigError(
                f"{str(path)!r} line {line}: slope_deg = {a:g} is out of range; allowed [0, 60)"
            )
        if not 0.0 <= s < 1.0:
            raise ConfigError(
                f"{str(path)!r} line {line}: slip = {s:g} is out of range; allowed [0, 1) "
                "(a fraction; a rover that slid back cannot be fitted)"
            )
        slopes.append(a)
        slips.append(s)
    distinct = len(set(slopes))
    if distinct < MIN_SLOPES:
        raise ConfigError(
            f"slip data {str(path)!r} has {distinct} distinct slope(s); need at least "
            f"{MIN_SLOPES} to fit {' and '.join(FIT_PARAMETERS)}"
        )
    return SlipData(slope_deg=np.array(slopes), slip=np.array(slips))


def _rover(rover: str) -> str:
    if rover not in ROVER_CHOICES:
        raise ConfigError(f"rover = {rover!r} is unknown; choose one of {sorted(ROVER_CHOICES)}")
    return rover


# ----------------------------------------------------------------------------- model


class _Model:
    """Slip at given slopes for one rover; slope loads computed once."""

    def __init__(self, rover: str):
        from lunar_drake.models.rover_description import rover_preset

        self.desc = rover_preset(ROVER_CHOICES[_rover(rover)])
        self.wheel = WheelParams(radius_m=self.desc.wheel_radius_m, width_m=self.desc.wheel_width_m)
        self._loads: dict[float, np.ndarray] = {}

    def loads(self, slope_deg: float) -> np.ndarray:
        if slope_deg not in self._loads:
            self._loads[slope_deg] = wr.slope_wheel_loads(
                description=self.desc, slope_rad=math.radians(slope_deg)
            )
        return self._loads[slope_deg]

    def slips(self, slopes_deg, soil: SoilParams, *, immobilized: float = 1.0) -> np.ndarray:
        out = []
        for a in slopes_deg:
            try:
                out.append(
                    wr.reference_slip(
                        slope_rad=math.radians(a),
                        wheel_loads_N=self.loads(float(a)),
                        wheel=self.wheel,
                        soil=soil,
                    )
                )
            except ImmobilizedError:
                out.append(immobilized)
        return np.array(out, dtype=np.float64)


def model_slips(*, slopes_deg, rover: str, soil: SoilParams) -> np.ndarray:
    """Reference slip of ``rover`` (skid/explicit) at each slope (deg) on ``soil`` at the
    quasi-static slope loads; NaN where it cannot climb."""
    return _Model(rover).slips(np.atleast_1d(slopes_deg), soil, immobilized=math.nan)


def _with(soil: SoilParams, x: np.ndarray) -> SoilParams:
    vals = dict(zip(FIT_PARAMETERS, (x / _SCALE).tolist(), strict=True))
    if "K" in vals and soil.K_y == soil.K:  # an isotropic base stays isotropic
        vals["K_y"] = vals["K"]
    return dc.replace(soil, **vals)


def fit_soil(
    *,
    data: SlipData,
    rover: str,
    base_soil: SoilParams,
    max_rms_pp: float = MAX_RMS_PP,
    name: str | None = None,
) -> SlipFit:
    """Fits ``phi`` and ``K`` of ``base_soil`` to ``data`` (module docstring).

    ``name`` names the fitted soil (default ``<base name>_fit``).

    Raises:
        ConfigError: no soil within :data:`BOUNDS` fits (RMS > ``max_rms_pp``), or bad
            rover.
    """
    from scipy.optimize import least_squares

    model = _Model(rover)
    base_soil = load_soil(base_soil)
    slopes, inverse = np.unique(data.slope_deg, return_inverse=True)
    lo = np.array([BOUNDS[p][0] for p in FIT_PARAMETERS]) * _SCALE
    hi = np.array([BOUNDS[p][1] for p in FIT_PARAMETERS]) * _SCALE
    count = [0]

    def residuals(x):
        count[0] += 1
        return model.slips(slopes, _with(base_soil, x))[inverse] - data.slip

    def solve(x0):
        return least_squares(
            residuals, np.clip(x0, lo, hi), bounds=(lo, hi), method="trf", diff_step=1e-5,
            x_scale=np.array([5.0, 1.0]), xtol=1e-6, ftol=1e-8, gtol=1e-8,
        )  # fmt: skip

    def rms(r):
        return 100.0 * math.sqrt(float(np.mean(np.square(r))))

    x0 = np.array([getattr(base_soil, p) for p in FIT_PARAMETERS]) * _SCALE
    best = solve(x0)
    if rms(best.fun) > max_rms_pp:
        grid = [np.array([p, k]) for p in np.linspace(lo[0], hi[0], 5) for k in (0.5, 1.5, 4, 9)]
        start = min(grid, key=lambda x: float(np.sum(np.square(residuals(x)))))
        again = solve(start)
        if again.cost < best.cost:
            best = again
    err = rms(best.fun)
    base_slip = model.slips(slopes, base_soil)[inverse]
    if err > max_rms_pp:
        x = best.x / _SCALE
        raise ConfigError(
            f"no soil with {FIT_PARAMETERS[0]} in [{math.degrees(BOUNDS['phi'][0]):g}, "
            f"{math.degrees(BOUNDS['phi'][1]):g}] deg and K in [{100 * BOUNDS['K'][0]:g}, "
            f"{100 * BOUNDS['K'][1]:g}] cm fits the data: the best (phi "
            f"{math.degrees(x[0]):.1f} deg, K {100 * x[1]:.2f} cm) leaves an RMS residual "
            f"of {err:.1f} pp > {max_rms_pp:g} pp (base {base_soil.name}: "
            f"{rms(base_slip - data.slip):.1f} pp)"
        )
    soil = _with(base_soil, best.x)
    climbs = model.slips(slopes, soil, immobilized=math.nan)
    if np.any(np.isnan(climbs)):
        k = int(np.argmax(np.isnan(climbs)))
        measured = data.slip[inverse == k]
        raise ConfigError(
            f"no soil with phi in [{math.degrees(BOUNDS['phi'][0]):g}, "
            f"{math.degrees(BOUNDS['phi'][1]):g}] deg and K in [{100 * BOUNDS['K'][0]:g}, "
            f"{100 * BOUNDS['K'][1]:g}] cm fits the data: the closest (phi "
            f"{math.degrees(soil.phi):.1f} deg, K {100 * soil.K:.2f} cm, RMS {err:.1f} pp) "
            f"cannot climb {slopes[k]:g} deg, where the data has slip "
            f"{float(np.mean(measured)):.3g}"
        )
    soil = dc.replace(soil, name=name or f"{base_soil.name}_fit")
    stderr = _stderr(best, len(data.slip))
    return SlipFit(
        soil=soil,
        base_soil=base_soil,
        rover=rover,
        data=data,
        fitted_slip=data.slip + best.fun,
        base_slip=base_slip,
        rms_pp=err,
        stderr=stderr,
        evaluations=count[0],
    )


def _stderr(result, m: int) -> dict:
    p = len(FIT_PARAMETERS)
    J = result.jac * _SCALE  # d residual / d SI parameter (x = SI * _SCALE)
    out = dict.fromkeys(FIT_PARAMETERS, math.nan)
    if m <= p:
        return out
    s2 = 2.0 * result.cost / (m - p)
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return out
    d = np.diag(cov)
    sd = [float(math.sqrt(v)) if v >= 0 else math.nan for v in d]
    return dict(zip(FIT_PARAMETERS, sd, strict=True))


# ----------------------------------------------------------------------------- output


def _pm(value: float, scale: float, digits: int) -> str:
    return "undetermined" if not math.isfinite(value) else f"+- {value * scale:.{digits}f}"


def _bound_note(name: str, value: float) -> str:
    lo, hi = BOUNDS[name]
    near = 1e-4 * (hi - lo)
    return ", at its bound" if value <= lo + near or value >= hi - near else ""


def describe(fit: SlipFit) -> list[str]:
    """Lines summarizing a fit (printed by the CLI and written atop soil.yaml)."""
    s, b = fit.soil, fit.base_soil
    e = fit.stderr
    n_slopes = len(set(fit.data.slope_deg.tolist()))
    base_rms = 100 * math.sqrt(float(np.mean(np.square(fit.base_slip - fit.data.slip))))
    return [
        f"phi = {math.degrees(s.phi):.2f} deg ({_pm(e['phi'], math.degrees(1.0), 2)}"
        f"{_bound_note('phi', s.phi)}; base {b.name} {math.degrees(b.phi):.2f} deg)",
        f"K = {100 * s.K:.3f} cm ({_pm(e['K'], 100.0, 3)}{_bound_note('K', s.K)}; base "
        f"{100 * b.K:.3f} cm)",
        f"RMS residual {fit.rms_pp:.2f} pp over {len(fit.data.slip)} measurements at "
        f"{n_slopes} slopes ({fit.rover} rover; base soil {b.name}: {base_rms:.2f} pp)",
    ]


def write_fit(fit: SlipFit, *, out_dir, source: str = "") -> list[Path]:
    """Writes ``soil.yaml``, ``fit.csv`` and ``fit.png`` into ``out_dir`` (created if
    needed), each atomically; returns their paths."""
    out = ensure_output_dir(out_dir, what="--out directory")
    comment = "\n".join(
        [
            f"Soil fitted by lunar-drake slip-fit{' to ' + source if source else ''}: "
            f"{' and '.join(FIT_PARAMETERS)} fitted, every other field from "
            f"{fit.base_soil.name}.",
            *describe(fit),
            "Units: SI (phi in rad, K in m).",
        ]
    )
    soil_path = atomic_write_text(out / "soil.yaml", soil_yaml(fit.soil, comment=comment),
                                  what="soil file")  # fmt: skip
    lines = ["slope_deg,measured_slip,fitted_slip"]
    lines += [
        f"{a:.6g},{m:.6f},{f:.6f}"
        for a, m, f in zip(fit.data.slope_deg, fit.data.slip, fit.fitted_slip, strict=True)
    ]
    csv_path = atomic_write_text(out / "fit.csv", "\n".join(lines) + "\n", what="fit table")
    png_path = _plot(fit, out / "fit.png")
    return [soil_path, csv_path, png_path]


def _plot(fit: SlipFit, path: Path) -> Path:
    from matplotlib.figure import Figure

    model = _Model(fit.rover)
    top = float(np.max(fit.data.slope_deg))
    grid = np.linspace(0.0, max(top * 1.15, top + 1.0), 16)
    fitted = model.slips(grid, fit.soil, immobilized=math.nan)
    base = model.slips(grid, fit.base_soil, immobilized=math.nan)
    fig = Figure(figsize=(7, 4.5))
    ax = fig.subplots()
    ax.plot(fit.data.slope_deg, 100 * fit.data.slip, "o", color="k", ms=4, label="measured")
    s = fit.soil
    ax.plot(grid, 100 * fitted, "-", color="C0",
            label=f"fitted: phi {math.degrees(s.phi):.1f} deg, K {100 * s.K:.2f} cm "
            f"(RMS {fit.rms_pp:.2f} pp)")  # fmt: skip
    b = fit.base_soil
    ax.plot(
        grid,
        100 * base,
        "--",
        color="C1",
        label=f"base {b.name}: phi {math.degrees(b.phi):.1f} deg, K {100 * b.K:.2f} cm",
    )
    ax.set_xlabel("slope (deg)")
    ax.set_ylabel("slip (%)")
    ax.set_ylim(0, 100)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"Slip vs slope: {fit.rover} rover, Wong-Reece reference fit")
    fig.tight_layout()
    with atomic_path(path, what="plot") as tmp:
        fig.savefig(tmp, dpi=110)
    return path


def run_slip_fit(*, data_path, rover: str, out_dir, base_soil="lunar_regolith") -> SlipFit:
    """Reads ``data_path``, fits (:func:`fit_soil`) and writes the outputs
    (:func:`write_fit`)."""
    rover = _rover(rover)
    base = load_soil(base_soil)
    data = read_slip_data(data_path)
    fit = fit_soil(data=data, rover=rover, base_soil=base)
    write_fit(fit, out_dir=out_dir, source=Path(data_path).name)
    return fit
