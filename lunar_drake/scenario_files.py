"""Loading and writing scenarios: named scenarios, overrides, and clear errors.

Two file layouts are read:

* a *scenario file* holds named scenarios at its top level (see
  ``lunar_drake/scenarios/default.yaml``); ``FILE.yaml:NAME`` picks one;
* a *run's* ``scenario.yaml`` is one bare scenario (its top-level keys are
  :class:`~lunar_drake.scenario.Scenario` fields), as :func:`dump_scenario` writes it,
  so ``lunar-drake run --scenario RUN/scenario.yaml`` reproduces that run.

Before Drake's ``yaml_load_typed`` sees a document it is parsed with PyYAML's safe
loader (YAML never executes code) and walked against the schema, so a malformed file, a
Python tag or an unknown key (at any depth) is a one-line
:class:`~lunar_drake.errors.ConfigError` naming the file, the line and the full key
(``rover.description.wheel_radius``). A value out of range after the merge is named
with the file (or ``--scenario-text``) and line that wrote it last. Relative paths in
``terrain.dem``, ``lighting.extra_kernels`` and a soil file named by
``flight.estimator.slip_calibration`` are resolved against the scenario file's
directory, so the written ``scenario.yaml`` holds absolute paths.
"""

from __future__ import annotations

import dataclasses as dc
import re
import typing
from importlib import resources
from pathlib import Path

import yaml
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed

from lunar_drake.errors import ConfigError, LunarDrakeError
from lunar_drake.scenario import Scenario, validate_scenario

_STANDARD_TAGS = {
    "tag:yaml.org,2002:" + t for t in ("str", "int", "float", "bool", "null", "map", "seq")
}


def default_scenario_file() -> Path:
    """The scenario file shipped with the package."""
    return Path(str(resources.files("lunar_drake") / "scenarios" / "default.yaml"))


def _where(source: str, node) -> str:
    mark = getattr(node, "start_mark", None)
    return f"{source}, line {mark.line + 1}" if mark is not None else source


def _compose(text: str, source: str):
    """The YAML node tree of ``text`` (safe: nothing is constructed)."""
    try:
        return yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f", line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{source}{line}: malformed YAML: {problem}") from None


def _check_tags(node, source: str) -> None:
    stack = [node]
    while stack:
        n = stack.pop()
        if n.tag not in _STANDARD_TAGS:
            raise ConfigError(
                f"{_where(source, n)}: YAML tag {n.tag!r} is not allowed (scenarios are plain data)"
            )
        if isinstance(n, yaml.MappingNode):
            for k, v in n.value:
                stack += [k, v]
        elif isinstance(n, yaml.SequenceNode):
            stack += list(n.value)


def _schema_fields(schema) -> dict | None:
    """field name -> type of a dataclass or a Drake config class, else None."""
    if dc.is_dataclass(schema):
        hints = typing.get_type_hints(schema)
        return {f.name: hints[f.name] for f in dc.fields(schema)}
    fields = getattr(schema, "__fields__", None)
    if fields is not None and not isinstance(fields, dict):
        return {f.name: f.type for f in fields}
    return None


_YAML_FLOATS = {".nan", ".inf", "+.inf", "-.inf"}


