"""Soil parameters by name or from a YAML file.

:func:`load_soil` accepts a preset name (``lunar_regolith``, ``grc1``, ``jsc1a``) or the
path of a YAML soil section, either a mapping of :class:`SoilParams` fields or the same
under a top-level ``soil:`` key (the form a scenario uses and ``slip-fit`` writes).
Fields left out keep :class:`SoilParams`' defaults, as in a scenario. Pure Python (PyYAML);
no Drake.
"""

# No `from __future__ import annotations`: keeps dataclass field types real, like the core.

import dataclasses
from pathlib import Path

import yaml

from lunar_drake.dynamics import terramechanics as tm
from lunar_drake.dynamics.terramechanics import JSC1A, SoilParams
from lunar_drake.errors import ConfigError

__all__ = ["JSC1A", "SOIL_NAMES", "load_soil", "soil_yaml"]

SOIL_NAMES = tuple(sorted(tm.SOIL_PRESETS))
"""Preset names :func:`load_soil` knows."""


def _preset(name: str) -> SoilParams:
    try:
        return tm.soil_preset(name)
    except ConfigError:
        raise ConfigError(
            f"soil {name!r} is neither a preset ({', '.join(SOIL_NAMES)}) nor a .yaml/.yml file"
        ) from None


def _from_yaml(path: Path) -> SoilParams:
    if not path.is_file():
        raise ConfigError(f"soil file {str(path)!r} does not exist")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"soil file {str(path)!r} cannot be read: {exc}") from None
    except yaml.YAMLError as exc:
        msg = " ".join(str(exc).split())
        raise ConfigError(f"soil file {str(path)!r} is not valid YAML: {msg}") from None
    if isinstance(data, dict) and set(data) == {"soil"}:
        data = data["soil"]
    if not isinstance(data, dict) or not data:
        raise ConfigError(
            f"soil file {str(path)!r} must hold a mapping of soil parameters (optionally "
            "under 'soil:')"
        )
    fields = {f.name for f in dataclasses.fields(SoilParams)}
    unknown = sorted(str(k) for k in data if k not in fields)
    if unknown:
        raise ConfigError(
            f"soil file {str(path)!r}: unknown key {unknown[0]!r}; allowed keys: "
            f"{', '.join(sorted(fields))}"
        )
    try:
        return dataclasses.replace(SoilParams(), **data)  # validates every field
    except ConfigError as exc:
        raise ConfigError(f"soil file {str(path)!r}: {exc}") from None


def load_soil(spec) -> SoilParams:
    """A new :class:`SoilParams` from a preset name (case-insensitive: lunar_regolith,
    grc1, jsc1a) or a YAML file path (``.yaml``/``.yml``, or any existing file); a
    ``SoilParams`` is validated and copied.

    Raises:
        ConfigError: unknown name, missing or unreadable file, bad YAML, unknown key, or a
            value out of range (the message names the file and the key).
    """
    if isinstance(spec, SoilParams):
        spec.validate()
        return dataclasses.replace(spec)
    if not isinstance(spec, (str, Path)) or not str(spec).strip():
        raise ConfigError(f"soil = {spec!r} must be a preset name or a YAML file path")
    text = str(spec)
    if text.endswith((".yaml", ".yml")) or isinstance(spec, Path) or Path(text).is_file():
        return _from_yaml(Path(text))
    return _preset(text)


def soil_yaml(soil: SoilParams, *, comment: str = "") -> str:
    """YAML text of ``soil`` as a ``soil:`` section (angles in rad, SI units), loadable by
    :func:`load_soil`, ``lunar-drake run --soil`` and as a scenario's ``soil`` section;
    ``comment`` lines go on top as ``#`` comments."""
    soil.validate()
    head = "".join(f"# {line}\n" if line else "#\n" for line in comment.splitlines())
    body = {
        k: (float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v)
        for k, v in dataclasses.asdict(soil).items()
    }
    return head + yaml.safe_dump({"soil": body}, sort_keys=False, default_flow_style=False)
