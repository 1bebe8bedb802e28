"""The MPC's current plan drawn into a MuJoCo scene: one function for the live viewer and the videos.

``PlanOverlay.of(robot, times, configurations, contacts, forces)`` turns a plan's whole-body knots into what
is drawn (forward kinematics of the planned configurations); ``draw_plan(scene, overlay)`` appends MuJoCo
user geoms (``mjv_initGeom`` / ``mjv_connector``, ``scene.ngeom``) to an ``MjvScene``: the passive viewer's
``user_scn`` (``sim.viewer``) or the off-screen renderer's scene after ``mjv_updateScene``
(``robots.rendering``, run videos). What is drawn:

* the planned base path: a blue line through the planned base positions, projected onto the ground under
  the plan's feet (at the base's own height it would hide inside the trunk);
* planned footholds: a green disc where each foot touches down in the plan (and under feet already in
  stance at the plan's first knot);
* swing-foot paths: an orange line through each swinging foot's planned positions;
* GRF arrows: the planned ground reaction force of each stance foot at the knot shown (red, from the foot,
  ``force_scale`` N per metre; default 200 N/m: the Mini Cheetah's 20-40 N stance forces give 10-20 cm).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import mujoco
import numpy as np

from cafe_mpc.core.plan import KnotPlan, nearest_knot
from cafe_mpc.robots.robot import Robot

BASE_RGBA = np.array([0.15, 0.45, 0.95, 0.9], dtype=np.float32)
SWING_RGBA = np.array([1.0, 0.55, 0.1, 0.9], dtype=np.float32)
FOOTHOLD_RGBA = np.array([0.1, 0.8, 0.3, 0.8], dtype=np.float32)
FORCE_RGBA = np.array([0.9, 0.15, 0.15, 0.9], dtype=np.float32)
FORCE_SCALE_N_PER_M = 200.0
"""Newtons per metre of arrow."""


@dataclass(frozen=True)
class PlanOverlay:
    """What a plan shows: base and foot positions at its knots, stance flags and planned forces.

    ``times`` (n,), ``base`` (n + 1, 3), ``feet`` (n + 1, n_feet, 3), ``contacts`` (n, n_feet),
    ``forces`` (n, n_feet, 3) (world frame).
    """

    times: np.ndarray
    base: np.ndarray
    feet: np.ndarray
    contacts: np.ndarray
    forces: np.ndarray
    foot_radius: float = 0.02
    """Height of a planned foot point above the ground it stands on (the foot sphere's radius)."""

    @classmethod
    def of(
        cls,
        robot: Robot,
        times: np.ndarray,
        configurations: np.ndarray,
        contacts: np.ndarray,
        forces: np.ndarray,
    ) -> PlanOverlay:
        """From a plan's knot times, planned configurations (n + 1, nq), stance flags and forces."""
        configurations = np.asarray(configurations, dtype=float)
        feet = np.array([robot.foot_positions(q) for q in configurations]).reshape(
            len(configurations), robot.n_feet, 3
        )
        return cls(
            np.asarray(times, dtype=float),
            configurations[:, :3].copy(),
            feet,
            np.asarray(contacts, dtype=bool),
            np.asarray(forces, dtype=float),
            float(robot.foot_radius),
        )

    @classmethod
    def of_plan(cls, robot: Robot, plan: KnotPlan) -> PlanOverlay | None:
        """The overlay of a plan that has the robot's configurations at its knots
        (``KnotPlan.knot_configurations``), else None."""
        configurations = plan.knot_configurations(robot.nq)
        if configurations is None:
            return None
        return cls.of(robot, plan.times, configurations, plan.contacts, plan.forces)

    def knot_at(self, t: float) -> int:
        """The knot closest in time to ``t`` (clamped), as ``Plan.knot_at``."""
        return nearest_knot(self.times, t)


def _add(scene: mujoco.MjvScene) -> mujoco.MjvGeom | None:
    """The next free geom of ``scene`` (None when it is full)."""
    if scene.ngeom >= scene.maxgeom:
        return None
    geom = scene.geoms[scene.ngeom]
    scene.ngeom += 1
    return geom


_IDENTITY = np.eye(3).flatten()


def _segment(
    scene: mujoco.MjvScene, start: np.ndarray, end: np.ndarray, width: float, rgba: np.ndarray
) -> bool:
    if np.linalg.norm(end - start) < 1e-6:
        return True
    geom = _add(scene)
    if geom is None:
        return False
    mujoco.mjv_initGeom(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), _IDENTITY, rgba)
    mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_CAPSULE, width, start, end)
    return True


def _polyline(scene: mujoco.MjvScene, points: np.ndarray, width: float, rgba: np.ndarray) -> bool:
    return all(_segment(scene, start, end, width, rgba) for start, end in itertools.pairwise(points))


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``(begin, end)`` index ranges of the True runs of ``flags`` (end exclusive)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[False], flags, [False]]).astype(int)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def draw_plan(
    scene: mujoco.MjvScene,
    overlay: PlanOverlay,
    t: float | None = None,
    force_scale: float = FORCE_SCALE_N_PER_M,
) -> int:
    """Append the overlay's geoms to ``scene`` (see the module docstring); GRF arrows at the knot closest to
    ``t`` (None: the first knot). Returns the number of geoms added (fewer when the scene is full)."""
    before = scene.ngeom
    n = len(overlay.times)
    if n == 0:
        return 0
    n_feet = overlay.contacts.shape[1]
    stance_heights = (
        overlay.feet[:-1][overlay.contacts][:, 2] if overlay.contacts.any() else overlay.feet[..., 2]
    )
    ground = float(np.min(stance_heights)) - overlay.foot_radius + 0.004
    shadow = overlay.base.copy()
    shadow[:, 2] = ground
    _polyline(scene, shadow, 0.008, BASE_RGBA)
    for foot in range(n_feet):
        stance = overlay.contacts[:, foot]
        positions = overlay.feet[:, foot]
        # swing paths: the swing knots and the knots on either side (lift-off and touchdown)
        for begin, end in _runs(~stance):
            _polyline(scene, positions[max(begin - 1, 0) : min(end + 1, n + 1)], 0.003, SWING_RGBA)
        # footholds: the first knot of every stance run (the touchdown, or the stance the plan starts in)
        for begin, _ in _runs(stance):
            geom = _add(scene)
            if geom is None:
                break
            centre = positions[begin].copy()
            centre[2] = centre[2] - overlay.foot_radius + 0.002  # at the sole: foot points are sphere centres
            mujoco.mjv_initGeom(
                geom,
                mujoco.mjtGeom.mjGEOM_CYLINDER,
                np.array([0.03, 0.001, 0.0]),
                centre,
                _IDENTITY,
                FOOTHOLD_RGBA,
            )
    knot = 0 if t is None else overlay.knot_at(t)
    for foot in range(n_feet):
        if not overlay.contacts[knot, foot]:
            continue
        force = overlay.forces[knot, foot]
        if np.linalg.norm(force) < 1e-3:
            continue
        geom = _add(scene)
        if geom is None:
            break
        start = overlay.feet[knot, foot]
        mujoco.mjv_initGeom(
            geom, mujoco.mjtGeom.mjGEOM_ARROW, np.zeros(3), np.zeros(3), _IDENTITY, FORCE_RGBA
        )
        mujoco.mjv_connector(geom, mujoco.mjtGeom.mjGEOM_ARROW, 0.006, start, start + force / force_scale)
    return scene.ngeom - before