def _check_scalar(node, schema, path: str, source: str) -> None:
    """Raises ConfigError, naming ``path``, for a scalar that is not a number where
    ``schema`` (float or int) wants one, not true or false where it wants a bool, or an
    unquoted number or boolean where it wants text; and for a value that is not a list
    where it wants one."""
    if typing.get_origin(schema) is list and not isinstance(node, yaml.SequenceNode):
        if not (isinstance(node, yaml.ScalarNode) and node.tag.endswith(":null")):
            raise ConfigError(f"{_where(source, node)}: {path} must be a list ([...]), "
                              f"not {_node_text(node)}")  # fmt: skip
        return
    if not isinstance(node, yaml.ScalarNode):
        return
    if schema is bool:
        if not node.tag.endswith(":bool"):
            raise ConfigError(f"{_where(source, node)}: {path} = {node.value!r} must be true "
                              "or false")  # fmt: skip
        return
    if schema is str:
        if node.style is None and node.tag.rsplit(":", 1)[-1] in ("int", "float", "bool"):
            raise ConfigError(f"{_where(source, node)}: {path} = {node.value!r} must be text "
                              "(quote it)")  # fmt: skip
        return
    if schema not in (float, int):
        return
    text = str(node.value).strip()
    if schema is int:
        ok = re.fullmatch(r"[-+]?(\d+|0[xX][0-9a-fA-F]+|0[oO][0-7]+)", text) is not None
    else:
        try:
            float(text)
            ok = True
        except ValueError:
            ok = text.lower() in _YAML_FLOATS
    if not ok:
        kind = "an integer" if schema is int else "a number"
        raise ConfigError(f"{_where(source, node)}: {path} = {node.value!r} must be {kind}")


def _check_keys(node, schema, path: str, source: str) -> None:
    """Raises ConfigError for the first mapping key that ``schema`` does not have, or
    the first scalar that is not a number where one is wanted."""
    fields = _schema_fields(schema)
    if fields is None:
        _check_scalar(node, schema, path, source)
        origin = typing.get_origin(schema)
        if origin is list and isinstance(node, yaml.SequenceNode):
            (item,) = typing.get_args(schema)
            for k, child in enumerate(node.value):
                _check_keys(child, item, f"{path}[{k}]", source)
        return
    if not isinstance(node, yaml.MappingNode):
        if isinstance(node, yaml.ScalarNode) and node.tag.endswith(":null"):
            return
        raise ConfigError(
            f"{_where(source, node)}: {path or 'the scenario'} must be a mapping of keys "
            f"({', '.join(sorted(fields))}), not {_node_text(node)}"
        )
    for key_node, value in node.value:
        key = key_node.value
        full = f"{path}.{key}" if path else str(key)
        if key not in fields:
            raise ConfigError(
                f"{_where(source, key_node)}: unknown key {full!r}; allowed keys"
                f"{' of ' + repr(path) if path else ''}: {', '.join(sorted(fields))}"
            )
        _check_keys(value, fields[key], full, source)


def check_yaml_schema(text: str, schema, *, source: str) -> None:
    """Raises ConfigError, naming the key and its line in ``source``, for a YAML tag,
    a key ``schema`` (a dataclass) does not have, a section that is not a mapping or a
    value that is not a number where one is wanted; before Drake's typed loading, whose
    errors name neither."""
    node = _compose(text, source)
    if node is not None:
        _check_tags(node, source)
        _check_keys(node, schema, "", source)


def _is_bare(node) -> bool:
    """A run's scenario.yaml: a mapping whose keys are Scenario fields."""
    names = {f.name for f in dc.fields(Scenario)}
    return (
        isinstance(node, yaml.MappingNode)
        and bool(node.value)
        and all(k.value in names for k, _ in node.value)
    )


def _read(path: Path) -> str:
    if not path.is_file():
        raise ConfigError(f"scenario file {str(path)!r} does not exist")
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"scenario file {str(path)!r} cannot be read: {exc}") from None


def scenario_names(*, filename: str | Path | None = None) -> list[str]:
    """Names of the scenarios in a scenario file (``[]`` for a run's bare scenario)."""
    path = Path(filename) if filename else default_scenario_file()
    root = _compose(_read(path), str(path))
    if root is None or _is_bare(root):
        return []
    if not isinstance(root, yaml.MappingNode):
        raise ConfigError(f"{path}: a scenario file must map scenario names to scenarios")
    return sorted(k.value for k, _ in root.value)


