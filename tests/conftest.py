"""Shared fixtures and the test markers.

``robot`` (also ``mini_cheetah``): the Mini Cheetah, loaded once per session (``reference_robot``) and
shared by every test file that needs the reference robot (loading builds the Pinocchio model and its MJCF:
about a second each time).
Tests must not mutate it: derive variants with ``dataclasses.replace``.

Markers (registered in ``pyproject.toml``; ``make test`` runs everything, ``pytest -m "not slow"`` the quick
part): ``slow`` 2.5 s or more on a 2-core VM (closed loops, sweeps, large model files, renders); ``realtime``
wall-clock processes (the MPC in its own process, timing checks: sensitive to machine load); ``display``
rendering through MuJoCo's OpenGL context (skipped without one).
"""

from __future__ import annotations

import pytest

from cafe_mpc.robots.robot import Robot, load_robot


@pytest.fixture(scope="session")
def reference_robot() -> Robot:
    """The Mini Cheetah, loaded once per session (read-only: every test shares it)."""
    return load_robot("mini_cheetah")


@pytest.fixture(scope="session")
def robot(reference_robot: Robot) -> Robot:
    """The Mini Cheetah (a module may override ``robot``, e.g. to parametrise over robots)."""
    return reference_robot


@pytest.fixture(scope="session")
def mini_cheetah(reference_robot: Robot) -> Robot:
    """The Mini Cheetah under its own name, even where a module overrides ``robot``."""
    return reference_robot
