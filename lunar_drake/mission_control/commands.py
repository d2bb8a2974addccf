"""Operator commands from the network: parsed and checked here (one line per problem),
applied to the ground's operator API by the live mission, and written down as the
scenario's ``ground.actions`` so the run's ``scenario.yaml`` reproduces them."""

from __future__ import annotations

import math

from lunar_drake.errors import ConfigError
from lunar_drake.scenario import ACTIONS, OperatorAction


class CommandError(ConfigError):
    """A command mission control cannot send (malformed, out of range, refused)."""


#: Each action's arguments: name -> (default or None if required, (lo, hi)).
ARGS = {
    "goal": {"x_m": (None, (-1e6, 1e6)), "y_m": (None, (-1e6, 1e6))},
    "stop": {},
    "resume": {},
    "drive_arc": {"speed_mps": (None, (-1.0, 1.0)), "curvature_per_m": (0.0, (-10.0, 10.0)),
                  "distance_m": (None, (0.0, 1000.0))},
    "point_mast": {"pan_deg": (None, (-180.0, 180.0)), "tilt_deg": (None, (-90.0, 90.0))},
    "drill": {"depth_m": (None, (0.0, 1.0)), "step_m": (0.1, (0.0, 1.0))},
}  # fmt: skip


def parse_command(data) -> dict:
    """A checked command ``{"action": ..., args...}`` from a decoded JSON body.

    Raises:
        CommandError: not an object, an unknown action or argument, a missing or
            non-numeric argument, or one out of range.
    """
    if not isinstance(data, dict):
        raise CommandError(f"a command is a JSON object with an 'action', not {data!r:.80}")
    action = data.get("action")
    if action not in ARGS:
        raise CommandError(f"action {action!r} is unknown; allowed: {', '.join(ARGS)}")
    spec = ARGS[action]
    extra = sorted(set(data) - {"action", "id", *spec})
    if extra:
        allowed = ", ".join(spec) or "none"
        raise CommandError(f"{action}: unknown argument {extra[0]!r}; allowed: {allowed}")
    out = {"action": action}
    for name, (default, bounds) in spec.items():
        value = data.get(name, default)
        if value is None:
            if action == "point_mast":  # neither: back to automatic pointing
                continue
            raise CommandError(f"{action}: argument {name!r} is required")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise CommandError(f"{action}: {name} = {value!r} must be a number")
        try:
            value = float(value)
        except OverflowError:
            value = math.inf
        if not math.isfinite(value):
            raise CommandError(f"{action}: {name} = {value!r} must be finite")
        if bounds is not None and not bounds[0] <= value <= bounds[1]:
            raise CommandError(f"{action}: {name} = {value:g} must be in "
                               f"[{bounds[0]:g}, {bounds[1]:g}]")  # fmt: skip
        out[name] = value
    if action == "point_mast" and len(out) == 2:
        raise CommandError("point_mast: give both pan_deg and tilt_deg, or neither (automatic)")
    if action == "drive_arc" and out["speed_mps"] == 0.0:
        raise CommandError("drive_arc: speed_mps = 0 must be non-zero")
    return out


def apply_command(operator, root, command: dict) -> None:
    """Queues ``command`` (from :func:`parse_command`) on the ground's operator API; the
    ground sends it at its next tick. Raises the API's LunarDrakeError when it refuses."""
    a = command["action"]
    if a == "goal":
        operator.send_goal(root, x_m=command["x_m"], y_m=command["y_m"])
    elif a == "stop":
        operator.stop(root)
    elif a == "resume":
        operator.resume(root)
    elif a == "drive_arc":
        operator.drive_arc(root, speed_mps=command["speed_mps"],
                           curvature_per_m=command["curvature_per_m"],
                           distance_m=command["distance_m"])  # fmt: skip
    elif a == "point_mast":
        if "pan_deg" in command:
            operator.point_mast(root, pan_rad=math.radians(command["pan_deg"]),
                                tilt_rad=math.radians(command["tilt_deg"]))  # fmt: skip
        else:
            operator.point_mast(root)
    elif a == "drill":
        operator.drill(root, depth_m=command["depth_m"], step_m=command["step_m"])


def as_action(command: dict, *, t_s: float) -> OperatorAction:
    """``command`` as a scheduled ``ground.actions`` entry at ``t_s`` (s)."""
    assert command["action"] in ACTIONS
    kw = {k: v for k, v in command.items() if k != "action"}
    if command["action"] == "point_mast" and "pan_deg" not in kw:
        kw["auto"] = True
    return OperatorAction(t_s=float(t_s), action=command["action"], **kw)


def next_tick_s(t_s: float, rate_hz: float) -> float:
    """The first ground tick at or after ``t_s`` (s): when a request queued at ``t_s``
    goes up, and so the time its ``ground.actions`` entry must carry to be applied at the
    same tick, after that tick's own scheduled actions."""
    return math.ceil(float(t_s) * rate_hz - 1e-6) / rate_hz
