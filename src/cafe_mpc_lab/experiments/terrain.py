"""``cafe-mpc experiment terrain``: gaits over steps, stairs and slopes: flat-ground, blind, height map.

Each run is one gait preset walking at its command onto one piece of terrain (``scene.terrain``, starting
1 m ahead; the named pieces in ``TERRAINS``: three steps of 2, 4, 6, 8 or 10 cm, up and down, five stairs
of 10 cm rise and 30 cm tread, up and down, a 10 degree slope over 1.5 m, a 15 and a 20 degree one over
1 m, each up and down again, a rough field of +-2 cm over 2 m, or three trenches 5 or 10 cm wide, 0.6 m
apart) with the controller's ground
``terrain``: ``flat`` (the paper's controller, z = 0 everywhere), ``blind`` (the plane through the stance
feet: ``core.ground``, docs/terrain.md) or ``height_map`` (the plant's height-map sensor on,
``HEIGHT_MAP_SENSOR``: the reference plans on its maps). By default with the fixed 20 ms latency, so every
row is deterministic and its ``cafe-mpc run`` command (``runs.md``) reproduces it. The table gives whether
and when the robot fell, how far it got and whether that was past the piece (onto its top, and over it).

One start is one sample of where the feet meet the first edge: a gait that crosses from 1 m may fall from
0.9 m. ``--starts 0.9,1.0,1.1`` runs each cell with the piece starting at each of these x, and the table's
notes give each cell's rate of runs over it, with its Wilson interval (a rate, not a run).

One latency is one sample too: a controller tuned at the fixed 20 ms may fall at 2 ms, which is what
measured latency gives on a fast machine. ``--latencies 0.002,0.01,0.02,0.03`` runs every cell at each of
these fixed latencies (``mpc.fixed_latency``), and the notes give the runs over per latency and each cell's
rate at each latency.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import Field, model_validator

from cafe_mpc.assembly.references import reference_commands
from cafe_mpc.config import ConfigError, TerrainConfig, parse_override
from cafe_mpc_lab.experiments.common import (
    SPEED_TOLERANCE,
    GaitPresetNames,
    RunStore,
    colors,
    fall_fields,
    fell_text,
    num,
)
from cafe_mpc_lab.experiments.options import ExperimentOptions, names, numbers
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.reliability import wilson_interval
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import new_figure, save_figure
from cafe_mpc_lab.report.metrics import commanded_at
from cafe_mpc_lab.sim.terrain import Gaps, Rough, Slope, Stairs, Steps, terrain_piece

TERRAINS: dict[str, str] = {
    "step2": "{kind: steps, rise: 0.02}",
    "step4": "{kind: steps, rise: 0.04}",
    "step6": "{kind: steps, rise: 0.06}",
    "step8": "{kind: steps, rise: 0.08}",
    "step10": "{kind: steps, rise: 0.1}",
    "stairs10": "{kind: stairs, count: 5, rise: 0.1, tread: 0.3}",
    "slope10": "{kind: slope, angle_deg: 10, length: 1.5}",
    "slope15": "{kind: slope, angle_deg: 15, length: 1.0}",
    "slope20": "{kind: slope, angle_deg: 20, length: 1.0}",
    "rough2": "{kind: rough, amplitude: 0.02}",
    "rough3": "{kind: rough, amplitude: 0.03}",
    "rough4": "{kind: rough, amplitude: 0.04}",
    "rough6": "{kind: rough, amplitude: 0.06}",
    "gap5": "{kind: gaps, gap_width: 0.05}",
    "gap10": "{kind: gaps, gap_width: 0.1}",
}
"""The named pieces of terrain (``scene.terrain`` entries; the rest of each kind's keys at their defaults:
from x = 1 m, 3 steps of 0.3 m, a 1 m top, down again)."""
DEFAULT_TERRAINS = ("step2", "step4", "step8", "slope10", "slope20")
MODES = ("flat", "blind", "height_map")
"""The controller's ground (``terrain``) the experiment compares."""
DEFAULT_MODES = ("flat", "blind")
HEIGHT_MAP_SENSOR = ("plant.height_map.enabled=true", "plant.height_map.forward_offset=0.3")
"""The height-map sensor of the ``height_map`` runs: the plant's defaults, its grid centred 0.3 m ahead
of the base (it sees 0.9 m ahead and 0.3 m behind)."""
DEFAULT_GAITS = ("trot", "pace", "bound")
TerrainNames = names(tuple(TERRAINS))
ModeNames = names(MODES)


