"""The template MPC's receding horizon (``TemplateMpc``): SRB problem -> warm start -> MS-iLQR ->
``TemplatePlan``, with its delay compensation (``TemplateMpc.predict_start``); the problem is
``planners.template.problem``'s.
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.config import MpcSettings
from cafe_mpc.core.plan import interval_at
from cafe_mpc.planners.base import RecedingHorizonPlanner
from cafe_mpc.planners.template.plan import TemplatePlan
from cafe_mpc.planners.template.problem import TemplateProblem, TemplateProblemBuilder
from cafe_mpc.planners.time_grid import TIME_QUANTUM, PiecewiseTrajectory, quanta
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot
from cafe_mpc.solver import MSiLQRSolver, SolverResult


class TemplateMpc(RecedingHorizonPlanner[TemplatePlan]):
    """Template-MPC updates: SRB problem -> warm start -> MS-iLQR -> ``TemplatePlan``.

    The one-phase update (timing, statistics, failure handling) is ``RecedingHorizonPlanner``'s; this class
    supplies the template's problem, warm start and plan, so the MPC loops (``control.inline``: fixed or
    measured latency; ``control.process``) run it unchanged. ``settings``: the
    same receding-horizon settings as CAFE-MPC (period, latency, iterations per update, first solve). No
    real-time iteration: its updates are small (5-10 ms) and one-phase, planned from the state predicted
    where their plan takes effect (``predict_start``).
    """

    name = "template MPC"

    def __init__(
        self,
        robot: Robot,
        reference: Reference,
        builder: TemplateProblemBuilder,
        settings: MpcSettings | None = None,
    ) -> None:
        super().__init__(robot, reference, builder, settings)
        self._prediction_data: dict[int, object] = {}

    def _build(self, t: float) -> TemplateProblem:
        """The problem from the state measured at ``t``; with ``settings.predict_latency`` (and a previous
        plan), the problem of ``t`` plus the expected latency, from the SRB state predicted there
        (``predict_start``)."""
        lead = self.expected_latency() if self.builder.settings.predict_latency else 0.0
        if lead <= 0.0 or self.previous is None:
            return self.builder.build(t, self._x, self.reference)
        t_plan = t + quanta(lead) * TIME_QUANTUM
        start = self.predict_start(t, t_plan, self.builder.initial_state(self._x))
        return self.builder.build(t_plan, self._x, self.reference, start)

    def expected_latency(self) -> float:
        """How long after its measurement the next plan will take effect: the fixed latency, or (measured)
        the median of the last ten in-loop updates' wall times times ``compute_scale`` (0 before the first
        one; the cold first solve runs before the clock starts and does not count)."""
        settings = self.settings
        if settings.latency == "fixed":
            return settings.fixed_latency
        recent = self.statistics.update_times[1:][-10:]
        return float(np.median(recent)) * settings.compute_scale if recent else 0.0

    def predict_start(self, t: float, t_plan: float, state: np.ndarray) -> np.ndarray:
        """The SRB state at ``t_plan`` from ``state`` at ``t``: the SRB dynamics (29), (30) under the plan in
        effect until then (the previous one: its GRFs, stance flags and feet, held over its intervals as its
        low level applies them). Delay compensation: the new plan then starts where the robot will be when
        it takes effect, not where it was measured."""
        previous, solution = self.previous
        times = previous.times
        forces = solution.phases[0].us
        x, time = np.asarray(state, dtype=float).copy(), t
        while time < t_plan - 0.5 * TIME_QUANTUM:
            k = min(interval_at(times, time), len(times) - 2)
            boundary = float(times[k + 1])
            end = min(boundary, t_plan) if boundary > time + 0.5 * TIME_QUANTUM else t_plan
            milliseconds = quanta(end - time)
            dynamics = self.builder.dynamics(milliseconds)
            data = self._prediction_data.get(milliseconds)
            if data is None:
                data = self._prediction_data[milliseconds] = dynamics.create_data()
            contacts = previous.contacts[k].astype(float)
            dynamics.calc(data, x, forces[k], previous.foot_positions[k], contacts)
            x = data.x_next.copy()
            time = time + milliseconds * TIME_QUANTUM
        return x

    def _solve(
        self, built: TemplateProblem, solver: MSiLQRSolver, budget_start: float | None = None
    ) -> SolverResult:
        xs, us = self._guess(built)
        if self.builder.settings.leg_torque_limits:
            self.builder.update_torque_maps(built, xs)
        return solver.solve(built.problem, [xs], [us], None, budget_start=budget_start)

    def _plan(self, built: TemplateProblem, result: SolverResult) -> TemplatePlan:
        return template_plan(built, result)

    def _guess(self, built: TemplateProblem) -> tuple[np.ndarray, np.ndarray]:
        """Warm start by time (``time_grid.PiecewiseTrajectory``): knots inside the previous horizon take
        the previous solution at their time (the state interpolated, the GRFs of the interval containing
        it), knots past it copy the last previous state and take the GRF targets. Cold start: the reference
        states and GRF targets (multiple shooting from the reference)."""
        n = len(built.times) - 1
        xs = built.reference_states.copy()
        us = built.force_targets.copy()
        xs[0] = built.problem.x0
        if self.previous is None:
            return xs, us
        previous, solution = self.previous
        phase = solution.phases[0]
        manifold = previous.problem.phases[0].state
        trajectory = PiecewiseTrajectory(
            previous.times, phase.xs, phase.us, manifold.difference, manifold.integrate
        )
        for k in range(n + 1):
            t = float(built.times[k])
            if k > 0:
                trajectory.state_into(t, xs[k])
            control = trajectory.control_at(t) if k < n else None
            if control is not None:
                us[k] = control
        return xs, us


def template_plan(built: TemplateProblem, result: SolverResult) -> TemplatePlan:
    """The solution as the low level's ``TemplatePlan`` (swing-foot GRFs are zeroed: they act on nothing)."""
    phase = result.phases[0]
    n = len(built.times) - 1
    forces = phase.us.reshape(n, -1, 3) * built.contacts[:, :, None]
    return TemplatePlan(
        times=built.times[:-1].copy(),
        dt=np.diff(built.times),
        base_states=phase.xs.copy(),
        forces=forces,
        contacts=built.contacts.copy(),
        foot_positions=built.foot_positions,
        foot_velocities=built.foot_velocities,
    )
