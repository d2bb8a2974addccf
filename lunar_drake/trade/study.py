"""A trade study's definition (``STUDY.yaml``) and its cases.

A study names a base scenario, the factors it varies (dotted scenario keys, or named
factors whose levels are scenario overrides), the design (full factorial, or a seeded
Latin hypercube from :mod:`scipy.stats.qmc`), the replicates (values of
``random_seed``: the noise changes, the site does not) and the metrics (dotted keys of
``summary.json`` or :mod:`lunar_drake.trade.metrics`' derived ones). Every case is
resolved into a validated :class:`~lunar_drake.scenario.Scenario` before anything runs,
so a bad key or value is a one-line :class:`~lunar_drake.errors.ConfigError` naming the
study file and line, and nothing is written.

Example::

    name: comms
    base: {scenario: goto, scenario_text: "{sensors: {camera: {enabled: false}}}"}
    factors:
      comms.uplink.delay_s: [1.3, 5.0]          # full factorial over the lists
      steering:                                  # a named factor: levels are overrides
        levels:
          slow: {ground: {drive_speed_mps: 0.1}}
          fast: {ground: {drive_speed_mps: 0.3}}
    replicates: 3                                # random_seed 0, 1, 2 (or a list)
    metrics: [goals.reached, mission.time_s: min]
    quick: {scenario_text: "{simulation_duration: 60}", replicates: 1}

With ``design: lhs`` a numeric factor is a range ``{min: A, max: B}`` (``int: true``
rounds it) and ``lhs: {n: N, seed: S}`` sets the points; a list is then categorical.
"""

from __future__ import annotations

import copy
import dataclasses as dc
import hashlib
import math
import re
from pathlib import Path

import yaml

from lunar_drake.errors import ConfigError, LunarDrakeError

#: Top-level keys of a study file.
STUDY_KEYS = ("name", "description", "base", "design", "lhs", "factors", "replicates",
              "metrics", "quick")  # fmt: skip
#: Most cases one study may have (cases x replicates).
MAX_JOBS = 100_000
_KEY_PART = re.compile(r"([A-Za-z_]\w*)(?:\[(\d+)\])?$")
_SOURCE_PREFIX = re.compile(r"^.*?, line \d+: ")


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader, reading ``1e6`` and ``4.0e6`` as numbers (YAML 1.2), not
    text as YAML 1.1 does."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?"
               r"|[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+"
               r"|\.[0-9_]+(?:[eE][-+]?[0-9]+)?"
               r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"),
    list("-+0123456789."),
)


@dc.dataclass(frozen=True)
class Factor:
    """One factor. ``key``: a dotted scenario key (``comms.uplink.delay_s``,
    ``comms.downlink.channels[1].bandwidth_bps``) or, for a named factor, its name;
    ``levels``: the values (a named factor's labels); ``overrides``: label -> scenario
    override mapping (named factors only); ``range``: (min, max) for an LHS factor;
    ``line``: where the study file writes it."""

    key: str
    levels: tuple = ()
    overrides: dict | None = None
    range: tuple[float, float] | None = None
    integer: bool = False
    line: int | None = None

    @property
    def named(self) -> bool:
        return self.overrides is not None


@dc.dataclass(frozen=True)
class Metric:
    """A metric's key and the better direction (``max``, ``min`` or None)."""

    key: str
    better: str | None = None


@dc.dataclass(frozen=True)
class Job:
    """One run: design point ``case`` (``c0003``) x replicate ``replicate`` (its seed
    ``seed``). ``factors``: factor key -> the value shown in results.csv;
    ``scenario_yaml``: the resolved scenario; ``key``: its hash (resume identity)."""

    case: str
    replicate: int
    seed: int
    factors: dict
    scenario_yaml: str
    key: str

    @property
    def id(self) -> str:
        return f"{self.case}-r{self.replicate}"


@dc.dataclass(frozen=True)
class Study:
    """A parsed study file (see the module docstring)."""

    name: str
    description: str
    source: str
    scenario: str
    scenario_text: str
    design: str
    factors: tuple[Factor, ...]
    replicates: tuple[int, ...]
    metrics: tuple[Metric, ...]
    lhs_n: int = 0
    lhs_seed: int = 0
    quick_text: str = "{}"
    quick_replicates: tuple[int, ...] | None = None
    lines: dict = dc.field(default_factory=dict)
    text: str = ""