DEFAULT_START = TerrainConfig.model_fields["start"].default
"""World x where a named piece begins unless ``--starts`` says otherwise (the schema's default)."""


def _spec(name: str, start: float) -> str:
    """The ``scene.terrain`` entry of a named piece beginning at ``start`` (the name's own text at the
    default start, so the commands of earlier sweeps stay the same)."""
    if start == DEFAULT_START:
        return TERRAINS[name]
    keys = yaml.safe_load(TERRAINS[name])
    keys["start"] = start
    return "{" + ", ".join(f"{key}: {value}" for key, value in keys.items()) + "}"


def _piece(name: str, start: float = DEFAULT_START) -> Slope | Steps | Stairs | Rough | Gaps:
    """The ``sim.terrain`` piece of a named terrain beginning at ``start``."""
    return terrain_piece(TerrainConfig(**yaml.safe_load(_spec(name, start))))


def _top(piece: Slope | Steps | Stairs | Rough | Gaps) -> float:
    """World x where the piece's top begins (a rough field's and the gaps': where they begin)."""
    if isinstance(piece, Rough | Gaps):
        return piece.start
    if isinstance(piece, Slope):
        return piece.start + piece.length
    return next(begin for _, begin, _, height in piece.treads if height >= piece.height - 1e-12)


class TerrainOptions(ExperimentOptions):
    gaits: GaitPresetNames = Field(
        DEFAULT_GAITS,
        description="gait presets (default: trot, pace, bound)",
        json_schema_extra={"metavar": "G,..."},
    )
    task: GaitPresetNames = Field(
        (),
        description="one gait preset (as the other experiments' --task): the same as --gaits PRESET",
        json_schema_extra={"metavar": "PRESET"},
    )
    terrains: TerrainNames = Field(
        DEFAULT_TERRAINS,
        description=f"named terrain pieces: {', '.join(TERRAINS)} (default: {', '.join(DEFAULT_TERRAINS)})",
        json_schema_extra={"metavar": "T,..."},
    )
    modes: ModeNames = Field(
        DEFAULT_MODES,
        description="the controller's ground: flat (z = 0), blind (the stance feet's plane), height_map "
        "(the sensor's maps); default flat, blind",
        json_schema_extra={"metavar": "flat,blind,height_map"},
    )
    starts: numbers(-10.0, 100.0) = Field(
        (DEFAULT_START,),
        description="world x where the piece begins, one run each (default 1): several make each cell a rate",
        json_schema_extra={"metavar": "X,..."},
    )
    latencies: numbers(0.0, 0.5) = Field(
        (),
        description="fixed latencies in s, one run each (mpc.fixed_latency; default: the one the runs "
        "have, 0.02 unless --set changes it)",
        json_schema_extra={"metavar": "L,..."},
    )

    @model_validator(mode="before")
    @classmethod
    def _task_is_the_gaits(cls, given: Any) -> Any:
        """``--task PRESET`` runs that preset's cells, as ``--gaits PRESET`` does; with ``--gaits`` too it
        would be ambiguous which one holds."""
        if isinstance(given, dict) and given.get("task"):
            if given.get("gaits"):
                raise ValueError("--task PRESET and --gaits G,... name the presets twice: give one of them")
            task = given["task"]
            if (len(task.split(",")) if isinstance(task, str) else len(task)) != 1:
                raise ValueError("--task takes one preset (several: --gaits G,...)")
            given = {**given, "gaits": task}
        return given


