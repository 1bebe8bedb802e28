"""Command line: ``cafe-mpc run | config | experiment | report | robot | compile | bench | optimize``.

Every user error (bad preset, key, value, robot file, NaN state) ends with one line ``cafe-mpc: error: ...``
on stderr and a non-zero exit code, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
from pathlib import Path

EXIT_USAGE = 2
EXIT_FAILED = 1
SIM_ROBOT_PRIORITY = 50
"""``sim-robot``'s physics loop priority (SCHED_FIFO): without it, on a 2-core machine shared with the
deployment and its MPC process, 8-13 % of the simulated robot's steps ran more than 1 ms late."""


def _talk(quiet: bool) -> None:
    """Print the stages of a run (``core.progress``) on stderr, one line each, unless ``quiet``; say when the
    numba kernels will be compiled (the first run after an install)."""
    from cafe_mpc.core.progress import STAGE_LOGGER, kernels_cached

    stage_logger = logging.getLogger(STAGE_LOGGER)
    for old in [handler for handler in stage_logger.handlers if getattr(handler, "stage_lines", False)]:
        stage_logger.removeHandler(old)  # main() called again in one process
    if quiet:
        return
    from tqdm import tqdm

    compiling = not kernels_cached()

    class StageLines(logging.Handler):
        """Each stage on its own line of stderr, above a progress bar if one is shown (``tqdm.write``). The
        first stage comes once the run starts (a config error before it stays one line); on the first run
        after an install it is preceded by the kernels' compilation notice."""

        def emit(self, record: logging.LogRecord) -> None:
            nonlocal compiling
            if compiling:
                compiling = False
                tqdm.write(
                    "cafe-mpc: compiling numba kernels (first run only; cached for later runs)", sys.stderr
                )
            tqdm.write(self.format(record), file=sys.stderr)

    handler = StageLines()
    handler.stage_lines = True  # type: ignore[attr-defined]
    handler.setFormatter(logging.Formatter("cafe-mpc: %(message)s"))
    handler.setLevel(logging.INFO)
    stage_logger.addHandler(handler)
    stage_logger.setLevel(logging.INFO)
    stage_logger.propagate = True  # run.log records them too; the console handler below skips them


def _command_run(arguments: argparse.Namespace) -> int:
    from cafe_mpc.assembly.checks import load_run_config
    from cafe_mpc_lab.experiments.run import default_out_dir, run
    from cafe_mpc_lab.report.summary import summarize

    _talk(arguments.quiet)

    overrides = list(arguments.set or [])
    if arguments.duration is not None:
        overrides.append(f"simulation.duration={arguments.duration}")
    if arguments.render:
        overrides.append("output.render=true")
    if arguments.realtime:
        overrides.append("simulation.realtime=true")
    config = load_run_config(arguments.config, overrides)
    out_dir = Path(arguments.out) if arguments.out else default_out_dir(config)
    result = run(config, out_dir, show_progress=not arguments.quiet, viewer=arguments.viewer)
    metrics = result.metrics
    # the verdict, then the numbers that matter in words with units: the top of the HTML report, as text
    for line in summarize(metrics, config.model_dump(mode="json"), config.name).lines():
        print(line)
    if "render_error" in metrics:
        print(f"no video: {metrics['render_error']}")
    print(f"results in {result.out_dir}")
    if metrics.get("task"):  # an acrobatic task: its outcome is the last line
        from cafe_mpc_lab.report.task_metrics import task_summary

        print(task_summary(metrics["task"]))
    return 0


def _command_config(arguments: argparse.Namespace) -> int:
    """Print a preset's or file's resolved config as YAML (what ``run`` would use), or the reference."""
    if arguments.reference or arguments.update:
        from cafe_mpc.config.reference import reference_markdown, update_document

        if arguments.update:
            path = Path(arguments.update)
            try:
                path.write_text(update_document(path.read_text()))
            except (OSError, ValueError) as error:
                raise _UsageError(f"config --update {path}: {error}") from error
            print(f"updated the configuration reference in {path}")
        else:
            print(reference_markdown(), end="")
        return 0
    if arguments.config is None:
        raise _UsageError("config: give a preset or a YAML file (or --reference)")
    import yaml

    from cafe_mpc.assembly.checks import load_run_config

    config = load_run_config(arguments.config, list(arguments.set or []))
    print(yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False), end="")
    return 0


class _UsageError(Exception):
    """A command used wrongly (one line, exit 2)."""


def _version() -> str:
    from importlib import metadata

    import cafe_mpc

    try:
        return metadata.version("cafe-mpc")
    except metadata.PackageNotFoundError:
        return cafe_mpc.__version__


def _experiment_listing() -> str:
    from cafe_mpc_lab.experiments.catalog import experiments
    from cafe_mpc_lab.experiments.options import option_fields

    lines = []
    for cls in experiments().values():
        duration = f"{cls.default_duration:g} s per run" if cls.default_duration else "each preset's duration"
        flags = " ".join(flag for _, flag, _, _, _ in option_fields(cls.Options))
        lines.append(
            f"  {cls.name:<15} {cls.title} ({cls.paper}; {duration})"
            + (f"\n{'':17} {flags}" if flags else "")
        )
    return "\n".join(lines)


