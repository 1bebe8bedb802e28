"""Every experiment of ``cafe-mpc experiment``, in the paper's order: the one list a new experiment joins."""

from __future__ import annotations

from cafe_mpc.config import ConfigError
from cafe_mpc_lab.experiments.command_ranges import CommandRanges
from cafe_mpc_lab.experiments.envelope import Envelope
from cafe_mpc_lab.experiments.faults import Faults
from cafe_mpc_lab.experiments.latency import Latency
from cafe_mpc_lab.experiments.push import Push
from cafe_mpc_lab.experiments.registry import Experiment
from cafe_mpc_lab.experiments.reliability import Reliability
from cafe_mpc_lab.experiments.robots import Robots
from cafe_mpc_lab.experiments.schedules import Schedules
from cafe_mpc_lab.experiments.solve_times import SolveTimes
from cafe_mpc_lab.experiments.template_gaits import TemplateGaits
from cafe_mpc_lab.experiments.template_vs_cafe import TemplateVsCafe
from cafe_mpc_lab.experiments.terrain import Terrain
from cafe_mpc_lab.experiments.trot_schedules import TrotSchedules
from cafe_mpc_lab.experiments.warm_start import WarmStart

EXPERIMENTS: tuple[type[Experiment], ...] = (
    Schedules,
    SolveTimes,
    TrotSchedules,
    Push,
    WarmStart,
    Reliability,
    Envelope,
    TemplateVsCafe,
    TemplateGaits,
    Latency,
    Robots,
    CommandRanges,
    Terrain,
    Faults,
)
"""The experiments, in the order ``cafe-mpc experiment --list`` shows them."""


def experiments() -> dict[str, type[Experiment]]:
    """Every experiment by name, in ``EXPERIMENTS``' order."""
    found: dict[str, type[Experiment]] = {}
    for cls in EXPERIMENTS:
        if cls.name in found:
            raise ValueError(
                f"experiment {cls.name!r} listed twice ({found[cls.name].__module__}, {cls.__module__})"
            )
        found[cls.name] = cls
    return found


def experiment_names() -> list[str]:
    return list(experiments())


def get_experiment(name: str) -> Experiment:
    """A new instance of the experiment ``name``; ``ConfigError`` naming the known ones otherwise."""
    known = experiments()
    if name not in known:
        raise ConfigError(f"unknown experiment {name!r}; experiments: {', '.join(known)}")
    return known[name]()
