"""``lunar-drake scenarios``: the named scenarios of a scenario file, one line each."""

from __future__ import annotations

import re
from pathlib import Path

from lunar_drake.cli._common import add_subcommand
from lunar_drake.scenario_files import INTERNAL_SCENARIOS  # hidden unless --all

#: Longest description, in characters, before it is cut at a clause or word.
DESCRIPTION_CHARS = 72


def comment_descriptions(text: str) -> dict:
    """{top-level key: the comment block right above it, as one line} of a YAML text
    (keys with no comment above them are left out)."""
    lines = text.splitlines()
    out = {}
    for i, line in enumerate(lines):
        m = re.match(r"^([A-Za-z_][\w.-]*)\s*:", line)
        if not m:
            continue
        j = i
        while j > 0 and lines[j - 1].startswith("#"):
            j -= 1
        if j < i:
            out[m.group(1)] = " ".join(s.lstrip("#").strip() for s in lines[j:i])
    return out


def short_description(comment: str, *, limit: int = DESCRIPTION_CHARS) -> str:
    """The first sentence of ``comment``, cut to ``limit`` characters at the last clause
    break (": ", "; ", ", ", " (") that leaves at least half of it, else at a word
    ("...")."""
    text = " ".join(comment.split())
    m = re.search(r"\.(\s|$)", text)
    text = text[: m.start()] if m else text
    if len(text) <= limit:
        return text
    cuts, depth = [], 0
    for i, ch in enumerate(text[: limit + 1]):
        depth += (ch == "(") - (ch == ")")
        if depth == 0 and (text[i : i + 2] in (": ", "; ", ", ", " (")) and i >= limit // 2:
            cuts.append(i)
    if cuts:
        return text[: cuts[-1]]
    return text[: limit - 3].rsplit(" ", 1)[0] + "..."


def scenario_facts(raw) -> str:
    """What a scenario does, from its YAML mapping ``raw`` over the schema's defaults
    (the keys it sets replace them, as the loader does): simulated time, goals or route
    (and the ground's map when it plans), cameras, science instruments."""
    from lunar_drake.scenario import Scenario

    d = Scenario()

    def get(path: str, default):
        node = raw
        for key in path.split("."):
            if not isinstance(node, dict) or key not in node:
                return default
            node = node[key]
        return node

    facts = [f"{float(get('simulation_duration', d.simulation_duration)):g} s"]
    goals = get("ground.goals", d.ground.goals) or []
    if goals:
        source = get("ground.map.source", d.ground.map.source)
        facts.append(f"{len(goals)} goal{'s' if len(goals) != 1 else ''} on the {source} map")
    elif get("ground.route", d.ground.route):
        facts.append("open-loop route")
    cam = get("sensors.camera.enabled", d.sensors.camera.enabled)
    facts.append("cameras" if cam else "no cameras")
    for n in ("nss", "nirvss"):
        if get(f"sensors.{n}.enabled", getattr(d.sensors, n).enabled):
            facts.append(n.upper())
    return ", ".join(facts)


def listing(filename=None, *, show_all: bool = False) -> list[str]:
    """The lines ``lunar-drake scenarios`` prints: ``NAME  description [facts]`` per
    scenario in file order, the internal test scenarios (:data:`INTERNAL_SCENARIOS`)
    only with ``show_all`` (marked), and a last line saying how to see them."""
    import yaml

    from lunar_drake.scenario_files import default_scenario_file, scenario_names

    path = Path(filename) if filename else default_scenario_file()
    names = set(scenario_names(filename=path))  # checks the file (one-line errors)
    text = path.read_text()
    raw = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader)) or {}
    if not names:
        facts = scenario_facts(raw)
        return [f"{path} holds one bare scenario (a run's scenario.yaml) [{facts}]"]
    comments = comment_descriptions(text)
    order = [k for k in comments if k in names]
    order += sorted(names - set(order))
    hidden = [n for n in order if n in INTERNAL_SCENARIOS]
    shown = order if show_all else [n for n in order if n not in INTERNAL_SCENARIOS]
    width = max(len(n) for n in shown) if shown else 0
    lines = []
    for n in shown:
        desc = short_description(comments.get(n, "")) or "(no description)"
        if n in INTERNAL_SCENARIOS:
            desc = f"(internal test scenario) {desc}"
        facts = scenario_facts(raw.get(n) or {})
        lines.append(f"{n:<{width}}  {desc} [{facts}]")
    if hidden and not show_all:
        lines.append(f"({', '.join(hidden)}: internal test scenarios; --all lists them)")
    return lines


def command(args) -> int:
    for line in listing(args.file, show_all=args.all):
        print(line)
    return 0


def add_parser(sub) -> None:
    sc = add_subcommand(
        sub, "scenarios", help="list the named scenarios of a file, each with what it does"
    )
    sc.add_argument(
        "file", nargs="?", default=None, help="a scenario file (default: the packaged one)"
    )
    sc.add_argument(
        "--all",
        action="store_true",
        help="also the internal test scenarios (Defaults, OneOfEverything)",
    )
    sc.set_defaults(func=command)
