"""Command line: ``cafe-mpc run | experiment | robot | bench | optimize``.

Every user error (bad preset, key, value, robot file, NaN state) ends with one line ``cafe-mpc: error: ...``
on stderr and a non-zero exit code, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

EXIT_USAGE = 2
EXIT_FAILED = 1


def _command_run(arguments: argparse.Namespace) -> int:
    from cafe_mpc.config import load_config
    from cafe_mpc.experiments.run import default_out_dir, run

    overrides = list(arguments.set or [])
    if arguments.duration is not None:
        overrides.append(f"simulation.duration={arguments.duration}")
    if arguments.render:
        overrides.append("output.render=true")
    if arguments.realtime:
        overrides.append("simulation.realtime=true")
    config = load_config(arguments.config, overrides)
    out_dir = Path(arguments.out) if arguments.out else default_out_dir(config)
    result = run(config, out_dir, show_progress=True)
    metrics = result.metrics
    print(
        f"{config.name}: fell={metrics['fell']} base_height_mean={metrics['base_height_mean']:.3f} m "
        f"sim {metrics['sim_time_s']:.2f} s in {metrics['wall_time_s']:.2f} s "
        f"(real-time factor {metrics['real_time_factor']:.2f})"
    )
    if config.gait is not None:
        print(_gait_summary(metrics))
    if "render_error" in metrics:
        print(f"no video: {metrics['render_error']}")
    print(f"results in {result.out_dir}")
    return 0


def _command_experiment(arguments: argparse.Namespace) -> int:
    from cafe_mpc.experiments.comparisons import run_experiment

    result = run_experiment(
        arguments.name,
        out_dir=Path(arguments.out) if arguments.out else None,
        duration=arguments.duration,
        overrides=list(arguments.set or []),
        schedules=arguments.schedules,
        gaits=arguments.gaits,
        warm_starts=arguments.warm_starts,
        show_progress=True,
        echo=print,
    )
    print((result.out_dir / "comparison.md").read_text().rstrip())
    print(f"results in {result.out_dir} (comparison.json, .md, .png; one folder per variant)")
    if result.errors:
        failed = ", ".join(result.errors)
        print(f"cafe-mpc: error: variants ended in an error: {failed} (see comparison.json)", file=sys.stderr)
        return EXIT_FAILED
    return 0


def _number(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _gait_summary(metrics: dict) -> str:
    """One line of tracking, MPC and low-level numbers for a gait run."""
    mpc, wbc = metrics.get("mpc") or {}, metrics.get("wbc") or {}
    return (
        f"vx_mean={_number(metrics.get('vx_mean'))} m/s (window from {metrics['metrics_window_start_s']} s) "
        f"vx_rms_error={_number(metrics.get('vx_rms_error'))} "
        f"pitch_rms={_number(metrics.get('pitch_rms'))} rad; "
        f"mpc ({(metrics.get('timing') or {}).get('mode')} latency) solves={mpc.get('solves')} "
        f"failures={mpc.get('failures')} update median {_number(mpc.get('update_ms_median'), 1)} ms "
        f"latency median {_number(mpc.get('latency_ms_median'), 1)} ms "
        f"rate {_number(mpc.get('rate_hz'), 1)} Hz; "
        f"{wbc.get('controller')}: torque limit violations {wbc.get('torque_limit_violations')}, "
        f"friction cone violations {wbc.get('friction_cone_violations')}, "
        f"foot slip max {_number(wbc.get('foot_slip_max_m'), 4)} m"
    )


def _command_robot(arguments: argparse.Namespace) -> int:
    from cafe_mpc.dynamics.srb import lumped_inertia, srb_parameters
    from cafe_mpc.robots.robot import load_robot
    from cafe_mpc.sim.consistency import check_consistency

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


def _command_bench(arguments: argparse.Namespace) -> int:
    if arguments.what == "mpc":
        from cafe_mpc.bench.mpc_bench import format_report, run_mpc_benchmark
        from cafe_mpc.config import load_config

        gaits = tuple(gait.strip() for gait in arguments.gaits.split(",") if gait.strip())
        if not gaits:
            raise ValueError("--gaits needs at least one preset, e.g. --gaits trot,bound")
        if not arguments.duration > 0:
            raise ValueError(f"--duration must be positive, got {arguments.duration}")
        for gait in gaits:  # bad names and overrides fail before anything runs
            load_config(gait, list(arguments.set or []))
        result = run_mpc_benchmark(gaits, arguments.duration, tuple(arguments.set or []))
        print(json.dumps(result["gaits"], indent=2) if arguments.json else format_report(result))
        return 0
    from cafe_mpc.bench.solver_bench import format_report, run_solver_benchmark

    if arguments.iterations < 1 or arguments.repeats < 1:
        raise ValueError("--iterations and --repeats must be at least 1")
    result = run_solver_benchmark(arguments.iterations, arguments.repeats)
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cafe-mpc", description="CAFE-MPC on a simulated quadruped")
    parser.add_argument("-v", "--verbose", action="store_true", help="log at INFO level to stderr")
    commands = parser.add_subparsers(dest="command", required=True)

    from cafe_mpc.config import available_presets

    presets = ", ".join(available_presets())
    run_parser = commands.add_parser(
        "run",
        help="run a preset or a YAML config in simulation",
        description=f"Run a preset or a YAML config in simulation. Presets: {presets}.",
        epilog=(
            "examples:\n"
            "  cafe-mpc run bound                      # bound forward at 0.5 m/s (CAFE-MPC + VWBC), 10 s\n"
            "  cafe-mpc run bound --duration 2 --set wbc=riccati --set mpc.schedule=S0\n"
            "  cafe-mpc run trot --set gait.commands.0.vx=0.8 --set mpc.period=0.03\n"
            "  cafe-mpc run bound-push --set wbc=riccati   # the paper's push test, Riccati controller"
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
    run_parser.add_argument("--render", action="store_true", help="write a video (needs off-screen GL)")
    run_parser.add_argument(
        "--realtime",
        action="store_true",
        help="against the wall clock: plant + low-level controller at 500 Hz, the MPC in its own process",
    )
    run_parser.set_defaults(handler=_command_run)

    from cafe_mpc.experiments.comparisons import EXPERIMENTS

    listing = "\n".join(
        f"  {e.name:<11} {e.title} ({e.paper}); default {e.default_duration:g} s"
        for e in EXPERIMENTS.values()
    )
    experiment_parser = commands.add_parser(
        "experiment",
        help=f"compare variants ({', '.join(EXPERIMENTS)})",
        description=(
            "Run several variants of a preset side by side (each in its own subfolder with its usual\n"
            "files) and write comparison.json, comparison.md (a markdown table) and comparison.png.\n\n"
            f"experiments:\n{listing}"
        ),
        epilog=(
            "examples:\n"
            "  cafe-mpc experiment schedules                    # bound: S0 (no SRB tail) vs S4, 10 s each\n"
            "  cafe-mpc experiment schedules --schedules S0,S1,S2,S4\n"
            "  cafe-mpc experiment push                         # bound-push: VWBC vs Riccati, 5 s each\n"
            "  cafe-mpc experiment warm-start --duration 2      # QP iterations: bound and pace x 3 modes"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    experiment_parser.add_argument("name", help=f"experiment: {', '.join(EXPERIMENTS)}")
    experiment_parser.add_argument("--duration", type=float, help="simulated seconds per variant")
    experiment_parser.add_argument("--out", help="output folder (default runs/<time>-experiment-<name>/)")
    experiment_parser.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a config key in every variant (not the keys the experiment varies); repeatable",
    )
    experiment_parser.add_argument(
        "--schedules", metavar="S0,S4,...", help="schedules: the model schedules to compare (default S0,S4)"
    )
    experiment_parser.add_argument(
        "--gaits", metavar="bound,pace", help="warm-start: gait presets (default bound,pace)"
    )
    experiment_parser.add_argument(
        "--warm-starts",
        metavar="previous,plan,none",
        help="warm-start: VWBC warm-start modes (default previous,plan,none; also equality)",
    )
    experiment_parser.set_defaults(handler=_command_experiment)

    robot_parser = commands.add_parser("robot", help="robot summary and Pinocchio/MuJoCo consistency check")
    robot_parser.add_argument("name", help="robot name (mini_cheetah, go1) or robot YAML file")
    robot_parser.add_argument("--json", action="store_true", help="print one JSON object")
    robot_parser.add_argument("--samples", type=int, default=5, help="random configurations to compare")
    robot_parser.set_defaults(handler=_command_robot)

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
    bench_parser.add_argument("--repeats", type=int, default=5, help="solves per problem")
    bench_parser.set_defaults(handler=_command_bench)

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
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    arguments = parser.parse_args(argv)
    console = logging.StreamHandler()
    console.setLevel(logging.INFO if arguments.verbose else logging.WARNING)
    console.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    logging.getLogger().addHandler(console)
    from cafe_mpc.config import ConfigError
    from cafe_mpc.control.realtime import MpcProcessError
    from cafe_mpc.robots.robot import RobotLoadError
    from cafe_mpc.sim.loop import ControllerError
    from cafe_mpc.sim.plant import SimulationDiverged
    from cafe_mpc.trajopt.task import TrajOptTaskError

    try:
        return int(arguments.handler(arguments))
    except (ConfigError, RobotLoadError, TrajOptTaskError, FileExistsError) as error:
        print(f"cafe-mpc: error: {error}", file=sys.stderr)
        return EXIT_USAGE
    except (SimulationDiverged, ControllerError, MpcProcessError, ValueError) as error:
        print(f"cafe-mpc: error: {error}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("cafe-mpc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
