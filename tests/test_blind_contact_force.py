"""Blind (``terrain: blind``) contact detection in closed loop: the detector's ground force from the momentum
observer (``vwbc.contact_detection.force_estimate: momentum``) against the plant's feet."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.config import load_config
from cafe_mpc.low_level import vwbc

AIR = 0.03
"""m: a sole this far above the terrain is in the air, whatever the detector says."""


@pytest.mark.slow
def test_the_blind_bound_lands_no_foot_in_the_air(monkeypatch):
    """The bound, blind, onto 6 cm steps from 1 m (fixed 20 ms latency, 2.45 s: its first stride onto the
    first tread). With the force from the joint torques through massless legs, a hind foot whose swing ended
    on the tilted plane 6.6 cm above the floor read its swing's final torques as 25 N and was taken in as an
    early touchdown at 2.372 s, and the stance torques threw it onto the floor at 5 m/s
    (docs/terrain-notes.md).
    With the momentum observer no foot is taken into the stance out of the plant's contact and more than 3 cm
    above the terrain. (Not asserted: a foot taken in on a riser's corner that then slides off it stays in
    the stance, the plane following its point down.)"""
    from cafe_mpc_lab.experiments.run import simulate_run
    from cafe_mpc_lab.sim.terrain import terrain_pieces

    config = load_config(
        "bound",
        [
            "mpc.latency=fixed",
            "mpc.fixed_latency=0.02",
            "simulation.duration=2.45",
            "output.plots=false",
            "scene.terrain=[{kind: steps, rise: 0.06}]",
            "terrain=blind",
            "vwbc.contact_detection.force_estimate=momentum",
        ],
    )
    detected: list[tuple[float, np.ndarray]] = []
    compute = vwbc.VWBCController.compute

    def recording(self, t, measurement, plan):
        torques = compute(self, t, measurement, plan)
        detected.append((t, self.last_stance.copy()))
        return torques

    monkeypatch.setattr(vwbc.VWBCController, "compute", recording)
    resolved, _, log = simulate_run(config)
    assert not log.fell and log.time[-1] >= 2.44
    robot, (steps,) = resolved.robot, terrain_pieces(config.scene)
    data = robot.model.createData()
    false_touchdowns = []
    previous = np.ones(robot.n_feet, dtype=bool)
    for t, stance in detected:
        tick = int(np.argmin(np.abs(log.time - t)))
        pin.framesForwardKinematics(robot.model, data, log.q[tick])
        for foot in np.flatnonzero(stance & ~previous & ~log.contacts[tick]):
            sole = data.oMf[robot.foot_frame_ids[foot]].translation
            # the highest terrain under the foot's sphere (a foot may land on a riser's corner)
            ground = max(
                steps.height_at(x, sole[1]) or 0.0 for x in sole[0] + robot.foot_radius * np.r_[-1, 0, 1]
            )
            if sole[2] - robot.foot_radius - ground > AIR:
                false_touchdowns.append((round(t, 3), int(foot)))
        previous = stance
    assert not false_touchdowns