def _drake_load(*, schema_defaults: Scenario, where: str, **kwargs) -> Scenario:
    try:
        return yaml_load_typed(schema=Scenario, defaults=schema_defaults, **kwargs)
    except Exception as exc:  # Drake raises RuntimeError/TypeError on a bad value
        msg = " ".join(str(exc).split())
        raise ConfigError(f"{where}: invalid value: {msg}") from None


def _resolve_paths(s: Scenario, base: Path) -> None:
    if s.terrain.dem and not Path(s.terrain.dem).is_absolute():
        s.terrain.dem = str((base / s.terrain.dem).resolve())
    s.lighting.extra_kernels = [
        k if Path(k).is_absolute() else str((base / k).resolve()) for k in s.lighting.extra_kernels
    ]
    cal = s.flight.estimator.slip_calibration
    if cal.endswith((".yaml", ".yml")) and not Path(cal).is_absolute():
        s.flight.estimator.slip_calibration = str((base / cal).resolve())


INTERNAL_SCENARIOS = ("Defaults", "OneOfEverything")
"""Test scenarios of the packaged file in Drake's style (``Defaults: {}``: every default;
``OneOfEverything``: every field set), not missions: lists leave them out."""


def _unknown_scenario(name: str, names: list[str], source: str) -> str:
    """The one-line error for a scenario name not in ``names``: the nearest name when
    one is close (case ignored), then the missions to choose from."""
    import difflib

    shown = [n for n in names if n not in INTERNAL_SCENARIOS] or names
    lower = {n.lower(): n for n in shown}
    close = difflib.get_close_matches(name.lower(), list(lower), n=1, cutoff=0.6)
    hint = f"did you mean {lower[close[0]]!r}? " if close else ""
    return f"scenario {name!r} not found in {source!r}; {hint}choose one of {shown}"


def _node_text(node) -> str:
    """A YAML node's value on one line in flow style, comments left out (for error
    messages): ``[12.5, 0]``, ``{a: 1}``, ``'3'``."""
    try:
        value = yaml.safe_load(yaml.serialize(node))
        text = yaml.safe_dump(value, default_flow_style=True, width=1 << 20).strip()
        text = text.removesuffix("...").strip()
        if isinstance(node, yaml.ScalarNode):
            text = repr(node.value)
    except (yaml.YAMLError, ValueError, TypeError):
        text = repr(node.value) if isinstance(node.value, str) else "a YAML collection"
    return text if len(text) <= 80 else text[:77] + "..."


def load_scenario(
    *, filename: str | Path | None = None, scenario_name: str = "default", scenario_text: str = "{}"
) -> Scenario:
    """Loads ``scenario_name`` from ``filename`` (default: the packaged file) -- or the
    bare scenario a run wrote -- applies the ``scenario_text`` YAML overrides and
    validates the result.

    Raises:
        ConfigError: missing or malformed file, a Python tag, an unknown name or key (at
            any depth), a malformed value, or a value out of range.
    """
    path = Path(filename) if filename else default_scenario_file()
    text = _read(path)
    source = str(path)
    root = _compose(text, source)
    if root is not None:
        _check_tags(root, source)
    origin = (source, root)
    if root is not None and _is_bare(root):
        _check_keys(root, Scenario, "", source)
        result = _drake_load(schema_defaults=Scenario(), where=source, data=text)
    else:
        names = scenario_names(filename=path)
        if scenario_name not in names:
            raise ConfigError(_unknown_scenario(scenario_name, names, source))
        node = next(v for k, v in root.value if k.value == scenario_name)
        origin = (source, node)
        _check_keys(node, Scenario, "", f"{source} (scenario {scenario_name!r})")
        result = _drake_load(
            schema_defaults=Scenario(),
            where=f"{source} (scenario {scenario_name!r})",
            filename=str(path),
            child_name=scenario_name,
        )
        if not result.name:
            result.name = scenario_name
    _resolve_paths(result, path.parent)
    result = apply_overrides(result, scenario_text, source="--scenario-text", origins=[origin])
    return result


