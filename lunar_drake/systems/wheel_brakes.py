"""WheelBrakes: parking brakes on the wheel drive joints, as applied generalized forces.

The brake logic is in the pure functions :func:`brake_torque`, :func:`brake_update` and
:func:`brake_stiffness` (numpy only); :class:`WheelBrakes` only moves numbers between
them and the Context.

Model: an elasto-plastic (stiction) brake per drive joint. When engaged it latches the
joint angle ``q_latch`` and applies ``tau = -clip(k (q - q_latch), -T_hold, T_hold)``;
when the spring would exceed the holding torque the latch is dragged along so that
``|q - q_latch| <= T_hold / k`` (the brake slips at ``T_hold``). Released: zero torque;
the latch follows ``q`` (it is re-latched to ``q`` at engagement, so a released brake
need not track it).

Stiffness and stability. The brake torque is computed from the state at the start of a
step and applied explicitly over it, while the drive servo's damping ``kd`` (a pure
velocity servo, kp = 0, holding zero speed) is applied implicitly by the SAP plant.
With wheel spin inertia ``I`` and step ``h``, one step of ``(I + h kd) w' = I w -
h k e``, ``e' = e + h w'`` (``e = q - q_latch``) is stable iff ``h^2 k < 4 I + 2 h
kd``. :func:`brake_stiffness` takes ``k = kd / h``, half the bound's ``2 kd / h`` part
(the inertia part only adds margin): the spin mode then has both eigenvalues of
magnitude ``sqrt(I / (I + h kd))`` (~0.1 for the presets), i.e. it is heavily damped
and settles in a few steps (k = 2e5 N·m/rad for krex2_rp, 3e4 for husky_rp). The
largest elastic deflection, ``T / k``, is 0.13 and 0.09 mrad for the presets' holding
torques: a rim displacement of about 0.03 and 0.015 mm.

The output goes to the plant's *applied generalized force* input, which, unlike
actuation, is not limited by the actuator effort limit: a brake may hold more than the
motor can drive.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import BasicVector, DiscreteStateIndex

from lunar_drake.systems.leaf import Leaf

__all__ = ["WheelBrakes", "brake_stiffness", "brake_torque", "brake_update"]

BRAKE_ENGAGE_THRESHOLD = 0.5
"""A ``brake_command`` at or above this engages the brakes."""


def brake_stiffness(*, drive_kd: float, time_step_s: float) -> float:
    """Brake spring stiffness (N·m/rad): ``kd / h``, half the explicit-application
    stability bound ``2 kd / h + 4 I / h^2`` (module docstring)."""
    if not (drive_kd > 0.0 and time_step_s > 0.0):
        raise ValueError(
            f"drive_kd = {drive_kd!r} and time_step_s = {time_step_s!r} must be positive"
        )
    return float(drive_kd) / float(time_step_s)


def brake_torque(q, latch, *, stiffness: float, holding_torque) -> np.ndarray:
    """Torque of engaged brakes (N·m): ``-clip(k (q - latch), -T, T)`` per joint."""
    return -np.minimum(np.maximum(stiffness * (q - latch), -holding_torque), holding_torque)


def brake_update(
    q, latch, engaged: bool, command: float, *, stiffness: float, holding_torque
) -> tuple[np.ndarray, bool]:
    """Latch angles and engaged flag after one step.

    Args:
        q: joint angles now (rad). latch: latched angles (rad). engaged: brakes engaged
            during the step that ends now. command: brake command (>= 0.5 engages).

    Returns:
        (latch, engaged): on engagement the latch is ``q``; while engaged it is dragged
        to stay within ``T / k`` of ``q`` (the brake slips at the holding torque);
        released, it is ``q``.
    """
    q = np.asarray(q, dtype=np.float64)
    if command < BRAKE_ENGAGE_THRESHOLD or not engaged:
        return q.copy(), bool(command >= BRAKE_ENGAGE_THRESHOLD)
    slack = holding_torque / stiffness
    return q - np.minimum(np.maximum(q - latch, -slack), slack), True


class WheelBrakes(Leaf):
    """Elasto-plastic parking brakes on a rover's drive joints (module docstring).

    .. pydrake_system::

        name: WheelBrakes
        input_ports:
        - brake_command
        - state
        output_ports:
        - generalized_force

    ``brake_command`` (1 value): >= 0.5 engages. ``state``: the plant's state [q; v]
    (``plant.get_state_output_port()``). ``generalized_force`` (``plant.num_velocities()``
    values): connect it to ``plant.get_applied_generalized_force_input_port()``; it is
    zero except at the drive joints' velocity indices.

    Discrete state, updated every ``time_step_s`` (the plant's time step): the latched
    joint angles followed by the engaged flag (0 or 1). The output depends on that state
    and the plant state only (not directly on the command), so engaging takes effect on
    the step after the command arrives. (Drake's discrete plant steps in an unrestricted
    update, applied before discrete updates, so the latch update sees the joint angles
    the next output will be computed from.) A released brake's update and output do no
    work beyond reading the command and the flag.

    Args:
        plant: the finalized MultibodyPlant. rover: its :class:`RoverModel`.
        time_step_s: update period (s); default the plant's time step.
        holding_torque_nm: per-joint holding torque (N·m); default
            ``rover.description.brake_holding_torque_nm()``.
        stiffness_nm_per_rad: brake spring (N·m/rad); default :func:`brake_stiffness`
            of the description's ``drive_kd`` and ``time_step_s``.
        joints: the braked joints (default ``rover.drive_joints``).
    """

    def __init__(
        self,
        *,
        plant,
        rover,
        time_step_s: float | None = None,
        holding_torque_nm: float | None = None,
        stiffness_nm_per_rad: float | None = None,
        joints=None,
    ):
        super().__init__()
        h = plant.time_step() if time_step_s is None else float(time_step_s)
        if not h > 0.0:
            raise ValueError(
                f"time_step_s = {time_step_s!r}: WheelBrakes needs a positive update period "
                "(pass it for a continuous plant)"
            )
        d = rover.description
        joints = list(rover.drive_joints if joints is None else joints)
        n = len(joints)
        self._k = (
            brake_stiffness(drive_kd=d.drive_kd, time_step_s=h)
            if stiffness_nm_per_rad is None
            else float(stiffness_nm_per_rad)
        )
        t = d.brake_holding_torque_nm() if holding_torque_nm is None else holding_torque_nm
        self._t_hold = float(t)
        if not (self._k > 0.0 and self._t_hold >= 0.0):
            raise ValueError(
                f"stiffness {self._k!r} N·m/rad must be > 0 and holding torque "
                f"{self._t_hold!r} N·m >= 0"
            )
        self._n = n
        self._nv = plant.num_velocities()
        self._q_idx = np.array([j.position_start() for j in joints], dtype=np.intp)
        self._v_idx = np.array([j.velocity_start() for j in joints], dtype=np.intp)
        self._zero = np.zeros(self._nv)
        self._xd = self.DeclareDiscreteState(n + 1)  # latch angles, engaged flag
        self.DeclarePeriodicDiscreteUpdateEvent(period_sec=h, offset_sec=0.0, update=self._update)
        self.brake_command_input = self.DeclareVectorInputPort("brake_command", 1)
        self.state_input = self.DeclareVectorInputPort(
            "state", plant.num_positions() + plant.num_velocities()
        )
        self.generalized_force_output = self.DeclareVectorOutputPort(
            "generalized_force",
            BasicVector(self._nv),
            self._calc_force,
            prerequisites_of_calc={
                self.discrete_state_ticket(DiscreteStateIndex(self._xd)),
                self.input_port_ticket(self.state_input.get_index()),
            },
        )

    @property
    def holding_torque_nm(self) -> float:
        """Per-joint holding torque (N·m)."""
        return self._t_hold

    @property
    def stiffness_nm_per_rad(self) -> float:
        """Brake spring stiffness (N·m/rad)."""
        return self._k

    def is_engaged(self, context) -> bool:
        """Whether the brakes are engaged in ``context`` (this system's context)."""
        return bool(context.get_discrete_state(self._xd).GetAtIndex(self._n) >= 0.5)

    def latched_angles(self, context) -> np.ndarray:
        """Latched joint angles (rad) in ``context`` (meaningful while engaged)."""
        return context.get_discrete_state(self._xd).value()[: self._n].copy()

    def _update(self, context, discrete_state):
        command = self.brake_command_input.Eval(context)[0]
        xd = context.get_discrete_state(self._xd).value()
        engaged = xd[self._n] >= 0.5
        if not engaged and command < BRAKE_ENGAGE_THRESHOLD:
            return  # released and staying released: nothing to do (state is unchanged)
        q = self.state_input.Eval(context)[self._q_idx]
        latch, on = brake_update(
            q,
            xd[: self._n],
            engaged,
            command,
            stiffness=self._k,
            holding_torque=self._t_hold,
        )
        out = discrete_state.get_mutable_vector(self._xd).get_mutable_value()
        out[: self._n] = latch
        out[self._n] = 1.0 if on else 0.0

    def _calc_force(self, context, output):
        xd = context.get_discrete_state(self._xd).value()
        if xd[self._n] < 0.5:
            output.SetFromVector(self._zero)
            return
        q = self.state_input.Eval(context)[self._q_idx]
        f = output.get_mutable_value()
        f[:] = 0.0
        f[self._v_idx] = brake_torque(
            q, xd[: self._n], stiffness=self._k, holding_torque=self._t_hold
        )