def _err(source: str, line: int | None, msg: str) -> ConfigError:
    return ConfigError(f"{source}, line {line}: {msg}" if line else f"{source}: {msg}")


def _line(node) -> int | None:
    return node.start_mark.line + 1 if node is not None else None


def _child(node, key: str):
    """(key node, value node) of ``key`` in a YAML mapping node, or (None, None)."""
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            if k.value == key:
                return k, v
    return None, None


def _seeds(value, source: str, line: int | None, what: str) -> tuple[int, ...]:
    if isinstance(value, bool) or value is None:
        raise _err(source, line, f"{what} = {value!r} must be a count or a list of seeds")
    if isinstance(value, int):
        if not 1 <= value <= 1000:
            raise _err(source, line, f"{what} = {value} is out of range; allowed [1, 1000]")
        return tuple(range(value))
    if isinstance(value, list) and value and all(
        isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in value
    ):
        if len(set(value)) != len(value):
            raise _err(source, line, f"{what} = {value} repeats a seed")
        return tuple(value)
    raise _err(source, line, f"{what} = {value!r} must be a count or a non-empty list of "
                             "seeds (integers >= 0)")  # fmt: skip


def _text(value, source: str, line: int | None, what: str) -> str:
    if value is None:
        return "{}"
    if isinstance(value, dict):
        return yaml.safe_dump(value, default_flow_style=True, sort_keys=True).strip()
    if not isinstance(value, str):
        raise _err(source, line, f"{what} must be YAML text or a mapping, not {value!r}")
    return value


def _parse_factor(key: str, value, key_node, value_node, *, design: str, source: str) -> Factor:
    line = _line(key_node)
    if isinstance(value, dict) and "levels" in value:
        extra = set(value) - {"levels"}
        levels = value["levels"]
        if extra or not isinstance(levels, dict) or not levels:
            raise _err(source, line, f"factor {key!r}: a named factor is {{levels: {{LABEL: "
                                     "OVERRIDES, ...}}} with at least one level")  # fmt: skip
        for label, ov in levels.items():
            if not isinstance(ov, dict):
                raise _err(source, line, f"factor {key!r} level {label!r}: the overrides must "
                                         f"be a mapping of scenario keys, not {ov!r}")  # fmt: skip
        return Factor(key=key, levels=tuple(str(k) for k in levels),
                      overrides={str(k): v for k, v in levels.items()}, line=line)  # fmt: skip
    if "." not in key and not _KEY_PART.match(key):
        raise _err(source, line, f"factor {key!r} is not a dotted scenario key")
    if isinstance(value, list):
        if not value:
            raise _err(source, line, f"factor {key!r} has no values (an empty design)")
        return Factor(key=key, levels=tuple(value), line=line)
    if isinstance(value, dict) and {"min", "max"} <= set(value):
        if design != "lhs":
            raise _err(source, line, f"factor {key!r} is a range; ranges need design: lhs "
                                     "(a factorial design takes lists)")  # fmt: skip
        lo, hi = value["min"], value["max"]
        ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (lo, hi))
        if not ok or not math.isfinite(lo) or not math.isfinite(hi) or not lo < hi:
            raise _err(source, line, f"factor {key!r}: min = {lo!r}, max = {hi!r} must be "
                                     "numbers with min < max")  # fmt: skip
        extra = set(value) - {"min", "max", "int"}
        if extra:
            raise _err(source, line, f"factor {key!r}: unknown keys {sorted(extra)}; a range "
                                     "has min, max and int")  # fmt: skip
        return Factor(key=key, range=(lo, hi), integer=bool(value.get("int", False)), line=line)
    raise _err(source, line, f"factor {key!r} = {value!r} must be a list of values"
                             + (", a range {min, max}" if design == "lhs" else "")
                             + " or {levels: {...}}")  # fmt: skip


def _parse_metric(item, source: str, line: int | None) -> Metric:
    from lunar_drake.trade.metrics import check_metric_key

    if isinstance(item, str):
        key, better = item, None
    elif isinstance(item, dict) and len(item) == 1:
        ((key, better),) = item.items()
        if better not in ("max", "min"):
            raise _err(source, line, f"metric {key!r}: {better!r} must be max or min")
    else:
        raise _err(source, line, f"metric {item!r} must be a key or {{key: max|min}}")
    try:
        check_metric_key(str(key))
    except ConfigError as exc:
        raise _err(source, line, str(exc)) from None
    return Metric(key=str(key), better=better)


