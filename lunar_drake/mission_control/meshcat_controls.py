"""Commanding from Meshcat: Drake's Meshcat buttons (stop, resume, drive an arc) and
sliders (arc speed and curvature) during a live mission, as an
:data:`~lunar_drake.simulation.Observer`. Each click goes through the same operator API
as the page's commands and is written down as a ``ground.actions`` entry."""

from __future__ import annotations

from lunar_drake.errors import LunarDrakeError
from lunar_drake.mission_control.commands import apply_command, as_action, next_tick_s

BUTTONS = {"Stop rover": {"action": "stop"}, "Resume rover": {"action": "resume"},
           "Drive arc (2 m)": {"action": "drive_arc"}}  # fmt: skip
SPEED, CURVATURE = "Arc speed (m/s)", "Arc curvature (1/m, + left)"


class MeshcatControls:
    """Adds the controls to ``meshcat`` and applies their clicks between steps.

    ``actions`` collects the commands applied (OperatorActions); ``log`` their outcome
    lines (a refusal is printed too)."""

    def __init__(self, meshcat, *, echo=print):
        self.meshcat = meshcat
        self.echo = echo
        self.actions: list = []
        self._clicks = {}
        for name in BUTTONS:
            meshcat.AddButton(name)
            self._clicks[name] = 0
        meshcat.AddSlider(SPEED, -0.3, 0.3, 0.05, 0.2)
        meshcat.AddSlider(CURVATURE, -1.0, 1.0, 0.05, 0.0)

    def __call__(self, run) -> None:
        for name, cmd in BUTTONS.items():
            n = self.meshcat.GetButtonClicks(name)
            if n <= self._clicks[name]:
                continue
            self._clicks[name] = n
            cmd = dict(cmd)
            if cmd["action"] == "drive_arc":
                cmd.update(speed_mps=self.meshcat.GetSliderValue(SPEED),
                           curvature_per_m=self.meshcat.GetSliderValue(CURVATURE),
                           distance_m=2.0)  # fmt: skip
            try:
                apply_command(run.operator, run.root, cmd)
            except LunarDrakeError as exc:
                self.echo(f"Meshcat: {name} refused: {exc}")
                continue
            self.actions.append(as_action(cmd, t_s=next_tick_s(run.time_s,
                                                               run.scenario.ground.rate_hz)))
            self.echo(f"Meshcat: {name} at t = {run.time_s:.1f} s")
        return None
