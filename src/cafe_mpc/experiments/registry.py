"""The experiment registry: every reproduction of the paper's Sec. VII is one module behind one interface.

An experiment is a subclass of ``Experiment`` in its own module of ``cafe_mpc.experiments``, decorated with
``@register``. It says

* which runs to make (``plan``: variants from the command-line options, each a preset plus ``--set``
  overrides, an optional seed and the columns it is known by: schedule, time step, sampled parameters);
* what to report of one finished run (``summarize``: the run's summary metrics, computed where the run ran,
  one row of ``results.csv``);
* how to show them (``table``: the markdown table of ``comparison.md``; ``plot``: ``comparison.png``;
  ``outputs``: extra files such as the reliability test's ``summary.json``).

Running the runs (one task per run on a Dask cluster), writing the files and resuming is
``experiments.sweep``'s job, the same for every experiment. A new experiment is one new file here: on first
use the registry imports every module of the package that uses ``@register``, and ``cafe-mpc experiment
--list`` shows what registered.
"""

from __future__ import annotations

import importlib
import pkgutil
import shlex
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal

from cafe_mpc.config import ConfigError, parse_override

if TYPE_CHECKING:
    from cafe_mpc.experiments.common import RunStore
    from cafe_mpc.experiments.run import RunResult

NOT_EXPERIMENTS = frozenset(
    {"registry", "sweep", "common", "run", "controllers"}
    | {"execution", "results_table", "cluster", "comparison"}
)
"""Modules of ``cafe_mpc.experiments`` that hold no experiment (never imported by the discovery)."""


class SweepError(RuntimeError):
    """An experiment cannot run as asked (cluster unreachable or unsuitable, a folder of another sweep)."""


@dataclass(frozen=True)
class Option:
    """A command-line option of an experiment (``--<dest with dashes>``); its value reaches ``plan`` as the
    raw string (``kind="text"``) or ``True`` (``kind="flag"``), or is absent when not given."""

    dest: str
    help: str
    metavar: str = ""
    kind: Literal["text", "flag"] = "text"

    @property
    def flag(self) -> str:
        return "--" + self.dest.replace("_", "-")


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
class Plan:
    """The runs of an experiment and the options that reproduce them (flag -> value, in command order)."""

    variants: list[Variant]
    options: dict[str, str] = field(default_factory=dict)
    drop_files: tuple[str, ...] = ()
    """Files of each run's folder not to keep (e.g. ``log.npz`` of thousands of trials)."""


class Experiment:
    """Base class of the experiments; subclasses set the class attributes and implement ``plan``,
    ``summarize``, ``table`` and ``plot`` (``outputs`` is optional)."""

    name: ClassVar[str]
    title: ClassVar[str]
    paper: ClassVar[str]
    default_duration: ClassVar[float | None] = None
    """Simulated seconds per run (None: each preset's own)."""
    varied_keys: ClassVar[tuple[str, ...]] = ()
    """Config keys the experiment sets per run (``--set`` may not touch them)."""
    options: ClassVar[tuple[Option, ...]] = ()
    default_overrides: ClassVar[tuple[str, ...]] = ()
    """``--set`` items applied before the user's (which may change them)."""
    needs_gait: ClassVar[bool] = True
    errors_are_results: ClassVar[bool] = False
    """A run that ends in a simulator or controller error is an outcome (reliability) rather than a failure
    of the experiment (the comparisons: the command then exits with status 1)."""
    reports_timing: ClassVar[bool] = False
    """Whether the experiment reports wall-clock timings (then only honest with one worker per core)."""

    def plan(self, options: Mapping[str, Any], context: PlanContext) -> Plan:
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


_REGISTRY: dict[str, type[Experiment]] = {}
_DISCOVERED = False


def register(cls: type[Experiment]) -> type[Experiment]:
    """Class decorator: add an experiment to the registry under ``cls.name``."""
    existing = _REGISTRY.get(cls.name)
    if existing is not None and existing is not cls and existing.__qualname__ != cls.__qualname__:
        raise ValueError(
            f"experiment {cls.name!r} registered twice ({existing.__module__}, {cls.__module__})"
        )
    _REGISTRY[cls.name] = cls
    return cls


def _discover() -> None:
    """Import every experiment module of the package once (each registers itself): the modules whose source
    uses ``@register`` (helpers such as ``run``, ``controllers`` or ``sweep`` are not imported for it)."""
    global _DISCOVERED
    if _DISCOVERED:
        return
    import cafe_mpc.experiments as package

    for module in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
        if module.name in NOT_EXPERIMENTS or module.name.startswith("_") or module.ispkg:
            continue
        source = Path(package.__path__[0]) / f"{module.name}.py"
        if source.is_file() and "@register" in source.read_text(encoding="utf-8"):
            importlib.import_module(f"{package.__name__}.{module.name}")
    _DISCOVERED = True