class Terrain(Experiment):
    name = "terrain"
    title = "Gaits over steps, stairs and slopes: the flat-ground controller, blind, and on the height map"
    paper = "beyond the paper (its experiments are on flat ground); issue 'off the flat floor'"
    default_duration = 10.0
    varied_keys = ("scene.terrain", "terrain", "plant.height_map.enabled", "plant.height_map.forward_offset")
    default_overrides = ("mpc.latency=fixed", "mpc.fixed_latency=0.02")
    Options = TerrainOptions

    def plan(self, options: TerrainOptions, context: PlanContext) -> ExperimentPlan:
        latencies = _checked_latencies(options.latencies, context.overrides)
        variants = [
            Variant(
                f"{gait}-{terrain}-{mode}"
                + ("" if start == DEFAULT_START else f"-from{start:g}")
                + ("" if latency is None else f"-lat{1000 * latency:g}ms"),
                gait,
                (
                    f"scene.terrain=[{_spec(terrain, start)}]",
                    f"terrain={mode}",
                    *(HEIGHT_MAP_SENSOR if mode == "height_map" else ()),
                    *(() if latency is None else (f"mpc.fixed_latency={latency:g}",)),
                ),
                f"{gait}, {terrain}, {mode}"
                + ("" if start == DEFAULT_START else f", from {start:g} m")
                + ("" if latency is None else f", fixed {1000 * latency:g} ms"),
                group=gait,
                fields=(
                    ("gait", gait),
                    ("terrain_piece", terrain),
                    ("mode", mode),
                    ("start", start),
                    *(() if latency is None else (("latency", latency),)),
                ),
            )
            for latency in latencies
            for gait in options.gaits
            for terrain in options.terrains
            for mode in options.modes
            for start in options.starts
        ]
        plan_options = {
            "--gaits": ",".join(options.gaits),
            "--terrains": ",".join(options.terrains),
            "--modes": ",".join(options.modes),
        }
        if tuple(options.starts) != (DEFAULT_START,):
            plan_options["--starts"] = ",".join(f"{s:g}" for s in options.starts)
        if options.latencies:
            plan_options["--latencies"] = ",".join(f"{latency:g}" for latency in options.latencies)
        return ExperimentPlan(variants, plan_options)

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        metrics = result.metrics
        steady = metrics.get("steady_state") or metrics
        fields = dict(variant.fields)
        piece = _piece(fields["terrain_piece"], fields["start"])
        x = result.log.q[:, 0]
        reached = float(np.max(x)) if len(x) else None
        top = _top(piece)
        end = result.log.time[-1:] if len(result.log.time) else np.zeros(1)
        desired = float(commanded_at(end, reference_commands(result.config), 0.0)[0, 0])
        vx = steady.get("vx_mean")
        over = reached is not None and reached >= piece.end and not metrics["fell"]
        return {
            **fall_fields(metrics),
            "x_reached": reached,
            "terrain_top_x": top,
            "terrain_end_x": piece.end,
            "on_top": reached is not None and reached >= top,
            "over": over,
            "vx_mean": vx,
            "vx_desired": desired,
            "steady_speed": over and vx is not None and abs(vx - desired) < SPEED_TOLERANCE,
        }

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        latencies = any("latency" in r for r in rows)
        header = ["gait", "terrain", "ground", "start [m]"]
        header += ["latency [ms]"] if latencies else []
        header += ["fell", "x reached [m]", "past the top", "over", "vx [m/s]"]
        body = [
            [
                str(r.get("gait")),
                str(r.get("terrain_piece")),
                str(r.get("mode")),
                num(r.get("start", DEFAULT_START), 2),
                *([num(1000 * r["latency"], 0) if "latency" in r else "-"] if latencies else []),
                fell_text(r),
                num(r.get("x_reached"), 2),
                "yes" if r.get("on_top") else "no",
                "yes" if r.get("over") else "no",
                num(r.get("vx_mean"), 2),
            ]
            for r in rows
        ]
        notes = [
            "Terrain from x = 1 m (the robot starts at 0): steps 0.3 m deep with a 1 m top, slopes with a "
            "1 m top, each down again. 'past the top': the base got to the top's start; 'over': it got past "
            "the piece's end without falling. vx: mean forward speed from 0.5 s to the end or the fall.",
            f"Runs over at a steady speed (vx within {SPEED_TOLERANCE:g} m/s of the command): "
            f"{steady_over(rows)}.",
        ]
        if len({r.get("start", DEFAULT_START) for r in rows}) > 1 or latencies:
            over = "the starts and latencies" if latencies else "the starts"
            notes.append(f"Over {over} (runs over the piece, Wilson 95 %): {over_rates(rows)}.")
        if latencies:
            notes.append(f"Runs over, per fixed latency: {over_per_latency(rows)}.")
        return header, body, notes

    def summary_line(self, comparison: dict) -> str | None:
        rows = list((comparison.get("variants") or {}).values())
        if any("latency" in r for r in rows):
            steady = steady_over(rows)
            return f"runs over, per fixed latency: {over_per_latency(rows)}; at a steady speed {steady}"
        return None

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
        if any("latency" in r for r in rows):
            _plot_over_latencies(rows, path)
            return
        rows = [r for r in rows if r.get("start", DEFAULT_START) == DEFAULT_START] or rows
        done = [r for r in rows if r.get("status") == "ok"]
        if not done:
            return
        terrains = list(dict.fromkeys(r["terrain_piece"] for r in done))
        gaits = list(dict.fromkeys(r["gait"] for r in done))
        modes = list(dict.fromkeys(r["mode"] for r in done))
        figure = new_figure((10, 4.5))
        axis = figure.add_subplot(1, 1, 1)
        width = 0.8 / max(len(gaits) * len(modes), 1)
        palette = colors(len(gaits) * len(modes))
        for g, gait in enumerate(gaits):
            for m, mode in enumerate(modes):
                index = g * len(modes) + m
                values = []
                for terrain in terrains:
                    row = next(
                        (
                            r
                            for r in done
                            if (r["gait"], r["terrain_piece"], r["mode"]) == (gait, terrain, mode)
                        ),
                        None,
                    )
                    values.append(row["x_reached"] if row and row.get("x_reached") is not None else np.nan)
                positions = np.arange(len(terrains)) + (index - 0.5 * (len(gaits) * len(modes) - 1)) * width
                axis.bar(
                    positions,
                    values,
                    width,
                    color=palette[index],
                    label=f"{gait}, {mode}",
                    hatch="//" if mode == "flat" else None,
                )
        axis.set_xticks(np.arange(len(terrains)), terrains)
        axis.set_ylabel("x reached [m] (terrain from 1 m)")
        axis.axhline(1.0, color="k", lw=0.8, ls="--")
        axis.legend(fontsize=7, ncol=len(gaits))
        axis.grid(alpha=0.3, axis="y")
        figure.suptitle(
            "How far each gait gets over steps and slopes: flat-ground controller and blind", fontsize=10
        )
        save_figure(figure, path)


