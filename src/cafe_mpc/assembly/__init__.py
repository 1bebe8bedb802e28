"""How a validated run config becomes a controller: the one place that builds planner, low level, fallback,
real-time front end and estimator front end, for the command line, the experiments, the benchmarks and the
library (``cafe_mpc.Controller``) alike. It imports no simulator.

* ``checks``: the config checked against its robot and the library (robot file, gait names, schedules,
  commands within the robot's range, trajectories, plant options), one ``ConfigError`` line naming the key;
  ``load_run_config`` loads and checks;
* ``resolve``: the config resolved once against its robot before anything is built (``resolve(config,
  robot) -> ResolvedRun``: the robot's scale, the scaled schedule and gaits, the torque limits, the contact
  model, what the run commands), which every builder and the run's metrics read;
* ``references``: the reference the MPC tracks (locomotion, composed with stored trajectories);
* ``controllers``: the planner and the low level through the registries (``planners.registry``,
  ``low_level.registry``), the MPC loop (inline or in its own process), the state estimator in front.
"""

from cafe_mpc.assembly.checks import check_config, load_run_config
from cafe_mpc.assembly.controllers import (
    RunController,
    build_controller,
    build_estimator,
    build_low_level,
    build_mpc_loop,
    build_planner,
    build_sensing_controller,
    low_level_name,
    process_planner,
    runs_alone,
)
from cafe_mpc.assembly.references import build_reference, reference_profile
from cafe_mpc.assembly.resolve import resolve

__all__ = [
    "RunController",
    "build_controller",
    "build_estimator",
    "build_low_level",
    "build_mpc_loop",
    "build_planner",
    "build_reference",
    "build_sensing_controller",
    "check_config",
    "load_run_config",
    "low_level_name",
    "process_planner",
    "reference_profile",
    "resolve",
    "runs_alone",
]