def _command_experiment(arguments: argparse.Namespace) -> int:
    from cafe_mpc.config import ConfigError
    from cafe_mpc_lab.experiments.catalog import get_experiment
    from cafe_mpc_lab.experiments.options import option_fields
    from cafe_mpc_lab.experiments.results_table import RESULTS_FILE
    from cafe_mpc_lab.experiments.sweep import run_experiment

    if arguments.list:
        print(_experiment_listing())
        return 0
    if arguments.name is None:
        raise ConfigError("give an experiment (cafe-mpc experiment --list shows them)")
    experiment = get_experiment(arguments.name)
    options = {dest: getattr(arguments, dest) for dest, *_ in option_fields(experiment.Options)}
    result = run_experiment(
        arguments.name,
        out_dir=Path(arguments.out) if arguments.out else None,
        duration=arguments.duration,
        overrides=list(arguments.set or []),
        scheduler=arguments.scheduler,
        workers=arguments.workers,
        resume=arguments.resume,
        show_progress=True,
        echo=print,
        **options,
    )
    print((result.out_dir / "comparison.md").read_text().rstrip())
    line = experiment.summary_line(result.comparison)
    if line:
        print(line)
    print(f"results in {result.out_dir} ({RESULTS_FILE}, comparison.json, .md, .png; one folder per run)")
    if result.errors:
        failed = ", ".join(list(result.errors)[:10]) + (", ..." if len(result.errors) > 10 else "")
        print(f"cafe-mpc: error: runs ended in an error: {failed} (see comparison.json)", file=sys.stderr)
        return EXIT_FAILED
    return 0


EXPERIMENT_EXAMPLES = (
    "examples:\n"
    "  cafe-mpc experiment --list\n"
    "  cafe-mpc experiment schedules                    # bound: Table I x dts 10/50 ms (Fig. 6, 7)\n"
    "  cafe-mpc experiment schedules --schedules S0,S4 --srb-dts 0.05 --duration 5\n"
    "  cafe-mpc experiment solve-times                  # Table II: 3 gaits x S0..S4\n"
    "  cafe-mpc experiment reliability --task bound --trials 100 --max-push 0.8\n"
    "  cafe-mpc experiment reliability --task bound --seeds 17     # trial 17 alone\n"
    "  cafe-mpc experiment latency --task bound         # success over fixed latency and period\n"
    "  cafe-mpc experiment schedules --out runs/s --resume         # continue an interrupted sweep\n"
    "  cafe-mpc experiment push --scheduler tcp://HOST:8786        # on a running Dask cluster\n"
    "  cafe-mpc experiment robots --workers 1 --set mpc.latency=fixed   # trot, bound: every robot\n"
    "  cafe-mpc experiment NAME --help                  # the options of one experiment\n"
    "\n"
    "timing: presets use measured latency; with more workers than cores use --set mpc.latency=fixed"
)


def _examples_of(name: str) -> str:
    """The lines of ``EXPERIMENT_EXAMPLES`` that run experiment ``name`` (its ``--help`` epilog)."""
    own = [line for line in EXPERIMENT_EXAMPLES.splitlines() if f"cafe-mpc experiment {name} " in line + " "]
    own = own or [f"  cafe-mpc experiment {name}"]
    return "examples:\n" + "\n".join(own) + "\n\n" + EXPERIMENT_EXAMPLES.splitlines()[-1]


def _add_sweep_arguments(parser: argparse.ArgumentParser) -> None:
    """The options every experiment takes (where and how its runs run)."""
    parser.add_argument("--duration", type=float, help="simulated seconds per run")
    parser.add_argument("--out", help="output folder (default runs/<time>-experiment-<name>/)")
    parser.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a config key in every run (not the keys the experiment varies); repeatable",
    )
    parser.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="a running Dask scheduler (dask scheduler; dask worker ADDRESS --nthreads 1); "
        "'synchronous': every run in this process, one after the other",
    )
    parser.add_argument(
        "--workers", type=int, help="worker processes of the local cluster (default: one per core)"
    )
    parser.add_argument(
        "--resume", action="store_true", help="continue the sweep in --out: skip the runs already finished"
    )


