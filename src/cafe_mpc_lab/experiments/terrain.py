"""``cafe-mpc experiment terrain``: gaits over steps and slopes, on the flat-ground controller and blind.

Each run is one gait preset walking at its command onto one piece of terrain (``scene.terrain``, starting
1 m ahead; the named pieces in ``TERRAINS``: three steps of 2, 4 or 8 cm, up and down, or a 10 degree slope
over 1.5 m and a 20 degree one over 1 m, each up and down again) with the controller's ground ``terrain``:
``flat`` (the paper's controller, z = 0 everywhere) or ``blind`` (the plane through the stance feet:
``core.ground``, docs/terrain.md). By default with the fixed 20 ms latency, so every row is deterministic
and its ``cafe-mpc run`` command (``runs.md``) reproduces it. The table gives whether and when the robot
fell, how far it got and whether that was past the piece (onto its top, and over it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from pydantic import Field

from cafe_mpc.config import TerrainConfig
from cafe_mpc_lab.experiments.common import GaitPresetNames, RunStore, colors, fall_fields, fell_text, num
from cafe_mpc_lab.experiments.options import ExperimentOptions, names
from cafe_mpc_lab.experiments.registry import Experiment, ExperimentPlan, PlanContext, Variant
from cafe_mpc_lab.experiments.run import RunResult
from cafe_mpc_lab.report.figures import new_figure, save_figure
from cafe_mpc_lab.sim.terrain import Slope, Steps, terrain_piece

TERRAINS: dict[str, str] = {
    "step2": "{kind: steps, rise: 0.02}",
    "step4": "{kind: steps, rise: 0.04}",
    "step8": "{kind: steps, rise: 0.08}",
    "slope10": "{kind: slope, angle_deg: 10, length: 1.5}",
    "slope20": "{kind: slope, angle_deg: 20, length: 1.0}",
}
"""The named pieces of terrain (``scene.terrain`` entries; the rest of each kind's keys at their defaults:
from x = 1 m, 3 steps of 0.3 m, a 1 m top, down again)."""
MODES = ("flat", "blind")
"""The controller's ground (``terrain``) the experiment compares."""
DEFAULT_GAITS = ("trot", "pace", "bound")
TerrainNames = names(tuple(TERRAINS))
ModeNames = names(MODES)


def _piece(name: str) -> Slope | Steps:
    """The ``sim.terrain`` piece of a named terrain."""
    piece = terrain_piece(TerrainConfig(**yaml.safe_load(TERRAINS[name])))
    assert isinstance(piece, Slope | Steps)
    return piece


def _top(piece: Slope | Steps) -> float:
    """World x where the piece's top begins."""
    return piece.start + (piece.length if isinstance(piece, Slope) else piece.count * piece.run)


class TerrainOptions(ExperimentOptions):
    gaits: GaitPresetNames = Field(
        DEFAULT_GAITS,
        description="gait presets (default: trot, pace, bound)",
        json_schema_extra={"metavar": "G,..."},
    )
    terrains: TerrainNames = Field(
        tuple(TERRAINS),
        description=f"named terrain pieces: {', '.join(TERRAINS)} (default: all)",
        json_schema_extra={"metavar": "T,..."},
    )
    modes: ModeNames = Field(
        MODES,
        description="the controller's ground: flat (z = 0), blind (the stance feet's plane); default both",
        json_schema_extra={"metavar": "flat,blind"},
    )


class Terrain(Experiment):
    name = "terrain"
    title = "Gaits over steps and slopes: the flat-ground controller against the blind ground estimate"
    paper = "beyond the paper (its experiments are on flat ground); issue 'off the flat floor'"
    default_duration = 10.0
    varied_keys = ("scene.terrain", "terrain")
    default_overrides = ("mpc.latency=fixed", "mpc.fixed_latency=0.02")
    Options = TerrainOptions

    def plan(self, options: TerrainOptions, context: PlanContext) -> ExperimentPlan:
        variants = [
            Variant(
                f"{gait}-{terrain}-{mode}",
                gait,
                (f"scene.terrain=[{TERRAINS[terrain]}]", f"terrain={mode}"),
                f"{gait}, {terrain}, {mode}",
                group=gait,
                fields=(("gait", gait), ("terrain_piece", terrain), ("mode", mode)),
            )
            for gait in options.gaits
            for terrain in options.terrains
            for mode in options.modes
        ]
        return ExperimentPlan(
            variants,
            {
                "--gaits": ",".join(options.gaits),
                "--terrains": ",".join(options.terrains),
                "--modes": ",".join(options.modes),
            },
        )

    def summarize(self, result: RunResult, variant: Variant) -> dict:
        metrics = result.metrics
        steady = metrics.get("steady_state") or metrics
        fields = dict(variant.fields)
        piece = _piece(fields["terrain_piece"])
        x = result.log.q[:, 0]
        reached = float(np.max(x)) if len(x) else None
        top = _top(piece)
        return {
            **fall_fields(metrics),
            "x_reached": reached,
            "terrain_top_x": top,
            "terrain_end_x": piece.end,
            "on_top": reached is not None and reached >= top,
            "over": reached is not None and reached >= piece.end and not metrics["fell"],
            "vx_mean": steady.get("vx_mean"),
        }

    def table(self, rows: list[dict], comparison: dict) -> tuple[list[str], list[list[str]], list[str]]:
        header = ["gait", "terrain", "ground", "fell", "x reached [m]", "past the top", "over", "vx [m/s]"]
        body = [
            [
                str(r.get("gait")),
                str(r.get("terrain_piece")),
                str(r.get("mode")),
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
        ]
        return header, body, notes

    def plot(self, rows: list[dict], runs: RunStore, path: Path) -> None:
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
