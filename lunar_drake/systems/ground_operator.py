"""GroundOperator (ground "operator command source" and "planning"): goals, replanning,
operator requests and the ground's pose estimate (:mod:`lunar_drake.autonomy.operations`)."""

from __future__ import annotations

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector

from lunar_drake.autonomy.operations import (
    TOPIC,
    OperatorParams,
    OperatorState,
    Request,
    corrected_pose,
    goal_shift_limit_m,
    ground_pose,
    operator_step,
)
from lunar_drake.autonomy.planner import path_blocked
from lunar_drake.errors import OutOfBoundsError, OutOfRangeError
from lunar_drake.systems.leaf import Leaf


class GroundOperator(Leaf):
    """The ground's operations software.

    .. pydrake_system::

        name: GroundOperator
        input_ports:
        - telemetry
        - pose_correction
        - pose_sigma
        - costmap
        output_ports:
        - commands
        - pose_estimate
        - preview

    ``telemetry`` is the downlink inbox (deliveries of telemetry packets). Every
    1 / ``rate_hz`` s it runs :func:`~lunar_drake.autonomy.operations.operator_step`
    with the requests due: the scenario's ``actions`` whose time has come, and those
    queued from Python (:meth:`send_goal`, :meth:`stop`, :meth:`resume`,
    :meth:`drive_arc`, :meth:`point_mast`, between ``AdvanceTo`` calls). ``commands`` is
    the uplink outbox (the messages made at the latest tick); ``pose_estimate`` (6,) the
    ground's estimate of the rover's pose (x, y, z, roll, pitch, yaw; m, rad; site
    frame) from the newest telemetry carried forward to now. Optional inputs from the
    ground's perception (:class:`~lunar_drake.systems.ground_perception.
    GroundPerception`): ``pose_correction`` (dx, dy, dyaw) applied to that estimate,
    ``pose_sigma`` (1,) its position sigma (m; goals are judged with it), and
    ``costmap`` ((version, Costmap)): plans are made on it and, when its version
    changes, the path being driven is checked against it (replanned if a new hazard
    blocks it). ``preview`` (abstract): (goto seq, (N, 4) array of t, x, y, z) the
    predicted path of the newest goto sent (``preview`` argument: ``preview(pose,
    waypoints)``; (-1, None) before). State (abstract): the OperatorState and the Python
    requests waiting for the next tick.

    Args:
        params: :class:`~lunar_drake.autonomy.operations.OperatorParams`.
        rate_hz: ground tick (Hz).
        planner: ``planner(start_xy, goal_xy)`` -> waypoints (the ground's map and
            planner; raises a LunarDrakeError for a goal it cannot serve).
        start_pose: (x, y, yaw) the spawn pose (m, rad), known to operations.
        actions: ((t_s, Request), ...) scheduled requests, sorted by time.
        in_map: ``in_map(x, y)`` -> True if the point is on the ground's map (checked
            by :meth:`send_goal`).
        preview: ``preview(pose, waypoints)`` -> predicted path of a goto (the command
            preview), or None.
        costmap: the a-priori costmap ``planner`` plans on, or None; kept as
            :attr:`prior_costmap` for the run's logs and plots (plans go through
            ``planner``).
        sun_azimuth: ``sun_azimuth(t_s)`` -> the Sun's azimuth (rad, counter-clockwise
            from the site frame's +x; the ground's ephemeris) sent with each goto for
            the ``sun`` heading policy, or None (``path``: gotos carry none).
    """

    def __init__(self, *, params: OperatorParams, rate_hz: float, planner, start_pose,
                 actions=(), in_map=None, preview=None, costmap=None,
                 sun_azimuth=None):  # fmt: skip
        super().__init__()
        self._sun_azimuth = sun_azimuth
        self.prior_costmap = costmap
        self._params = params
        self._planner = planner
        self._start = tuple(float(v) for v in start_pose)
        self._actions = tuple(sorted(actions, key=lambda a: a[0]))
        self._in_map = in_map
        self._preview = preview
        self.telemetry_input = self.DeclareAbstractInputPort("telemetry", AbstractValue.Make(()))
        self.pose_correction_input = self.DeclareVectorInputPort("pose_correction", 3)
        self.pose_sigma_input = self.DeclareVectorInputPort("pose_sigma", 1)
        self.costmap_input = self.DeclareAbstractInputPort("costmap", AbstractValue.Make((0, None)))
        # (OperatorState, index of the next scheduled action, Python requests)
        self._state = self.DeclareAbstractState(AbstractValue.Make((OperatorState(), 0, ())))
        self.DeclarePeriodicUnrestrictedUpdateEvent(1.0 / rate_hz, 0.0, self._update)
        self.commands_output = self.DeclareAbstractOutputPort(
            TOPIC,
            lambda: AbstractValue.Make(()),
            lambda c, o: o.set_value(self.operator_state(c).outbox),
            prerequisites_of_calc={self.all_state_ticket()},
        )
        self.preview_output = self.DeclareAbstractOutputPort(
            "preview",
            lambda: AbstractValue.Make((-1, None)),
            lambda c, o: o.set_value(self.operator_state(c).preview),
            prerequisites_of_calc={self.all_state_ticket()},
        )
        self.pose_estimate_output = self.DeclareVectorOutputPort(
            "pose_estimate",
            BasicVector(6),
            self._calc_pose,
            prerequisites_of_calc={self.time_ticket(), self.all_state_ticket()},
        )

    @property
    def params(self) -> OperatorParams:
        """The ground's settings."""
        return self._params

    # ----------------------------------------------------------------- the operator API

    def operator_state(self, context) -> OperatorState:
        """The OperatorState in ``context`` (this system's context or the root's):
        goals and their status, the ``events`` ledger."""
        return self._own(context).get_abstract_state(self._state).get_value()[0]

    def send_goal(self, context, *, x_m: float, y_m: float) -> None:
        """Queues a goal (site frame, m); driven after those before it."""
        x, y = float(x_m), float(y_m)
        if not (math.isfinite(x) and math.isfinite(y)):
            raise OutOfRangeError(f"goal ({x_m!r}, {y_m!r}) m must be finite")
        if self._in_map is not None and not self._in_map(x, y):
            raise OutOfBoundsError(f"goal ({x:.2f}, {y:.2f}) m is off the ground's map")
        self._request(context, Request("goal", (x, y)))

    def stop(self, context) -> None:
        """Stops the rover and pauses goal driving."""
        self._request(context, Request("stop"))

    def resume(self, context) -> None:
        """Resumes a stopped or safed rover and continues the goals from the estimate."""
        self._request(context, Request("resume"))

    def drive_arc(self, context, *, speed_mps: float, curvature_per_m: float = 0.0,
                  distance_m: float) -> None:  # fmt: skip
        """Drives an arc: ``speed_mps`` (negative: backwards), ``curvature_per_m``
        (positive: left), for ``distance_m`` of path."""
        v, k, d = float(speed_mps), float(curvature_per_m), float(distance_m)
        if not (math.isfinite(v) and 0.0 < abs(v) <= 1.0):
            raise OutOfRangeError(f"speed_mps = {speed_mps!r} must be in [-1, 0) or (0, 1] m/s")
        if not (math.isfinite(k) and abs(k) <= 10.0):
            raise OutOfRangeError(f"curvature_per_m = {curvature_per_m!r} must be in [-10, 10]")
        if not (math.isfinite(d) and 0.0 < d <= 1000.0):
            raise OutOfRangeError(f"distance_m = {distance_m!r} must be in (0, 1000] m")
        self._request(context, Request("drive_arc", (v, k, d)))

    def point_mast(self, context, *, pan_rad: float | None = None,
                   tilt_rad: float | None = None) -> None:  # fmt: skip
        """Holds the mast at (pan, tilt) rad; with neither given, returns it to the
        flight software's own pointing."""
        if pan_rad is None and tilt_rad is None:
            self._request(context, Request("point_mast"))
            return
        pan, tilt = float(pan_rad or 0.0), float(tilt_rad or 0.0)
        if not (math.isfinite(pan) and math.isfinite(tilt)):
            raise OutOfRangeError(f"pan_rad, tilt_rad = {pan_rad!r}, {tilt_rad!r} must be finite")
        self._request(context, Request("point_mast", (pan, tilt)))

    def drill(self, context, *, depth_m: float, step_m: float = 0.1) -> None:
        """Drills at the rover's stop: samples every ``step_m`` down to ``depth_m`` (m, at
        most 1 m), read by NIRVSS (``drill.csv``). Send it while the rover waits."""
        from lunar_drake.science.drill import check_drill_request

        check_drill_request(float(depth_m), float(step_m))
        self._request(context, Request("drill", (float(depth_m), float(step_m))))

    # ------------------------------------------------------------------------ internals

    def _own(self, context):
        return self.own_context(context)

    def _request(self, context, request: Request) -> None:
        own = self.own_mutable_context(context)
        st, k, reqs = own.get_abstract_state(self._state).get_value()
        own.get_mutable_abstract_state(self._state).set_value((st, k, (*reqs, request)))

    def _calc_pose(self, context, output):
        st = self.operator_state(context)
        if st.packet is None:
            x, y, yaw = self._start
            output.SetFromVector([x, y, 0.0, 0.0, 0.0, yaw])
            return
        pose = ground_pose(st.packet, st.t_sent, context.get_time(),
                           max_extrapolation_s=self._params.max_extrapolation_s)  # fmt: skip
        output.SetFromVector(corrected_pose(pose, self._correction(context)))

    def _correction(self, context):
        if not self.pose_correction_input.HasValue(context):
            return (0.0, 0.0, 0.0)
        return tuple(self.pose_correction_input.Eval(context))

    def _sigma(self, context) -> float:
        if not self.pose_sigma_input.HasValue(context):
            return 0.0
        return float(self.pose_sigma_input.Eval(context)[0])

    def _update(self, context, state):
        now = context.get_time()
        st, k, reqs = context.get_abstract_state(self._state).get_value()
        due = []
        while k < len(self._actions) and self._actions[k][0] <= now + 1e-9:
            due.append(self._actions[k][1])
            k += 1
        planner, version, blocked = self._planner, 0, None
        if self.costmap_input.HasValue(context):
            version, costmap = self.costmap_input.Eval(context)
            if costmap is not None:
                planner = plan_waypoints(
                    costmap, goal_free_radius_m=goal_shift_limit_m(self._params)
                )

                def blocked(path, xy, costmap=costmap):
                    return path_blocked(costmap=costmap, path_xy=path, from_xy=xy)

        st = operator_step(
            st,
            self.telemetry_input.Eval(context),
            now=now,
            params=self._params,
            planner=planner,
            start_pose=self._start,
            requests=(*due, *reqs),
            correction=self._correction(context),
            sigma_m=self._sigma(context),
            map_version=int(version),
            blocked=blocked,
            preview=self._preview,
            sun_azimuth=self._sun_azimuth,
        )
        state.get_mutable_abstract_state(self._state).set_value((st, k, ()))


def plan_waypoints(costmap, *, goal_free_radius_m: float = 0.0):
    """A planner for :class:`GroundOperator` on ``costmap``
    (:func:`~lunar_drake.autonomy.planner.plan_path`; a goal inside a hazard moved to
    the nearest free cell within ``goal_free_radius_m``)."""
    from lunar_drake.autonomy.planner import plan_path

    def planner(start_xy, goal_xy):
        path = plan_path(costmap=costmap, start_xy=start_xy, goal_xy=goal_xy,
                         start_free_radius_m=1.0,
                         goal_free_radius_m=goal_free_radius_m)  # fmt: skip
        return [tuple(map(float, p)) for p in np.asarray(path.waypoints_xy)]

    return planner