def parse_study(text: str, *, source: str, base_dir: Path | None = None) -> Study:
    """The study in YAML ``text`` (``source`` names it in errors). A scenario file the
    base names relatively is resolved against ``base_dir``.

    Raises:
        ConfigError: malformed YAML, an unknown key, a factor without values, a bad
            design, replicates or metric; naming ``source`` and the line.
    """
    from lunar_drake.scenario_files import _check_tags, _compose

    root = _compose(text, source)
    if root is None or not isinstance(root, yaml.MappingNode):
        raise _err(source, None, "a study file must be a mapping (name, base, factors, ...)")
    _check_tags(root, source)
    data = yaml.load(text, Loader=_Loader)
    lines = {k.value: _line(k) for k, _ in root.value}
    for k, _ in root.value:
        if k.value not in STUDY_KEYS:
            raise _err(source, _line(k), f"unknown key {k.value!r}; allowed keys: "
                                         f"{', '.join(STUDY_KEYS)}")  # fmt: skip
    design = data.get("design", "factorial")
    if design not in ("factorial", "lhs"):
        raise _err(source, lines.get("design"), f"design = {design!r}; allowed: factorial, lhs")
    base = data.get("base") or {}
    if not isinstance(base, dict) or set(base) - {"scenario", "scenario_text"}:
        raise _err(source, lines.get("base"), "base must be {scenario: NAME|FILE.yaml[:NAME], "
                                              "scenario_text: YAML}")  # fmt: skip
    scenario = str(base.get("scenario", "default"))
    if scenario.split(":")[0].endswith((".yaml", ".yml")) and base_dir is not None:
        f, _, n = scenario.partition(":")
        if not Path(f).is_absolute():
            scenario = str((base_dir / f).resolve()) + (f":{n}" if n else "")
    scenario_text = _text(base.get("scenario_text"), source, lines.get("base"),
                          "base.scenario_text")  # fmt: skip
    _, fnode = _child(root, "factors")
    factors_data = data.get("factors")
    if not isinstance(factors_data, dict) or not factors_data:
        raise _err(source, lines.get("factors"), "factors must map at least one key to its "
                                                 "values (an empty design)")  # fmt: skip
    factors = []
    for knode, vnode in fnode.value:
        key = str(knode.value)
        factors.append(_parse_factor(key, factors_data[key], knode, vnode, design=design,
                                     source=source))  # fmt: skip
    lhs_n = lhs_seed = 0
    if design == "lhs":
        lhs = data.get("lhs")
        if not isinstance(lhs, dict) or set(lhs) - {"n", "seed"} or "n" not in lhs:
            raise _err(source, lines.get("lhs", lines.get("design")),
                       "design: lhs needs lhs: {n: POINTS, seed: SEED}")  # fmt: skip
        lhs_n, lhs_seed = lhs["n"], lhs.get("seed", 0)
        if not (isinstance(lhs_n, int) and 1 <= lhs_n <= 10_000):
            raise _err(source, lines["lhs"], f"lhs.n = {lhs_n!r} is out of range; allowed "
                                             "[1, 10000]")  # fmt: skip
        if not (isinstance(lhs_seed, int) and lhs_seed >= 0):
            raise _err(source, lines["lhs"], f"lhs.seed = {lhs_seed!r} must be an integer >= 0")
    elif "lhs" in data:
        raise _err(source, lines["lhs"], "lhs is only for design: lhs")
    replicates = _seeds(data.get("replicates", 1), source, lines.get("replicates"), "replicates")
    metrics_data = data.get("metrics")
    _, mnode = _child(root, "metrics")
    if not isinstance(metrics_data, list) or not metrics_data:
        raise _err(source, lines.get("metrics"), "metrics must list at least one key of "
                                                 "summary.json (goals.reached, ...)")  # fmt: skip
    metrics = tuple(
        _parse_metric(item, source, _line(n)) for item, n in zip(metrics_data, mnode.value,
                                                                 strict=True)
    )
    quick = data.get("quick") or {}
    if not isinstance(quick, dict) or set(quick) - {"scenario_text", "replicates"}:
        raise _err(source, lines.get("quick"), "quick must be {scenario_text: YAML, "
                                               "replicates: N}")  # fmt: skip
    quick_reps = None
    if "replicates" in quick:
        quick_reps = _seeds(quick["replicates"], source, lines.get("quick"), "quick.replicates")
    name = data.get("name") or Path(source).stem
    return Study(
        name=str(name),
        description=str(data.get("description") or ""),
        source=source,
        scenario=scenario,
        scenario_text=scenario_text,
        design=design,
        factors=tuple(factors),
        replicates=replicates,
        metrics=metrics,
        lhs_n=lhs_n,
        lhs_seed=lhs_seed,
        quick_text=_text(quick.get("scenario_text"), source, lines.get("quick"),
                         "quick.scenario_text"),
        quick_replicates=quick_reps,
        lines=lines,
        text=text,
    )