def _add_experiment_parser(commands: argparse._SubParsersAction) -> None:
    from cafe_mpc_lab.experiments.catalog import experiments
    from cafe_mpc_lab.experiments.options import option_fields

    known = experiments()
    parser = commands.add_parser(
        "experiment",
        help=f"the paper's experiments, in parallel on Dask ({', '.join(known)})",
        description=(
            "Run an experiment of the paper's Sec. VII: its runs in parallel on Dask (by default a local\n"
            "cluster, one worker process per core; --scheduler for a running cluster), each run in its own\n"
            "folder, one row per run in results.csv as it completes, then comparison.json, comparison.md\n"
            "(a markdown table) and comparison.png. An interrupted sweep keeps its finished runs: re-run\n"
            "the same command with --resume --out DIR.\n\n"
            f"experiments:\n{_experiment_listing()}"
        ),
        epilog=EXPERIMENT_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--list", action="store_true", help="list the experiments and exit")
    parser.set_defaults(handler=_command_experiment, name=None)
    names = parser.add_subparsers(dest="name", metavar="NAME")
    for name, cls in known.items():
        sub = names.add_parser(
            name,
            help=f"{cls.title} ({cls.paper})",
            description=f"{cls.title} ({cls.paper}).",
            epilog=_examples_of(name),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        _add_sweep_arguments(sub)
        for dest, option, text, metavar, is_flag in option_fields(cls.Options):
            if is_flag:
                sub.add_argument(option, dest=dest, action="store_true", help=text)
            else:
                sub.add_argument(option, dest=dest, metavar=metavar, help=text)
        sub.set_defaults(handler=_command_experiment, list=False)


class _Parser(argparse.ArgumentParser):
    """A parser whose usage errors are one ``cafe-mpc: error:`` line (``ConfigError``, exit status 2); an
    unknown experiment name is named as such, with the known ones."""

    def error(self, message: str):  # type: ignore[override]
        from cafe_mpc.config import ConfigError

        if self.prog.endswith(" experiment") and message.startswith("argument NAME: invalid choice: "):
            from cafe_mpc_lab.experiments.catalog import experiment_names

            given = message.removeprefix("argument NAME: invalid choice: ").split(" (choose", 1)[0].strip("'")
            raise ConfigError(f"unknown experiment {given!r}; experiments: {', '.join(experiment_names())}")
        raise ConfigError(message)


def _parse_arguments(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace | None:
    """The parsed command line, or None after printing its one-line usage error (``cafe-mpc: error: ...``;
    an option of another experiment is named as such)."""
    from cafe_mpc.config import ConfigError

    try:
        _check_experiment_name_first(sys.argv[1:] if argv is None else argv)
        arguments, extra = parser.parse_known_args(argv)
        if extra:
            raise ConfigError(_unknown_arguments(arguments, extra))
    except ConfigError as error:
        print(f"cafe-mpc: error: {error}", file=sys.stderr)
        return None
    return arguments


def _check_experiment_name_first(argv: list[str]) -> None:
    """``cafe-mpc experiment`` takes the experiment's name before its options (each experiment has its own):
    options first would make the option's value read as the name."""
    from cafe_mpc.config import ConfigError

    words = [word for word in argv if not word.startswith("-")]
    if not words or words[0] != "experiment":
        return
    after = argv[argv.index("experiment") + 1 :]
    if after and after[0].startswith("-") and after[0] not in ("-h", "--help", "--list"):
        raise ConfigError(
            f"give an experiment (cafe-mpc experiment --list shows them) before its options: "
            f"cafe-mpc experiment NAME {after[0]} ..."
        )


def _unknown_arguments(arguments: argparse.Namespace, extra: list[str]) -> str:
    """The one-line error for arguments no parser took: an experiment's, naming the experiment."""
    if getattr(arguments, "command", None) == "experiment" and getattr(arguments, "name", None):
        from cafe_mpc_lab.experiments.catalog import get_experiment
        from cafe_mpc_lab.experiments.options import option_fields

        option = next((item for item in extra if item.startswith("--")), extra[0])
        flags = ", ".join(flag for _, flag, *_ in option_fields(get_experiment(arguments.name).Options))
        return f"{option.split('=')[0]} does not apply to experiment {arguments.name!r}" + (
            f" (it takes {flags})" if flags else ""
        )
    return f"unrecognized arguments: {' '.join(extra)}"


def _command_report(arguments: argparse.Namespace) -> int:
    from cafe_mpc_lab.report.html import write_report

    path = write_report(Path(arguments.folder))
    print(f"report written to {path} (self-contained: open it in a browser, or share the file)")
    return 0


def _command_robot_init(arguments: argparse.Namespace) -> int:
    """``cafe-mpc robot --init MODEL_FILE``: write a starting robot file, then load it."""
    from cafe_mpc.robots.robot import load_robot
    from cafe_mpc.robots.starting_file import StartingFileError, starting_robot_file

    model_file = Path(arguments.init)
    out = Path(arguments.out) if arguments.out else Path(f"{model_file.stem.replace('-', '_')}.yaml")
    if out.suffix not in (".yaml", ".yml"):
        raise _UsageError(f"--out {out}: a robot file ends in .yaml")
    if out.exists():
        raise FileExistsError(f"{out} exists; give another --out")
    try:
        text = starting_robot_file(model_file, arguments.name)
    except StartingFileError as error:
        raise _UsageError(f"robot --init {model_file}: {error}") from error
    out.write_text(text)
    to_fill = sum("# FILL IN" in line for line in text.splitlines())
    print(f"wrote {out}: {to_fill} line(s) marked FILL IN (values the model file does not give)")
    robot = load_robot(str(out))
    print(
        f"it loads: {robot.name}, {robot.total_mass:.3f} kg, legs {', '.join(robot.leg_names)} = feet "
        f"{', '.join(robot.foot_frame_names)}, standing height {robot.standing_height:.3f} m; next: "
        f"cafe-mpc robot {out}"
    )
    return 0


def _command_robot(arguments: argparse.Namespace) -> int:
    from cafe_mpc.dynamics.srb import lumped_inertia, srb_parameters
    from cafe_mpc.robots.robot import load_robot
    from cafe_mpc_lab.sim.consistency import check_consistency

    if arguments.init is not None:
        return _command_robot_init(arguments)
    if arguments.name is None:
        raise _UsageError("cafe-mpc robot needs a robot name or file (or --init MODEL_FILE)")
    robot = load_robot(arguments.name)
    summary = robot.summary()
    srb = srb_parameters(robot)
    summary["srb_mass"] = srb.mass
    summary["srb_inertia"] = srb.inertia_matrix.tolist()
    summary["srb_center_of_mass"] = lumped_inertia(robot).lever.tolist()
    summary["consistency"] = check_consistency(robot, samples=arguments.samples)
    if arguments.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{robot.name}: total mass {robot.total_mass:.3f} kg, feet {', '.join(robot.foot_frame_names)}")
        feet = zip(robot.leg_names, robot.foot_frame_names, strict=True)
        legs = ", ".join(f"{leg} {foot}" for leg, foot in feet)
        print(
            f"legs (named by {robot.legs_named_by}): {legs}; the model file's order "
            f"{', '.join(robot.model_leg_order)}"
        )
        origin = f" ({robot.model_path})" if robot.model_path is not None else ""
        print(
            f"source {robot.source}{origin}; leg length {robot.leg_length:.3f} m, standing height "
            f"{robot.standing_height:.3f} m"
        )
        inertia = srb.inertia_matrix
        print(
            f"SRB (legs lumped at the standing pose, rotors included): mass {srb.mass:.3f} kg, inertia "
            f"diag({inertia[0, 0]:.4f}, {inertia[1, 1]:.4f}, {inertia[2, 2]:.4f}) kg m^2 "
            f"(xz {inertia[0, 2]:.4f})"
        )
        print(
            f"torque limits (plan) {robot.torque_limits[:3].tolist()} Nm, "
            f"motor {robot.plant.motor_torque_limits[:3].tolist()} Nm"
        )
        consistency = summary["consistency"]
        print(
            f"Pinocchio vs MuJoCo: mass diff {consistency['total_mass_difference']:.2e} kg, "
            f"feet {consistency['foot_position_max_error_m']:.2e} m, "
            f"mass matrix {consistency['mass_matrix_max_error']:.2e}: "
            f"{'passed' if consistency['passed'] else 'FAILED'}"
        )
    return 0 if summary["consistency"]["passed"] else EXIT_FAILED


def _command_compile(arguments: argparse.Namespace) -> int:
    """Compile and cache the numba kernels a run uses, by running the first steps of each preset asked for
    (nothing written): what a first run would otherwise do before it moves. ``make install`` runs it."""
    import time

    from cafe_mpc.assembly.checks import load_run_config
    from cafe_mpc_lab.experiments.run import run

    _talk(arguments.quiet)
    start = time.perf_counter()
    for preset in arguments.presets.split(","):
        config = load_run_config(preset.strip(), ["simulation.duration=0.1", "output.plots=false"])
        run(config, None)
    print(f"kernels compiled and cached in {time.perf_counter() - start:.1f} s")
    return 0


def _command_bench(arguments: argparse.Namespace) -> int:
    if arguments.what == "mpc":
        from cafe_mpc.assembly.checks import load_run_config
        from cafe_mpc_lab.bench.mpc_bench import format_report, run_mpc_benchmark

        gaits = tuple(gait.strip() for gait in arguments.gaits.split(",") if gait.strip())
        if not gaits:
            raise ValueError("--gaits needs at least one preset, e.g. --gaits trot,bound")
        if not arguments.duration > 0:
            raise ValueError(f"--duration must be positive, got {arguments.duration}")
        for gait in gaits:  # bad names and overrides fail before anything runs
            load_run_config(gait, list(arguments.set or []))
        result = run_mpc_benchmark(gaits, arguments.duration, tuple(arguments.set or []))
        print(json.dumps(result["gaits"], indent=2) if arguments.json else format_report(result))
        return 0
    from cafe_mpc_lab.bench.solver_bench import format_report, run_solver_benchmark

    if arguments.iterations < 1 or arguments.rounds < 1:
        raise ValueError("--iterations and --rounds must be at least 1")
    result = run_solver_benchmark(arguments.iterations, arguments.rounds)
    print(json.dumps(result, indent=2) if arguments.json else format_report(result))
    return 0


def _command_optimize(arguments: argparse.Namespace) -> int:
    import time

    from cafe_mpc.robots.robot import load_robot
    from cafe_mpc.trajopt.multiphase import solve_task
    from cafe_mpc.trajopt.outputs import write_outputs
    from cafe_mpc.trajopt.presets import load_task

    task = load_task(arguments.task, list(arguments.set or []))
    out_dir = (
        Path(arguments.out)
        if arguments.out
        else Path("runs") / f"{time.strftime('%Y%m%d-%H%M%S')}-{task.name}"
    )
    if out_dir.exists() and any(out_dir.iterdir()):
        raise FileExistsError(f"output folder {out_dir} exists and is not empty; choose another --out")
    robot = load_robot(task.robot)
    print(f"{task.name}: {len(task.phases)} phases, {sum(task.knots_per_phase)} knots at dt = {task.dt} s")
    result = solve_task(robot, task, verbose=arguments.verbose_solver, echo=print)
    command = " ".join(
        ["cafe-mpc optimize", arguments.task]
        + [f"--set {item!r}" for item in arguments.set or []]
        + [f"--out {out_dir}"]
        + (["--no-video"] if arguments.no_video else [])
    )
    summary = write_outputs(robot, result, out_dir, render=not arguments.no_video, command=command)
    roll = summary["roll_at_landing_rad"]
    print(
        f"converged={summary['converged']} ({summary['status']}) "
        f"roll_at_landing={'n/a' if roll is None else f'{roll:.4f}'} rad "
        f"max_defect={summary['max_defect']:.2e} max_abs_torque={summary['max_abs_torque']:.2f} Nm "
        f"iterations={summary['iterations']} wall_time={summary['wall_time_s']:.2f} s"
    )
    if summary.get("render_error"):
        print(f"no video: {summary['render_error']}")
    print(f"results in {out_dir}")
    if not summary["converged"]:
        print(f"cafe-mpc: error: the optimisation did not converge ({summary['status']})", file=sys.stderr)
        return EXIT_FAILED
    return 0


def _command_word(argv: list[str] | None) -> str | None:
    """The command of a command line (its first word that is not an option), if any."""
    words = sys.argv[1:] if argv is None else argv
    return next((word for word in words if not word.startswith("-")), None)


def _add_run_parser(commands: argparse._SubParsersAction, presets: str) -> None:
    """``cafe-mpc run``: a preset or a config file in simulation."""
    run_parser = commands.add_parser(
        "run",
        help="run a preset or a YAML config in simulation",
        description=f"Run a preset or a YAML config in simulation. Presets: {presets}.",
        epilog=(
            "examples:\n"
            "  cafe-mpc run bound                      # bound forward at 0.5 m/s (CAFE-MPC + VWBC), 10 s\n"
            "  cafe-mpc run bound --duration 2 --set wbc=riccati --set mpc.schedule=S0\n"
            "  cafe-mpc run trot --set gait.commands.0.vx=0.8 --set mpc.period=0.03\n"
            "  cafe-mpc run bound-push --set wbc=riccati   # the paper's push test, Riccati controller\n"
            "  cafe-mpc run trot --viewer                  # watch it live, with the plan drawn\n"
            "  cafe-mpc run trot --set plant.floor_friction=0.3 --set mpc.friction=0.6   # slippery floor\n"
            "  cafe-mpc run trot --set 'scene.terrain=[{kind: steps, rise: 0.02}]'"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    run_parser.add_argument("config", help=f"preset name ({presets}) or path to a YAML config")
    run_parser.add_argument("--duration", type=float, help="simulated seconds (overrides the config)")
    run_parser.add_argument("--out", help="output folder (default runs/<time>-<preset>/)")
    run_parser.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a config key by its dotted path; repeatable",
    )
    run_parser.add_argument(
        "--render", action="store_true", help="write a video with the plan drawn in it (needs off-screen GL)"
    )
    run_parser.add_argument(
        "--viewer",
        action="store_true",
        help="watch the run live in MuJoCo's viewer with the current plan drawn (needs a display)",
    )
    run_parser.add_argument(
        "--realtime",
        action="store_true",
        help="against the wall clock: plant + low-level controller at 500 Hz, the MPC in its own process",
    )
    run_parser.add_argument(
        "-q", "--quiet", action="store_true", help="no stage lines and no progress bar (results only)"
    )
    run_parser.set_defaults(handler=_command_run)


def _add_config_parser(commands: argparse._SubParsersAction, presets: str) -> None:
    """``cafe-mpc config``: a resolved config as YAML, or the configuration reference."""
    config_parser = commands.add_parser(
        "config",
        help="print a preset's resolved config (YAML), or the configuration reference",
        description=(
            "Print the config a run would use, every key resolved, as YAML: a starting point for your own\n"
            "file. A file may start from a preset with 'base: PRESET' and give only what it changes."
        ),
        epilog=(
            "examples:\n"
            "  cafe-mpc config trot                               # the trot preset, every key\n"
            "  cafe-mpc config trot --set gait.commands.0.vx=0.8 > my_trot.yaml\n"
            "  cafe-mpc config my_trot.yaml                       # a file (with base: trot) resolved\n"
            "  cafe-mpc config --reference                        # every key, type, default, description\n"
            "  cafe-mpc config --update docs/configuration.md     # regenerate the reference page"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    config_parser.add_argument("config", nargs="?", help=f"preset name ({presets}) or path to a YAML config")
    config_parser.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a config key by its dotted path"
    )
    config_parser.add_argument(
        "--reference", action="store_true", help="print the configuration reference (docs/configuration.md)"
    )
    config_parser.add_argument(
        "--update",
        metavar="FILE",
        help="rewrite the generated reference block of FILE (docs/configuration.md) from the schema",
    )
    config_parser.set_defaults(handler=_command_config)


def _add_report_parser(commands: argparse._SubParsersAction) -> None:
    """``cafe-mpc report``: the self-contained index.html of a run or an experiment folder."""
    report_parser = commands.add_parser(
        "report",
        help="write index.html for a run or an experiment folder (metrics, plots, video; self-contained)",
        description=(
            "Write DIR/index.html: for a run folder the metrics tables, plots, video and config; for an\n"
            "experiment folder the comparison table, its figures and one row per variant with a link to the\n"
            "variant's own index.html (written too). Images and video are embedded: the file opens from the\n"
            "file system and can be shared alone."
        ),
        epilog="examples:\n  cafe-mpc report runs/20261123-120000-trot\n  cafe-mpc report runs/fig6",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    report_parser.add_argument("folder", help="a run folder (metrics.json) or an experiment folder")
    report_parser.set_defaults(handler=_command_report)


def _priority(text: str) -> int:
    """A ``--realtime-priority`` value: an integer 0 (off) to 99."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer 0-99, got {text!r}") from None
    if not 0 <= value <= 99:
        raise argparse.ArgumentTypeError(f"expected 0 (off) to 99, got {value}")
    return value


def _outages(text: str | None) -> tuple[tuple[float, float], ...]:
    """``START:DURATION[,START:DURATION...]`` (s) -> outage windows; ``_UsageError`` naming the flag."""
    if not text:
        return ()
    windows = []
    for part in text.split(","):
        try:
            start, length = (float(value) for value in part.split(":"))
        except ValueError:
            raise _UsageError(f"--outage: expected START:DURATION in seconds, got {part!r}") from None
        windows.append((start, length))
    return tuple(windows)


def _command_sim_robot(arguments: argparse.Namespace) -> int:
    from cafe_mpc.robot_io.interface import RobotInterfaceError
    from cafe_mpc.robots.robot import load_robot
    from cafe_mpc_lab.sim.robot_server import LinkModel, SimRobotServer

    robot = load_robot(arguments.robot)
    if robot.hardware is None or robot.hardware.interface != arguments.interface:
        raise _UsageError(
            f"robot {robot.name!r} does not speak {arguments.interface!r} (its hardware section)"
        )
    try:
        link = LinkModel(arguments.latency, arguments.jitter, arguments.loss, _outages(arguments.outage))
        server = SimRobotServer(
            robot,
            arguments.domain,
            arguments.network_interface,
            not arguments.no_multicast,
            link=link,
            signal_outage=arguments.signal_outage,
            realtime_priority=arguments.realtime_priority,
        )
        viewer = None
        if arguments.viewer:
            from cafe_mpc_lab.sim.viewer import LiveViewer, check_display

            check_display()
            viewer = LiveViewer(robot, lambda: None, realtime=False)
        server.run(arguments.duration, Path(arguments.out) if arguments.out else None, viewer=viewer)
    except RobotInterfaceError as error:
        print(f"cafe-mpc: error: {error}", file=sys.stderr)
        return EXIT_FAILED
    return 0


class DeployTeleop:
    """Steering a deployment from the terminal, one command a line (the ``--viewer`` teleop's steps): ``w`` /
    ``s`` forward speed +- 0.1 m/s, ``a`` / ``d`` yaw rate +- 0.1 rad/s, ``x`` stop (speed and yaw rate 0),
    ``g GAIT`` switch gait at the next cycle boundary, ``q`` end the run (the robot lies down). A command
    the robot cannot follow is refused (the controller's own check)."""

    SPEED_STEP = 0.1
    YAW_RATE_STEP = 0.1

    def __init__(self, controller, stop) -> None:
        self.controller = controller
        self.stop = stop
        first = controller.config.gait.commands[0]
        self.vx, self.yaw_rate = first.vx, first.yaw_rate

    def handle(self, line: str) -> str:
        """Apply one command line; returns what happened (one line)."""
        from cafe_mpc.config import ConfigError

        words = line.split()
        if not words:
            return ""
        key = words[0].lower()
        vx, yaw_rate = self.vx, self.yaw_rate
        if key == "q":
            self.stop()
            return "stopping: lying down"
        if key == "g" and len(words) == 2:
            try:
                self.controller.set_gait(words[1])
            except ConfigError as error:
                return f"refused: {error}"
            return f"gait {words[1]} from the next cycle"
        steps = {"w": (self.SPEED_STEP, 0.0), "s": (-self.SPEED_STEP, 0.0)}
        steps |= {"a": (0.0, self.YAW_RATE_STEP), "d": (0.0, -self.YAW_RATE_STEP)}
        if key == "x":
            vx, yaw_rate = 0.0, 0.0
        elif key in steps:
            vx, yaw_rate = round(vx + steps[key][0], 6), round(yaw_rate + steps[key][1], 6)
        else:
            return "commands: w/s speed, a/d yaw rate, x stop, g GAIT, q lie down and end"
        try:
            self.controller.set_command(vx=vx, yaw_rate=yaw_rate)
        except ConfigError as error:
            return f"refused: {error}"
        self.vx, self.yaw_rate = vx, yaw_rate
        return f"vx {vx:+.2f} m/s, yaw rate {yaw_rate:+.2f} rad/s"

    def start(self) -> None:
        """Read stdin in a daemon thread for the rest of the process."""
        import threading

        def read() -> None:
            for line in sys.stdin:
                answer = self.handle(line)
                if answer:
                    print(f"teleop: {answer}")

        threading.Thread(target=read, name="deploy-teleop", daemon=True).start()


def _command_deploy(arguments: argparse.Namespace) -> int:

    from pydantic import ValidationError

    from cafe_mpc import Controller
    from cafe_mpc.config import ConfigError, format_validation_error
    from cafe_mpc.config.loading import parse_override, set_dotted
    from cafe_mpc.deploy.runner import Deployment
    from cafe_mpc.deploy.settings import DeploySettings
    from cafe_mpc.deploy.startup import StartupRefused
    from cafe_mpc.robot_io import make_interface
    from cafe_mpc.robot_io.interface import RobotInterfaceError, WallClock

    _talk(arguments.quiet)
    overrides = list(arguments.set or [])
    if arguments.robot:
        overrides.append(f"robot={arguments.robot}")
    try:
        values: dict = {}
        for item in arguments.deploy_set or []:
            key, value = parse_override(item)
            set_dotted(values, DeploySettings, key, value, noun="deployment setting")
        if arguments.duration is not None:
            values["duration"] = arguments.duration
        settings = DeploySettings(**values)
    except ValidationError as error:
        raise ConfigError(format_validation_error(error, "deploy")) from error
    controller = Controller(arguments.config, overrides, mode="process")
    try:
        try:
            interface = make_interface(
                arguments.interface,
                controller.robot,
                arguments.domain,
                arguments.network_interface,
                not arguments.no_multicast,
            )
        except ValueError as error:
            raise _UsageError(str(error)) from error
        interface.clock = WallClock(settings.spin)
        deployment = Deployment(interface, controller, settings)
        for signal_number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signal_number, lambda *_: deployment.stop())
        if sys.stdin.isatty() and not arguments.dry_run and controller.config.gait is not None:
            DeployTeleop(controller, deployment.stop).start()
            print("teleop: type w/s (speed), a/d (yaw rate), x (stop), g GAIT, q (lie down and end) + Enter")
        try:
            report = deployment.run(dry_run=arguments.dry_run)
        except StartupRefused as error:
            print(f"cafe-mpc: refused: {error}", file=sys.stderr)
            return EXIT_FAILED
        except RobotInterfaceError as error:
            print(f"cafe-mpc: error: {error}", file=sys.stderr)
            return EXIT_FAILED
    finally:
        controller.close()
    if arguments.out:
        Path(arguments.out).write_text(json.dumps(report.as_dict(), indent=1, default=str))
    lateness = report.lateness_ms_p99
    print(
        f"deploy: {report.outcome}{': ' + report.message if report.message else ''}; {report.ticks} ticks "
        f"({report.mpc_ticks} with the MPC), {report.late_ticks} late, lateness p99 "
        f"{'-' if lateness is None else f'{lateness:.2f}'} ms, tick CPU median {report.tick_cpu_ms_p50} ms; "
        f"{report.link_losses} link losses; "
        f"states {report.link.get('received')} received, {report.link.get('lost')} lost"
    )
    return 0 if report.outcome in ("completed", "dry-run", "stopped") else EXIT_FAILED


def _add_robot_io_parsers(commands: argparse._SubParsersAction, presets: str) -> None:
    """``cafe-mpc deploy`` (the controller on a robot's wire) and ``cafe-mpc sim-robot`` (a simulated robot
    on that wire)."""

    def wire_arguments(parser: argparse.ArgumentParser, domain: int) -> None:
        parser.add_argument("--interface", default="unitree-dds", help="robot interface (unitree-dds)")
        parser.add_argument(
            "--network-interface", default=None, help="network interface the robot is on (lo, eth0, ...)"
        )
        parser.add_argument("--domain", type=int, default=domain, help=f"DDS domain (default {domain})")
        parser.add_argument(
            "--no-multicast",
            action="store_true",
            help="unicast discovery on 127.0.0.1 (both ends must use it)",
        )

    deploy = commands.add_parser(
        "deploy",
        help="run the controller on a robot over its low-level interface (docs/deploy.md)",
        description=(
            "Run a preset on a robot over its low-level interface: wait for its state, check it, stand up,\n"
            "start the MPC, run, lie down. Ctrl-C lies the robot down. Read docs/deploy.md first."
        ),
        epilog=(
            "examples:\n"
            "  cafe-mpc sim-robot --robot go2 --network-interface lo &       # a simulated Go2 on the wire\n"
            "  cafe-mpc deploy trot --robot go2 --network-interface lo --domain 1 --duration 10\n"
            "  cafe-mpc deploy stand --robot go2 --network-interface eth0 --domain 0 --dry-run"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    deploy.add_argument("config", help=f"preset name ({presets}) or path to a YAML config")
    deploy.add_argument("--robot", help="robot name (its robot file needs a hardware section)")
    wire_arguments(deploy, 0)
    deploy.add_argument("--duration", type=float, help="s of MPC control (0: until Ctrl-C)")
    deploy.add_argument("--dry-run", action="store_true", help="read and check the state; command nothing")
    deploy.add_argument("--set", action="append", metavar="KEY=VALUE", help="config override; repeatable")
    deploy.add_argument(
        "--deploy-set",
        action="append",
        metavar="KEY=VALUE",
        help="deployment setting (deploy.settings.DeploySettings, e.g. stale_after=0.05); repeatable",
    )
    deploy.add_argument("--out", help="write the deployment's report (JSON) here")
    deploy.add_argument("-q", "--quiet", action="store_true", help="no stage lines")
    deploy.set_defaults(handler=_command_deploy)

    sim_robot = commands.add_parser(
        "sim-robot",
        help="a simulated robot on the wire: our MuJoCo plant on its low-level topics (docs/deploy.md)",
    )
    sim_robot.add_argument("--robot", default="go2", help="robot name (default go2)")
    wire_arguments(sim_robot, 1)
    sim_robot.set_defaults(network_interface="lo")
    sim_robot.add_argument("--duration", type=float, help="simulated s to serve (default: until Ctrl-C)")
    sim_robot.add_argument("--latency", type=float, default=0.0, help="s of added link latency, each way")
    sim_robot.add_argument("--jitter", type=float, default=0.0, help="s of added uniform jitter, each way")
    sim_robot.add_argument("--loss", type=float, default=0.0, help="fraction of messages lost, each way")
    sim_robot.add_argument("--outage", help="START:DURATION[,...] s of simulated time without states")
    sim_robot.add_argument(
        "--signal-outage", type=float, default=0.3, help="s of link outage each SIGUSR1 starts (default 0.3)"
    )
    sim_robot.add_argument(
        "--realtime-priority",
        type=_priority,
        default=SIM_ROBOT_PRIORITY,
        help="the physics loop in SCHED_FIFO at this priority where the OS allows it, as a robot's own "
        f"firmware runs hard real time (default {SIM_ROBOT_PRIORITY}; 0: the normal class)",
    )
    sim_robot.add_argument(
        "--viewer", action="store_true", help="watch the simulated robot in MuJoCo's viewer (needs a display)"
    )
    sim_robot.add_argument("--out", help="write the summary (JSON, with the true base motion) here")
    sim_robot.set_defaults(handler=_command_sim_robot)


def _add_robot_parser(commands: argparse._SubParsersAction) -> None:
    """``cafe-mpc robot``: a robot's summary and its Pinocchio/MuJoCo consistency check."""
    robot_parser = commands.add_parser("robot", help="robot summary and Pinocchio/MuJoCo consistency check")
    robot_parser.add_argument(
        "name",
        nargs="?",
        help="robot name (mini_cheetah, go1) or robot YAML file; with --init: the new robot's name",
    )
    robot_parser.add_argument(
        "--init",
        metavar="MODEL_FILE",
        help="write a starting robot file for a URDF or MJCF (legs, feet and limits found, what is missing "
        "marked FILL IN) to --out, then load it",
    )
    robot_parser.add_argument(
        "--out", help="with --init: the robot file to write (default ./<model file>.yaml)"
    )
    robot_parser.add_argument("--json", action="store_true", help="print one JSON object")
    robot_parser.add_argument("--samples", type=int, default=5, help="random configurations to compare")
    robot_parser.set_defaults(handler=_command_robot)


def _add_compile_parser(commands: argparse._SubParsersAction) -> None:
    """``cafe-mpc compile``: the numba kernels compiled and cached before the first run."""
    compile_parser = commands.add_parser(
        "compile",
        help="compile and cache the numba kernels (what a first run does before it moves; make install "
        "runs it)",
    )
    compile_parser.add_argument(
        "--presets", default="trot", help="comma-separated presets whose first 0.1 s is run (default trot)"
    )
    compile_parser.add_argument("--quiet", action="store_true", help="no stage lines")
    compile_parser.set_defaults(handler=_command_compile)


def _add_bench_parser(commands: argparse._SubParsersAction) -> None:
    """``cafe-mpc bench``: the solver and MPC benchmarks."""
    bench_parser = commands.add_parser(
        "bench", help="benchmarks (solver: MS-iLQR vs Crocoddyl FDDP; mpc: closed-loop update times per gait)"
    )
    bench_parser.add_argument("what", choices=["solver", "mpc"], help="what to benchmark")
    bench_parser.add_argument("--gaits", default="trot,bound", help="mpc: comma-separated gait presets")
    bench_parser.add_argument("--duration", type=float, default=4.0, help="mpc: simulated seconds per gait")
    bench_parser.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="mpc: config override for every gait; repeatable"
    )
    bench_parser.add_argument("--json", action="store_true", help="print one JSON object")
    bench_parser.add_argument("--iterations", type=int, default=10, help="iterations per solve")
    bench_parser.add_argument(
        "--rounds", type=int, default=20, help="solver: interleaved rounds (each side solves once per round)"
    )
    bench_parser.set_defaults(handler=_command_bench)


def _add_optimize_parser(commands: argparse._SubParsersAction) -> None:
    """``cafe-mpc optimize``: offline whole-body trajectory optimisation of a task."""
    from cafe_mpc.trajopt.presets import TASKS

    optimize_parser = commands.add_parser(
        "optimize",
        help=f"offline whole-body trajectory optimisation ({', '.join(TASKS)})",
        description=(
            "Offline multi-phase whole-body trajectory optimisation with the MS-iLQR (paper Sec. VI-B,\n"
            "Appendix). Writes <task>.npz (the trajectory), <task>.yaml (its settings; re-run it with\n"
            "cafe-mpc optimize <task>.yaml), roll.png, height.png, lateral_position.png, torques.png,\n"
            "grfs.png, video.mp4 (kinematic replay, needs off-screen GL) and summary.json."
        ),
        epilog=(
            "examples:\n"
            "  cafe-mpc optimize barrel-roll                       # the in-place barrel roll\n"
            "  cafe-mpc optimize barrel-roll --set solver.max_al_iterations=40 --out out/br\n"
            "  cafe-mpc optimize barrel-roll --set phases.2.terminal.base_position.5=5  # authors' weight\n"
            "  cafe-mpc optimize out/br/barrel_roll.yaml           # re-run a written settings file"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    optimize_parser.add_argument("task", help=f"task preset ({', '.join(TASKS)}) or a task YAML file")
    optimize_parser.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a task key by its dotted path; repeatable",
    )
    optimize_parser.add_argument("--out", help="output folder (default runs/<time>-<task>/)")
    optimize_parser.add_argument("--no-video", action="store_true", help="skip the video")
    optimize_parser.add_argument(
        "--verbose-solver", action="store_true", help="print one line per MS-iLQR iteration"
    )
    optimize_parser.set_defaults(handler=_command_optimize)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The whole command line's parser. The experiments' subparsers import every experiment (and so the
    simulator and Dask), the optimiser's the trajectory optimisation: each is built only when the command
    line is ``cafe-mpc experiment ...`` (``optimize ...``) or ``argv`` is None, so that ``cafe-mpc --help``,
    ``--version`` and the other commands start fast."""
    parser = _Parser(prog="cafe-mpc", description="CAFE-MPC on a simulated quadruped")
    parser.add_argument("-v", "--verbose", action="store_true", help="log at INFO level to stderr")
    parser.add_argument("--version", action="version", version=f"cafe-mpc {_version()}")
    commands = parser.add_subparsers(dest="command", required=True)

    from cafe_mpc.config import available_presets

    presets = ", ".join(available_presets())
    _add_run_parser(commands, presets)
    _add_config_parser(commands, presets)
    if argv is None or _command_word(argv) == "experiment":
        _add_experiment_parser(commands)
    else:
        commands.add_parser(
            "experiment", help="the paper's experiments, in parallel on Dask (cafe-mpc experiment --list)"
        )
    _add_report_parser(commands)
    _add_robot_parser(commands)
    _add_compile_parser(commands)
    _add_bench_parser(commands)
    if argv is None or _command_word(argv) == "optimize":  # its parser imports the trajectory optimiser
        _add_optimize_parser(commands)
    else:
        commands.add_parser("optimize", help="offline whole-body trajectory optimisation (--help: the tasks)")
    _add_robot_io_parsers(commands, presets)
    return parser


def _say_starting(argv: list[str]) -> None:
    """``cafe-mpc run`` at a terminal: one line at once, before the seconds of imports (a person waiting
    sees that it started; a script or a test, not at a terminal, gets no extra line)."""
    words = [word for word in argv if not word.startswith("-")]
    if words[:1] != ["run"] or {"-h", "--help", "--quiet"} & set(argv) or not sys.stderr.isatty():
        return
    print(
        f"cafe-mpc: {words[1] if len(words) > 1 else 'run'}: loading the libraries",
        file=sys.stderr,
        flush=True,
    )


def main(argv: list[str] | None = None) -> int:
    _say_starting(sys.argv[1:] if argv is None else list(argv))
    parser = build_parser(sys.argv[1:] if argv is None else list(argv))
    arguments = _parse_arguments(parser, argv)
    if arguments is None:
        return EXIT_USAGE
    console = logging.StreamHandler()
    console.setLevel(logging.INFO if arguments.verbose else logging.WARNING)
    console.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    console.addFilter(lambda record: not record.name.startswith("cafe_mpc.stage"))  # printed by _talk
    logging.getLogger().addHandler(console)
    from cafe_mpc.config import ConfigError
    from cafe_mpc.control.process import MpcProcessError
    from cafe_mpc.robots.robot import RobotLoadError
    from cafe_mpc.trajopt.task import TrajOptTaskError
    from cafe_mpc_lab.experiments.registry import SweepError
    from cafe_mpc_lab.report.html import ReportError
    from cafe_mpc_lab.sim.loop import INTERRUPT, ControllerError
    from cafe_mpc_lab.sim.plant import SimulationDiverged
    from cafe_mpc_lab.sim.viewer import ViewerUnavailable

    def interrupt(signal_number: int, frame: object) -> None:
        INTERRUPT.set()  # the loop's next tick raises it again if this one is swallowed
        raise KeyboardInterrupt

    main_thread = threading.current_thread() is threading.main_thread()
    previous_handler = signal.signal(signal.SIGINT, interrupt) if main_thread else None
    try:
        return int(arguments.handler(arguments))
    except (
        ConfigError,
        RobotLoadError,
        TrajOptTaskError,
        FileExistsError,
        ViewerUnavailable,
        ReportError,
        _UsageError,
    ) as error:
        print(f"cafe-mpc: error: {error}", file=sys.stderr)
        return EXIT_USAGE
    except (SimulationDiverged, ControllerError, MpcProcessError, SweepError, ValueError) as error:
        print(f"cafe-mpc: error: {error}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("cafe-mpc: interrupted", file=sys.stderr)
        return 130
    finally:
        INTERRUPT.clear()
        if main_thread:
            signal.signal(signal.SIGINT, previous_handler)


if __name__ == "__main__":
    sys.exit(main())