def _checked_latencies(latencies: tuple[float, ...], overrides: tuple[str, ...]) -> tuple[float | None, ...]:
    """The fixed latencies the plan runs at (``(None,)``: the one the runs' config has). ``--latencies``
    varies ``mpc.fixed_latency``, so a ``--set`` of it would be overridden silently, and with another
    latency mode than ``fixed`` the value would mean nothing: both are errors."""
    if not latencies:
        return (None,)
    mode = "fixed"
    for item in overrides:
        key, value = parse_override(item)
        if key == "mpc.fixed_latency" and item not in Terrain.default_overrides:
            raise ConfigError("--latencies sets mpc.fixed_latency per run: drop --set mpc.fixed_latency")
        if key == "mpc.latency":
            mode = str(value)
    if mode != "fixed":
        raise ConfigError(f"--latencies needs mpc.latency=fixed, got --set mpc.latency={mode}")
    return latencies


def _cell(r: dict) -> str:
    return f"{r['gait']} {r['terrain_piece']} {r['mode']}"


def _rate(over: list[bool]) -> str:
    """``k of n (low-high %)``: the runs over with the Wilson 95 % interval."""
    low, high = wilson_interval(sum(over), len(over))
    return f"{sum(over)} of {len(over)} ({100 * low:.0f}-{100 * high:.0f} %)"