def load_study(path: str | Path) -> Study:
    """The study in file ``path`` (or a shipped study's name, see :func:`shipped_studies`).

    Raises:
        ConfigError: the file does not exist or the study is invalid.
    """
    p = Path(path)
    if not p.is_file():
        shipped = shipped_studies()
        if str(path) in shipped:
            p = shipped[str(path)]
        else:
            raise ConfigError(f"study {str(path)!r} is neither a file nor a shipped study; "
                              f"shipped: {', '.join(sorted(shipped))}")  # fmt: skip
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"study file {str(p)!r} cannot be read: {exc}") from None
    return parse_study(text, source=str(p), base_dir=p.parent)


def shipped_studies() -> dict[str, Path]:
    """Name -> path of the studies shipped in ``lunar_drake/studies/*.yaml``."""
    from importlib import resources

    root = Path(str(resources.files("lunar_drake") / "studies"))
    return {p.stem: p for p in sorted(root.glob("*.yaml"))}


# ------------------------------------------------------------------------ the design


def design_points(study: Study) -> list[dict]:
    """The design: one dict factor key -> value per point, in design order. Factorial:
    every combination, the first factor varying slowest. LHS: ``lhs_n`` points of a
    seeded, scrambled Latin hypercube (:class:`scipy.stats.qmc.LatinHypercube`); a
    range maps linearly (rounded with ``int``), a list picks level floor(u n)."""
    if study.design == "factorial":
        points = [{}]
        for f in study.factors:
            points = [{**p, f.key: v} for p in points for v in f.levels]
        return points
    from scipy.stats import qmc

    u = qmc.LatinHypercube(d=len(study.factors), seed=study.lhs_seed).random(study.lhs_n)
    points = []
    for row in u:
        p = {}
        for f, x in zip(study.factors, row, strict=True):
            if f.range is not None:
                lo, hi = f.range
                v = lo + float(x) * (hi - lo)
                p[f.key] = round(v) if f.integer else round(v, 6)
            else:
                p[f.key] = f.levels[min(int(x * len(f.levels)), len(f.levels) - 1)]
        points.append(p)
    return points


def _set_dotted(tree: dict, key: str, value, base: dict) -> None:
    """Sets dotted ``key`` in the override ``tree``; a list on the way is copied whole
    from ``base`` (the base scenario as plain data) so one element can change."""
    parts = key.split(".")
    node, ref = tree, base
    for i, part in enumerate(parts):
        m = _KEY_PART.match(part)
        if m is None:
            raise ConfigError(f"{part!r} is not a key (letters, digits, _; [N] for a list "
                              "element)")  # fmt: skip
        name, index = m[1], m[2]
        last = i == len(parts) - 1
        ref = ref.get(name) if isinstance(ref, dict) else None
        if index is None:
            if last:
                node[name] = value
            else:
                node = node.setdefault(name, {})
            continue
        if not isinstance(ref, list):
            raise ConfigError(f"{name!r} is not a list in the base scenario")
        k = int(index)
        if k >= len(ref):
            raise ConfigError(f"{name}[{k}] does not exist: the base scenario's {name} has "
                              f"{len(ref)} elements")  # fmt: skip
        lst = node.setdefault(name, copy.deepcopy(ref))
        ref = ref[k]
        if last:
            lst[k] = value
        else:
            node = lst[k]


def _merge(tree: dict, extra: dict) -> None:
    for k, v in extra.items():
        if isinstance(v, dict) and isinstance(tree.get(k), dict):
            _merge(tree[k], v)
        else:
            tree[k] = copy.deepcopy(v)


