"""The experiment interface: every reproduction of the paper's Sec. VII is one module behind one interface.

An experiment is a subclass of ``Experiment`` in its own module of ``cafe_mpc_lab.experiments``, listed in
``experiments.catalog``. It says

* which options it takes (``Options``: a typed model, ``experiments.options``; ``cafe-mpc experiment NAME
  --help`` shows them);
* which runs to make (``plan``: variants from its options, each a preset plus ``--set`` overrides, an
  optional seed and the columns it is known by: schedule, time step, sampled parameters);
* what to report of one finished run (``summarize``: the run's summary metrics, computed where the run ran,
  one row of ``results.csv``);
* how to show them (``table``: the markdown table of ``comparison.md``; ``plot``: ``comparison.png``;
  ``outputs``: extra files such as the reliability test's ``summary.json``).

Running the runs (one task per run on a Dask cluster), writing the files and resuming is
``experiments.sweep``'s job, the same for every experiment. A new experiment is one new module here and one
line in ``experiments.catalog``.
"""

from __future__ import annotations

import shlex
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from cafe_mpc.config import ConfigError, parse_override
from cafe_mpc_lab.experiments.options import ExperimentOptions, parse_options

if TYPE_CHECKING:
    from cafe_mpc_lab.experiments.common import RunStore
    from cafe_mpc_lab.experiments.run import RunResult


class SweepError(RuntimeError):
    """An experiment cannot run as asked (cluster unreachable or unsuitable, a folder of another sweep)."""


@dataclass(frozen=True)
class Variant:
    """One run of an experiment: ``cafe-mpc run PRESET --set OVERRIDES`` into the folder ``name``.

    ``variant``: what the run stands for in ``results.csv`` (default ``name``; the reliability test's trials
    share their task's name and differ by ``seed``). ``group``: a plot panel or table row (the gait).
    ``fields``: columns known before the run (schedule, SRB time step, sampled plant parameters).
    """

    name: str
    preset: str
    overrides: tuple[str, ...] = ()
    label: str = ""
    group: str = ""
    variant: str = ""
    seed: int | None = None
    fields: tuple[tuple[str, Any], ...] = ()

    @property
    def variant_name(self) -> str:
        return self.variant or self.name


@dataclass(frozen=True)
class PlanContext:
    """What else a plan may depend on: the duration asked for (None: the experiment's default, or each
    preset's own) and the ``--set`` items every run gets (the experiment's defaults, then the user's)."""

    duration: float | None = None
    overrides: tuple[str, ...] = ()


@dataclass
class ExperimentPlan:
    """The runs of an experiment and the options that reproduce them (flag -> value, in command order)."""

    variants: list[Variant]
    options: dict[str, str] = field(default_factory=dict)
    drop_files: tuple[str, ...] = ()
    """Files of each run's folder not to keep (e.g. ``log.npz`` of thousands of trials)."""


class Experiment:
    """Base class of the experiments; subclasses set the class attributes and implement ``plan``,
    ``summarize``, ``table`` and ``plot`` (``outputs`` is optional)."""

    Options: ClassVar[type[ExperimentOptions]] = ExperimentOptions
    """The experiment's own command-line options (none by default)."""

    name: ClassVar[str]
    title: ClassVar[str]
    paper: ClassVar[str]
    default_duration: ClassVar[float | None] = None
    """Simulated seconds per run (None: each preset's own)."""
    varied_keys: ClassVar[tuple[str, ...]] = ()
    """Config keys the experiment sets per run (``--set`` may not touch them)."""
    default_overrides: ClassVar[tuple[str, ...]] = ()
    """``--set`` items applied before the user's (which may change them)."""
    needs_gait: ClassVar[bool] = True
    errors_are_results: ClassVar[bool] = False
    """A run that ends in a simulator or controller error is an outcome (reliability) rather than a failure
    of the experiment (the comparisons: the command then exits with status 1)."""
    reports_timing: ClassVar[bool] = False
    """Whether the experiment reports wall-clock timings (then only honest with one worker per core)."""

    def options_from(self, given: Mapping[str, Any]) -> ExperimentOptions:
        """The experiment's ``Options`` from command-line strings or Python values (``None``: not given);
        ``ConfigError`` with one line naming the flag."""
        return parse_options(self.Options, given, self.name)

    def plan(self, options: Any, context: PlanContext) -> ExperimentPlan:
        """The runs of ``options`` (an instance of ``Options``: ``options_from`` makes one)."""
        raise NotImplementedError

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        raise NotImplementedError

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        """Header, rows and notes of ``comparison.md``."""
        raise NotImplementedError

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        raise NotImplementedError

    def outputs(self, rows: list[dict], comparison: dict, out_dir: Path) -> dict:
        """Extra files of the experiment; returns fields added to ``comparison.json``."""
        return {}

    def markdown_intro(self, rows: list[dict], comparison: dict) -> list[str]:
        """Lines of ``comparison.md`` before the table (default: none)."""
        return []

    def summary_line(self, comparison: dict) -> str | None:
        """One line the command prints after the table (None: nothing)."""
        return None


def check_overrides(experiment: Experiment, overrides: Sequence[str]) -> None:
    """``--set`` may change anything the experiment does not vary itself, nor the duration, nor the real-time
    mode (a real-time run needs the whole machine; parallel workers would share it)."""
    reserved = (*experiment.varied_keys, "simulation.duration", "simulation.realtime")
    for item in overrides:
        key, _ = parse_override(item)
        for varied in reserved:
            if key == varied or key.startswith(varied + ".") or varied.startswith(key + "."):
                if varied == "simulation.duration":
                    hint = "use --duration"
                elif varied == "simulation.realtime":
                    hint = "a real-time run needs the whole machine: use cafe-mpc run --realtime"
                else:
                    hint = "the experiment sets it per variant"
                raise ConfigError(f"--set {key}: not allowed in experiment {experiment.name!r} ({hint})")


def experiment_command(
    name: str, duration: float | None, overrides: Sequence[str], options: Mapping[str, str]
):
    """The ``cafe-mpc experiment`` command line that reproduces an experiment (into a new folder)."""
    words = ["cafe-mpc", "experiment", name]
    if duration is not None:
        words += ["--duration", f"{duration:g}"]
    for flag, value in options.items():
        words += [flag] if value == "" else [flag, value]
    for item in overrides:
        words += ["--set", item]
    return shlex.join(words)


def run_command(variant: Variant, duration: float | None, overrides: Sequence[str]) -> str:
    """The ``cafe-mpc run`` command of one variant."""
    words = ["cafe-mpc", "run", variant.preset]
    if duration is not None:
        words += ["--duration", f"{duration:g}"]
    for item in (*overrides, *variant.overrides):
        words += ["--set", item]
    return shlex.join(words)