ORDER = (
    "schedules",
    "solve-times",
    "trot-schedules",
    "push",
    "warm-start",
    "reliability",
    "template-vs-cafe",
    "template-gaits",
    "latency",
    "robots",
)
"""Listing order of the built-in experiments (others follow by name)."""


def experiments() -> dict[str, type[Experiment]]:
    """Every registered experiment by name, the paper's order first."""
    _discover()
    names = [n for n in ORDER if n in _REGISTRY] + sorted(n for n in _REGISTRY if n not in ORDER)
    return {name: _REGISTRY[name] for name in names}


def experiment_names() -> list[str]:
    return list(experiments())


def get_experiment(name: str) -> Experiment:
    """A new instance of the experiment ``name``; ``ConfigError`` naming the known ones otherwise."""
    known = experiments()
    if name not in known:
        raise ConfigError(f"unknown experiment {name!r}; experiments: {', '.join(known)}")
    return known[name]()


def all_options() -> dict[str, list[tuple[str, Option]]]:
    """Every option of every experiment: dest -> [(experiment name, its option), ...]."""
    found: dict[str, list[tuple[str, Option]]] = {}
    for name, cls in experiments().items():
        for option in cls.options:
            found.setdefault(option.dest, []).append((name, option))
    return found


def check_options(experiment: Experiment, given: Mapping[str, Any]) -> dict[str, Any]:
    """The options given (not None) that the experiment takes; ``ConfigError`` for one it does not take."""
    own = {option.dest for option in experiment.options}
    chosen = {}
    for dest, value in given.items():
        if value is None or value is False:
            continue
        if dest not in own:
            flags = ", ".join(option.flag for option in experiment.options)
            raise ConfigError(
                f"--{dest.replace('_', '-')} does not apply to experiment {experiment.name!r}"
                + (f" (it takes {flags})" if flags else "")
            )
        chosen[dest] = value
    return chosen


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


def parse_list(text: str | Sequence[str] | None) -> tuple[str, ...] | None:
    """``"S0,S4"`` or ``["S0", "S4"]`` -> ``("S0", "S4")`` (None stays None)."""
    if text is None:
        return None
    items = text.split(",") if isinstance(text, str) else list(text)
    return tuple(str(item).strip() for item in items if str(item).strip())


def check_list(option: str, values: tuple[str, ...], known: Sequence[str] | None = None) -> None:
    """At least one value, no repeats, each one of ``known`` (when given)."""
    flag = "--" + option.replace("_", "-")
    if not values:
        raise ConfigError(f"{flag}: give at least one value")
    if len(set(values)) != len(values):
        raise ConfigError(f"{flag}: repeated value in {','.join(values)}")
    if known is not None:
        for value in values:
            if value not in known:
                raise ConfigError(f"{flag}: unknown value {value!r}; known: {', '.join(known)}")


def list_option(options: Mapping[str, Any], dest: str, default: Sequence[str], known: Sequence[str] | None):
    """A comma-separated list option, checked, or its default."""
    values = parse_list(options.get(dest))
    chosen = tuple(default) if values is None else values
    check_list(dest, chosen, known)
    return chosen


def float_list_option(
    options: Mapping[str, Any], dest: str, default: Sequence[float], low: float, high: float
) -> tuple[float, ...]:
    """A comma-separated list of numbers in ``[low, high]``, or its default."""
    values = parse_list(options.get(dest))
    if values is None:
        return tuple(default)
    check_list(dest, values)
    flag = "--" + dest.replace("_", "-")
    numbers = []
    for value in values:
        try:
            number = float(value)
        except ValueError:
            raise ConfigError(f"{flag}: {value!r} is not a number") from None
        if not low <= number <= high:
            raise ConfigError(f"{flag}: {value} is outside [{low:g}, {high:g}]")
        numbers.append(number)
    return tuple(numbers)


def int_option(options: Mapping[str, Any], dest: str, default: int | None, low: int, high: int) -> int | None:
    """An integer option in ``[low, high]``, or its default."""
    value = options.get(dest)
    if value is None:
        return default
    flag = "--" + dest.replace("_", "-")
    try:
        number = int(str(value))
    except ValueError:
        raise ConfigError(f"{flag}: {value!r} is not an integer") from None
    if not low <= number <= high:
        raise ConfigError(f"{flag}: {number} is outside [{low}, {high}]")
    return number


def float_option(options: Mapping[str, Any], dest: str, default: float, low: float, high: float) -> float:
    """A number option in ``[low, high]``, or its default."""
    value = options.get(dest)
    if value is None:
        return default
    flag = "--" + dest.replace("_", "-")
    try:
        number = float(str(value))
    except ValueError:
        raise ConfigError(f"{flag}: {value!r} is not a number") from None
    if not low <= number <= high:
        raise ConfigError(f"{flag}: {number:g} is outside [{low:g}, {high:g}]")
    return number


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