def scenario_key(scenario_yaml: str) -> str:
    """The resume identity of a resolved scenario: 16 hex digits of its SHA-256."""
    return hashlib.sha256(scenario_yaml.encode()).hexdigest()[:16]


def expand_jobs(study: Study, *, quick: bool = False) -> list[Job]:
    """Every run of ``study`` (``quick``: its reduced form, whose ``scenario_text`` goes
    over each case's factors), resolved and validated, in case-then-replicate order.

    Raises:
        ConfigError: the base scenario fails to load, or a factor's key or value is
            refused (naming the study file, the factor's line, the key and the value).
    """
    from lunar_drake.cli._common import split_scenario
    from lunar_drake.scenario_files import apply_overrides, dump_scenario, load_scenario

    filename, name = split_scenario(study.scenario)
    try:
        base = load_scenario(filename=filename, scenario_name=name,
                             scenario_text=study.scenario_text)  # fmt: skip
        quick_tree = {}
        if quick:  # checked here; applied over each case's factors (the quick form wins)
            apply_overrides(base, study.quick_text, source="quick.scenario_text")
            quick_tree = yaml.safe_load(study.quick_text) or {}
    except LunarDrakeError as exc:
        line = study.lines.get("quick" if quick else "base")
        raise _err(study.source, line, f"base scenario: {exc}") from None
    base_data = yaml.safe_load(dump_scenario(base))
    points = design_points(study)
    reps = (study.quick_replicates or study.replicates[:1]) if quick else study.replicates
    if len(points) * len(reps) > MAX_JOBS:
        raise _err(study.source, study.lines.get("factors"),
                   f"{len(points)} cases x {len(reps)} replicates is more than {MAX_JOBS} runs")
    width = max(4, len(str(len(points) - 1)))
    jobs = []
    for p, point in enumerate(points):
        tree: dict = {}
        for f in study.factors:
            value = point[f.key]
            try:
                if f.named:
                    _merge(tree, f.overrides[value])
                else:
                    _set_dotted(tree, f.key, value, base_data)
            except ConfigError as exc:
                raise _err(study.source, f.line, f"factor {f.key}: {exc}") from None
        _merge(tree, quick_tree)
        for r, seed in enumerate(reps):
            _merge(tree, {"random_seed": seed})
            text = yaml.safe_dump(tree, default_flow_style=False, sort_keys=True)
            try:
                scenario = apply_overrides(copy.deepcopy(base), text, source="factors")
            except LunarDrakeError as exc:
                raise _blame(study, point, exc) from None
            if scenario.ground.goals:  # as ``lunar-drake run``: the route is unused
                scenario.ground.route = []
            resolved = dump_scenario(scenario)
            jobs.append(Job(case=f"c{p:0{width}d}", replicate=r, seed=seed, factors=point,
                            scenario_yaml=resolved, key=scenario_key(resolved)))  # fmt: skip
    return jobs


def _blame(study: Study, point: dict, exc: Exception) -> ConfigError:
    """The error of a refused case, put on the line of the factor it names."""
    msg = _SOURCE_PREFIX.sub("", str(exc))
    for f in study.factors:
        top = f.key.split(".")[0].split("[")[0]
        if f.named:
            keys = _leaf_keys(f.overrides[point[f.key]])
            if any(k in msg for k in keys):
                return _err(study.source, f.line, f"factor {f.key} = {point[f.key]!r}: {msg}")
        elif f.key in msg or f.key.rsplit(".", 1)[-1] in msg or msg.startswith(top):
            return _err(study.source, f.line, f"factor {f.key} = {point[f.key]!r}: {msg}")
    shown = ", ".join(f"{k} = {v!r}" for k, v in point.items())
    return _err(study.source, study.lines.get("factors"), f"case {shown}: {msg}")


def _leaf_keys(tree: dict, prefix: str = "") -> list[str]:
    out = []
    for k, v in tree.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        out += _leaf_keys(v, key) if isinstance(v, dict) else [key, str(k)]
    return out


def resolved_study_text(study: Study, *, quick: bool) -> str:
    """The study file as run (``study.yaml`` beside the results): the original text with
    a header saying whether it was the quick form."""
    head = f"# lunar-drake trade: {study.name}" + (" (--quick)" if quick else "") + "\n"
    return head + study.text.rstrip() + "\n"