#: The scenario key an error message starts with (``sensors.nss.height_m = ...``).
_MESSAGE_KEY = re.compile(r"([A-Za-z_]\w*(?:\[\d+\])?(?:\.[A-Za-z_]\w*(?:\[\d+\])?)*)[ :]")
#: Any further dotted scenario key a message names (``... sensors.nirvss.enabled``).
_DOTTED_KEY = re.compile(r"(?<![\w.\[\]])([A-Za-z_]\w*(?:\[\d+\])?(?:\.[A-Za-z_]\w*(?:\[\d+\])?)+)")
#: A key a message names by its short name (``... is above max_ppm = 5``): a lone word
#: holding an underscore, taken as a sibling of the key the message starts with.
_SHORT_KEY = re.compile(r"(?<![\w.\[\]])([a-z]\w*_\w*)(?![\w.\[])")


def _key_line(node: yaml.Node, key: str) -> int | None:
    """The 1-based line of dotted ``key`` (``a.b[2].c``) in YAML mapping ``node``: that
    of the list element holding it where the element is written but the key is left to
    its default; None where it is not written there."""
    element = None
    for part in key.split("."):
        m = re.fullmatch(r"(\w+)(?:\[(\d+)\])?", part)
        if not isinstance(node, yaml.MappingNode):
            return element
        found = next(((k, v) for k, v in node.value if k.value == m[1]), None)
        if found is None:
            return element
        mark_node, node = found
        if m[2] is not None:
            if not isinstance(node, yaml.SequenceNode) or int(m[2]) >= len(node.value):
                return mark_node.start_mark.line + 1
            node = mark_node = node.value[int(m[2])]
            element = mark_node.start_mark.line + 1
    return mark_node.start_mark.line + 1


def _validate_located(scenario: Scenario, origins: list) -> None:
    """:func:`validate_scenario`; an error naming a key written in one of ``origins``
    (``(source, node)``, the last applied first) gets that source and line in front: the
    key the message starts with, else any other it names in full (``a.b``), else one it
    names by its short name beside the first (``a.min_x ... above max_x``: ``a.max_x``)."""
    try:
        validate_scenario(scenario)
    except LunarDrakeError as exc:
        msg = str(exc)
        m = _MESSAGE_KEY.match(msg)
        keys = ([m[1]] if m else []) + [k for k in _DOTTED_KEY.findall(msg) if not m or k != m[1]]
        if m and "." in m[1]:
            parent = m[1].rsplit(".", 1)[0]
            short = (f"{parent}.{w}" for w in _SHORT_KEY.findall(msg))
            keys += [k for k in short if k not in keys]
        for source, node in origins:
            for key in keys if node is not None else ():
                line = _key_line(node, key)
                if line is not None:
                    raise type(exc)(f"{source}, line {line}: {msg}") from None
        raise


def apply_overrides(scenario: Scenario, text: str, *, source: str = "overrides",
                    origins: tuple | list = ()) -> Scenario:  # fmt: skip
    """``scenario`` with the YAML mapping ``text`` merged on top, validated. Relative
    paths in the overrides are resolved against the working directory. A value out of
    range is named with the source and line that wrote it: ``text``'s, else that of
    ``origins`` (``(source, YAML node)`` pairs, the last applied first)."""
    node = _compose(text or "{}", source)
    if node is not None:
        _check_tags(node, source)
        _check_keys(node, Scenario, "", source)
        scenario = _drake_load(schema_defaults=scenario, where=source, data=text)
        _resolve_paths(scenario, Path.cwd())
    _validate_located(scenario, [(source, node), *origins])
    return scenario


def scenario_from_text(text: str) -> Scenario:
    """A validated scenario from a YAML mapping (no name level), over the defaults."""
    return apply_overrides(Scenario(), text, source="scenario text")


def dump_scenario(scenario: Scenario) -> str:
    """YAML text of a scenario (loads back to an equal scenario)."""
    return yaml_dump_typed(scenario)
