"""PowerSystem: the rover's solar array, battery and loads (the power core in a Context).

The physics is in :mod:`lunar_drake.power` (numpy, no Drake):
:func:`~lunar_drake.power.solar_array.array_output`,
:func:`~lunar_drake.power.battery.battery_step` and
:func:`~lunar_drake.power.loads.mean_load_breakdown`; this system only moves numbers
between them and the Context.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import AbstractParameterIndex, EventStatus

from lunar_drake.power.battery import battery_step
from lunar_drake.power.config import PowerConfig
from lunar_drake.power.loads import mean_load_breakdown
from lunar_drake.power.solar_array import PanelMount, array_output
from lunar_drake.render.horizon import HorizonMask
from lunar_drake.systems.leaf import Leaf
from lunar_drake.terrain.heightfield import Heightfield

__all__ = ["MEASUREMENT_FIELDS", "TRUTH_FIELDS", "PowerSystem"]

#: Columns of the ``truth`` output (and of ``power.csv`` after ``t_s``).
TRUTH_FIELDS = ("sun_incidence_deg", "visible_fraction", "array_W", "load_W", "soc")
#: Columns of the ``measurement`` output (what the power electronics report on board).
MEASUREMENT_FIELDS = ("soc", "array_W", "load_W")

# Discrete state layout.
_SOC, _INCIDENCE, _FRACTION, _ARRAY, _LOAD, _DRIVE_J, _STEER_J, _BRAKED = range(8)
_STATE_SIZE = 8


class PowerSystem(Leaf):
    """The rover's electrical power: solar array, battery, loads (issue 30).

    .. pydrake_system::

        name: PowerSystem
        input_ports:
        - body_poses
        - sun_direction_W
        - sun_distance_km
        - heightfield
        - drive_energy
        - steer_energy
        - brake_command
        output_ports:
        - truth
        - measurement

    Inputs: the plant's body poses (``chassis_body_index`` carries the panel, mounted as
    ``mount`` says), the ephemeris' ``sun_direction_W`` (unit, site frame W) and
    ``sun_distance_km``, the site raster (the terrain horizon from the panel's height;
    terrain outside the raster is ``horizon_mask``, by default a level horizon at 0 deg
    as in the camera's lightmaps), the positive mechanical work done so far by the drive
    and the steering motors (J; :class:`~lunar_drake.systems.energy_meter.EnergyMeter`,
    integrated at the plant's step) and the brake command (>= 0.5: braked, the holding
    draw).

    A periodic discrete update every ``config.period_s`` (first at ``period_s``):

    1. the loads over the period just ended
       (:func:`~lunar_drake.power.loads.mean_load_breakdown`): the constant draws, the
       motors' work over the period at their efficiencies, and the holding draw when the
       brakes were commanded at its start (sampled and held);
    2. the battery steps over the period with the array power held since the last update
       minus that load (:func:`~lunar_drake.power.battery.battery_step`);
    3. the array is evaluated at the chassis pose and the Sun now
       (:func:`~lunar_drake.power.solar_array.array_output`) and held for the next period.

    An initialization event evaluates the array at t = 0.

    Outputs (of the discrete state: a zero-order hold of the last update):

    * ``truth`` (5): :data:`TRUTH_FIELDS` -- the angle between the Sun's centre and the
      panel normal (deg), the visible fraction of the solar disk, the array power (W),
      the mean load over the last period (W; before the first update the constant draws
      and the holding draw), the state of charge.
    * ``measurement`` (3): :data:`MEASUREMENT_FIELDS` -- SOC, array and load power as the
      power electronics report them (ideal: no noise, no delay).

    The config (:class:`~lunar_drake.power.config.PowerConfig`) is an abstract
    parameter: a Context may change cells, battery or loads without a rebuild (the
    initial SOC takes effect at initialization); its ``period_s`` and the panel mount are
    fixed at construction.

    Args:
        config: the power system. mount: the panel on the chassis.
        chassis_body_index: the plant BodyIndex of the chassis.
        horizon_mask: terrain outside the raster (default ``HorizonMask.level(0.0)``).
    """

    def __init__(
        self,
        *,
        config: PowerConfig,
        mount: PanelMount,
        chassis_body_index,
        horizon_mask: HorizonMask | None = None,
    ):
        super().__init__()
        config.validate()
        self._mount = mount
        self._body = int(chassis_body_index)
        self._period = float(config.period_s)
        self._mask = HorizonMask.level(0.0) if horizon_mask is None else horizon_mask

        self._config_index = self.DeclareAbstractParameter(AbstractValue.Make(config))
        self.body_poses_input = self.DeclareAbstractInputPort(
            "body_poses", AbstractValue.Make([RigidTransform()])
        )
        self.sun_direction_input = self.DeclareVectorInputPort("sun_direction_W", 3)
        self.sun_distance_input = self.DeclareVectorInputPort("sun_distance_km", 1)
        self.heightfield_input = self.DeclareAbstractInputPort(
            "heightfield",
            AbstractValue.Make(Heightfield.from_array(np.zeros((4, 4)), resolution_m=1.0)),
        )
        self.drive_energy_input = self.DeclareVectorInputPort("drive_energy", 1)
        self.steer_energy_input = self.DeclareVectorInputPort("steer_energy", 1)
        self.brake_command_input = self.DeclareVectorInputPort("brake_command", 1)

        x0 = np.zeros(_STATE_SIZE)
        x0[_SOC] = config.battery.initial_soc
        self._state = self.DeclareDiscreteState(x0)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)
        self.DeclarePeriodicDiscreteUpdateEvent(self._period, self._period, self._update)

        xd = {self.discrete_state_ticket(self._state)}
        self.truth_output = self.DeclareVectorOutputPort(
            "truth", len(TRUTH_FIELDS), self._calc_truth, prerequisites_of_calc=xd
        )
        self.measurement_output = self.DeclareVectorOutputPort(
            "measurement", len(MEASUREMENT_FIELDS), self._calc_measurement,
            prerequisites_of_calc=xd,
        )  # fmt: skip

    @property
    def mount(self) -> PanelMount:
        """The panel on the chassis."""
        return self._mount

    def get_config(self, context) -> PowerConfig:
        """The power config in ``context`` (this system's context)."""
        index = AbstractParameterIndex(self._config_index)
        return context.get_abstract_parameter(index).get_value()

    def set_config(self, context, config: PowerConfig) -> None:
        """Replaces the power config in ``context`` (``period_s`` stays the built one)."""
        config.validate()
        index = AbstractParameterIndex(self._config_index)
        context.get_mutable_abstract_parameter(index).set_value(config)

    # ------------------------------------------------------------------ the core's calls

    def _array(self, context, config: PowerConfig, x: np.ndarray) -> None:
        """Evaluates the array now into ``x`` (incidence, visible fraction, power)."""
        X_WB = self.body_poses_input.Eval(context)[self._body]
        R_WB, p_WB = X_WB.rotation().matrix(), X_WB.translation()
        hf = self.heightfield_input.Eval(context)
        _, p_WP = self._mount.pose_in_world(R_WB=R_WB, p_WB=p_WB)
        b = hf.bounds
        on = b.left <= p_WP[0] <= b.right and b.bottom <= p_WP[1] <= b.top
        out = array_output(
            config=config.array,
            mount=self._mount,
            R_WB=R_WB,
            p_WB=p_WB,
            sun_direction_W=self.sun_direction_input.Eval(context),
            sun_distance_km=float(self.sun_distance_input.Eval(context)[0]),
            heightfield=hf if on else None,  # off the raster: only the outside horizon
            horizon_mask=self._mask,
        )
        x[_INCIDENCE] = out.incidence_deg
        x[_FRACTION] = out.visible_fraction
        x[_ARRAY] = out.power_W

    def _braked(self, context) -> float:
        return 1.0 if self.brake_command_input.Eval(context)[0] >= 0.5 else 0.0

    # ------------------------------------------------------------------------- events

    def _initialize(self, context, discrete_state):
        config = self.get_config(context)
        x = np.zeros(_STATE_SIZE)
        x[_SOC] = config.battery.initial_soc
        x[_DRIVE_J] = self.drive_energy_input.Eval(context)[0]
        x[_STEER_J] = self.steer_energy_input.Eval(context)[0]
        x[_BRAKED] = self._braked(context)
        x[_LOAD] = mean_load_breakdown(
            config=config.loads, dt_s=self._period, braked=bool(x[_BRAKED])
        ).total_W
        self._array(context, config, x)
        discrete_state.set_value(self._state, x)
        return EventStatus.Succeeded()

    def _update(self, context, discrete_state):
        config = self.get_config(context)
        x = context.get_discrete_state(self._state).get_value().copy()
        drive_J = self.drive_energy_input.Eval(context)[0]
        steer_J = self.steer_energy_input.Eval(context)[0]
        load = mean_load_breakdown(
            config=config.loads,
            dt_s=self._period,
            drive_work_J=max(drive_J - x[_DRIVE_J], 0.0),
            steer_work_J=max(steer_J - x[_STEER_J], 0.0),
            braked=bool(x[_BRAKED]),
        ).total_W
        step = battery_step(
            config=config.battery, soc=x[_SOC], net_power_W=x[_ARRAY] - load, dt_s=self._period
        )
        x[_SOC], x[_LOAD] = step.soc, load
        x[_DRIVE_J], x[_STEER_J] = drive_J, steer_J
        x[_BRAKED] = self._braked(context)
        self._array(context, config, x)
        discrete_state.set_value(self._state, x)
        return EventStatus.Succeeded()

    # ------------------------------------------------------------------------ outputs

    def _calc_truth(self, context, output):
        x = context.get_discrete_state(self._state).get_value()
        output.SetFromVector(x[[_INCIDENCE, _FRACTION, _ARRAY, _LOAD, _SOC]])

    def _calc_measurement(self, context, output):
        x = context.get_discrete_state(self._state).get_value()
        output.SetFromVector(x[[_SOC, _ARRAY, _LOAD]])