def over_rates(rows: list[dict]) -> str:
    """Each (gait, terrain, ground) cell's runs over the piece out of its finished runs, with the Wilson
    95 % interval, e.g. ``bound step6 blind 1 of 3 (6-79 %)``; with several fixed latencies one rate per
    cell and latency (``bound step6 blind at 2 ms 1 of 3 (6-79 %)``)."""
    latencies = len({r.get("latency") for r in rows}) > 1
    cells: dict[str, list[bool]] = {}
    for r in rows:
        if r.get("status") == "ok":
            name = _cell(r) + (f" at {1000 * r['latency']:g} ms" if latencies else "")
            cells.setdefault(name, []).append(bool(r.get("over")))
    return "; ".join(f"{name} {_rate(over)}" for name, over in cells.items())


def steady_over(rows: list[dict]) -> str:
    """The runs over the piece at a steady speed (``steady_speed``) out of the runs over: ``44 of 45``."""
    return f"{sum(bool(r.get('steady_speed')) for r in rows)} of {sum(bool(r.get('over')) for r in rows)}"


def over_per_latency(rows: list[dict]) -> str:
    """The runs over the piece at each fixed latency, all cells together, e.g. ``2 ms 35 of 45 (...)``."""
    runs: dict[float, list[bool]] = {}
    for r in rows:
        if r.get("status") == "ok" and "latency" in r:
            runs.setdefault(r["latency"], []).append(bool(r.get("over")))
    return "; ".join(f"{1000 * latency:g} ms {_rate(over)}" for latency, over in sorted(runs.items()))


def _plot_over_latencies(rows: list[dict], path: Path) -> None:
    """Each (gait, terrain, ground) cell's share of runs over the piece (over its starts), a bar per fixed
    latency: whether a cell holds over the latencies or at one of them only."""
    done = [r for r in rows if r.get("status") == "ok" and "latency" in r]
    if not done:
        return
    cells = list(dict.fromkeys(_cell(r) for r in done))
    latencies = sorted({r["latency"] for r in done})
    figure = new_figure((max(8.0, 0.6 * len(cells) * max(len(latencies), 2) / 2), 4.5))
    axis = figure.add_subplot(1, 1, 1)
    width = 0.8 / len(latencies)
    palette = colors(len(latencies))
    for index, latency in enumerate(latencies):
        shares = []
        for cell in cells:
            over = [bool(r.get("over")) for r in done if _cell(r) == cell and r["latency"] == latency]
            shares.append(np.mean(over) if over else np.nan)
        positions = np.arange(len(cells)) + (index - 0.5 * (len(latencies) - 1)) * width
        axis.bar(positions, shares, width, color=palette[index], label=f"fixed {1000 * latency:g} ms")
    axis.set_xticks(np.arange(len(cells)), cells, rotation=60, ha="right", fontsize=7)
    axis.set_ylabel("share of runs over the piece")
    axis.set_ylim(0.0, 1.05)
    axis.legend(fontsize=7, ncol=len(latencies))
    axis.grid(alpha=0.3, axis="y")
    figure.suptitle("Each cell over the fixed latencies: does it hold at every one?", fontsize=10)
    save_figure(figure, path)
