"""Whole-body trajectory files (``.npz``): the format, contact codes, writing and validated loading.

The offline trajectory optimisation (``cafe_mpc.trajopt``, paper Sec. VI-B and Appendix) writes one; a
stored-trajectory reference reads it back. One file holds one trajectory of ``N`` knots at a fixed time step
(``numpy.savez``, no pickled objects; ``format_version`` 1):

============================  ==================  ===========================================================
field                         shape / type        meaning
============================  ==================  ===========================================================
``format_version``            int                 ``1``
``name``                      str                 what the trajectory is (``"barrel-roll"``)
``robot``                     str                 robot name (``cafe_mpc.robots``; sets nq, nv, nu)
``dt``                        float > 0           knot spacing (s)
``times``                     (N + 1,)            knot times, strictly increasing, spaced by ``dt``
``xs``                        (N + 1, nq + nv)    ``[q, v]`` per knot: base position, quaternion (x, y, z, w),
                                                  joints; base-frame linear and angular velocity, joint rates
                                                  (Pinocchio free flyer). At a touchdown the state is the
                                                  *post-impact* one.
``us``                        (N, nu)             joint torques of each interval ``[times[k], times[k+1])``
``contacts``                  (N, 4) uint8        stance flags (1 = stance) of each interval, leg order
                                                  ``FL, FR, HL, HR``
``forces``                    (N, 4, 3)           world-frame ground reaction forces of each interval (zero
                                                  on swing feet), from the planning model's contact dynamics
``phase_contacts``            (P,) str            contact code of each phase (below)
``switching_times``           (P + 1,)            phase boundaries, ``times[0]`` ... ``times[-1]``, on knots
``phase_names``               (P,) str            names of the phases
============================  ==================  ===========================================================

Contact codes (the paper's notation, Sec. VI): ``"FS"`` full stance, ``"FT"`` flight, otherwise the stance
legs joined by ``-`` in leg order, e.g. ``"FR-HR"`` (right legs) or ``"FL-HR"`` (a trot pair). Dynamics
between knots: ``x[k+1] = f_phase(x[k], us[k])`` inside a phase; at a switch into a phase where a foot
touches down, ``x[k+1] = P(f(x[k], us[k]))`` with the impact map ``P`` (Eqs. (22), (24)); take-off is the
identity.

``load_trajectory`` checks everything (fields present, shapes against the robot's ``nq``/``nv``/``nu``,
finite values, unit quaternions, monotone times on the ``dt`` grid, known contact codes, per-knot flags that
match their phase) and raises one ``TrajectoryFileError`` (a ``ValueError``) that names the file and the
field.
"""

from __future__ import annotations

import itertools
import math
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import numpy as np

from cafe_mpc.core.contacts import LEG_NAMES, ContactFlags, as_contact_flags

if TYPE_CHECKING:
    from cafe_mpc.robots.robot import Robot

FORMAT_VERSION = 1
DATA_DIR = Path(__file__).parent / "data"
PACKAGED_TRAJECTORIES: dict[str, str] = {
    "barrel-roll": "barrel_roll.npz",
    "running-barrel-roll": "running_barrel_roll.npz",
    "running-barrel-roll-from-pace": "running_barrel_roll_from_pace.npz",
    "backflip": "backflip.npz",
    "front-flip": "front_flip.npz",
    "running-front-flip": "running_front_flip.npz",
    "spin": "spin.npz",
    "box-jump": "box_jump.npz",
    "box-jump-off": "box_jump_off.npz",
    "box-jump-25": "box_jump_25.npz",
    "box-jump-30": "box_jump_30.npz",
}
"""Trajectories shipped with the package (``reference/data/``), by name."""

FULL_STANCE_CODE = "FS"
FLIGHT_CODE = "FT"
TIME_TOLERANCE = 1e-9
QUATERNION_TOLERANCE = 1e-6
FIELDS = (
    "format_version",
    "name",
    "robot",
    "dt",
    "times",
    "xs",
    "us",
    "contacts",
    "forces",
    "phase_contacts",
    "switching_times",
    "phase_names",
)


class TrajectoryFileError(ValueError):
    """A trajectory file that cannot be used; names the file and the offending field."""

    def __init__(self, path: str | Path, field: str | None, reason: str) -> None:
        self.path = str(path)
        self.field = field
        self.reason = reason
        where = f"field {field!r}: " if field else ""
        super().__init__(f"trajectory file {self.path}: {where}{reason}")


# --------------------------------------------------------------------------------------------------
# Contact codes
# --------------------------------------------------------------------------------------------------


def contact_code(flags: Sequence[bool]) -> str:
    """Stance flags -> contact code: ``"FS"``, ``"FT"`` or the stance legs joined by ``-`` (``"FR-HR"``)."""
    flags = as_contact_flags(flags)
    if all(flags):
        return FULL_STANCE_CODE
    if not any(flags):
        return FLIGHT_CODE
    return "-".join(leg for leg, on in zip(LEG_NAMES, flags, strict=True) if on)


def parse_contact_code(code: str) -> ContactFlags:
    """Contact code -> stance flags (``ValueError`` for an unknown code; legs must be in leg order)."""
    if not isinstance(code, str):
        raise ValueError(f"contact code must be a string, got {code!r}")
    text = code.strip().upper()
    if text == FULL_STANCE_CODE:
        return (True, True, True, True)
    if text == FLIGHT_CODE:
        return (False, False, False, False)
    legs = text.split("-")
    known = "'FS', 'FT' or stance legs joined by '-' in the order FL, FR, HL, HR (e.g. 'FR-HR')"
    if any(leg not in LEG_NAMES for leg in legs) or len(set(legs)) != len(legs):
        raise ValueError(f"unknown contact code {code!r}: use {known}")
    indices = [LEG_NAMES.index(leg) for leg in legs]
    if indices != sorted(indices):
        raise ValueError(f"contact code {code!r}: legs must be in the order FL, FR, HL, HR")
    flags = tuple(leg in legs for leg in LEG_NAMES)
    if all(flags):
        return (True, True, True, True)
    return flags  # type: ignore[return-value]


# --------------------------------------------------------------------------------------------------
# The trajectory
# --------------------------------------------------------------------------------------------------


@dataclass
class WholeBodyTrajectory:
    """A whole-body trajectory on a fixed knot grid (see the module docstring for every field)."""

    name: str
    robot: str
    dt: float
    times: np.ndarray
    xs: np.ndarray
    us: np.ndarray
    contacts: np.ndarray
    forces: np.ndarray
    phase_contacts: tuple[str, ...]
    switching_times: np.ndarray
    phase_names: tuple[str, ...]

    @property
    def n_knots(self) -> int:
        """Number of intervals ``N`` (``N + 1`` states)."""
        return len(self.us)

    @property
    def n_phases(self) -> int:
        return len(self.phase_contacts)

    @property
    def phase_stances(self) -> list[ContactFlags]:
        return [parse_contact_code(code) for code in self.phase_contacts]

    def phase_knots(self) -> list[range]:
        """Knot indices (intervals) of each phase."""
        boundaries = np.rint((self.switching_times - self.times[0]) / self.dt).astype(int)
        return [range(int(a), int(b)) for a, b in itertools.pairwise(boundaries)]

    def from_phase(self, index: int) -> WholeBodyTrajectory:
        """The trajectory from the start of phase ``index`` on (its knots, times and phases; the earlier
        phases dropped). The running barrel roll plays the in-place roll from its right-stance phase
        (paper Sec. VII-C: "starting the barrel roll reference with right legs at stance")."""
        if not 0 <= index < self.n_phases:
            raise ValueError(f"phase {index} does not exist: the trajectory has {self.n_phases} phases")
        if index == 0:
            return self
        first = self.phase_knots()[index].start
        return WholeBodyTrajectory(
            name=self.name,
            robot=self.robot,
            dt=self.dt,
            times=self.times[first:].copy(),
            xs=self.xs[first:].copy(),
            us=self.us[first:].copy(),
            contacts=self.contacts[first:].copy(),
            forces=self.forces[first:].copy(),
            phase_contacts=tuple(self.phase_contacts[index:]),
            switching_times=self.switching_times[index:].copy(),
            phase_names=tuple(self.phase_names[index:]),
        )

    def validate(self, nq: int, nv: int, nu: int, source: str | Path = "<memory>") -> None:
        """Raise ``TrajectoryFileError`` (naming ``source`` and the field) unless everything is consistent."""
        _validate(self, nq, nv, nu, str(source))


def _fail(source: str, field: str | None, reason: str) -> NoReturn:
    raise TrajectoryFileError(source, field, reason)


def _check_array(
    source: str, field: str, value: np.ndarray, shape: tuple[int, ...], meaning: str = ""
) -> None:
    if value.shape != shape:
        _fail(source, field, f"expected shape {shape}{meaning}, got {value.shape}")
    if not np.all(np.isfinite(value)):
        index = tuple(int(i) for i in np.argwhere(~np.isfinite(value))[0])
        _fail(source, field, f"non-finite value (NaN or inf) at index {index}")


def _validate(trajectory: WholeBodyTrajectory, nq: int, nv: int, nu: int, source: str) -> None:
    t = trajectory
    if not isinstance(t.name, str) or not t.name:
        _fail(source, "name", "must be a non-empty string")
    if not isinstance(t.robot, str) or not t.robot:
        _fail(source, "robot", "must be a non-empty string")
    if not (isinstance(t.dt, float | int) and math.isfinite(t.dt) and t.dt > 0):
        _fail(source, "dt", f"must be a positive finite number, got {t.dt!r}")
    times = t.times
    if times.ndim != 1 or len(times) < 2:
        _fail(source, "times", f"expected a vector of N + 1 >= 2 knot times, got shape {times.shape}")
    n = len(times) - 1
    _check_array(source, "times", times, (n + 1,))
    steps = np.diff(times)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        _fail(
            source,
            "times",
            f"not strictly increasing: times[{k}] = {times[k]}, times[{k + 1}] = {times[k + 1]}",
        )
    if np.max(np.abs(steps - t.dt)) > 1e-6:
        k = int(np.argmax(np.abs(steps - t.dt)))
        _fail(source, "times", f"not on the dt = {t.dt} grid: times[{k + 1}] - times[{k}] = {steps[k]}")
    _check_array(
        source, "xs", t.xs, (n + 1, nq + nv), f" (N + 1 = {n + 1} knot times, nq + nv = {nq} + {nv})"
    )
    quaternion_norms = np.linalg.norm(t.xs[:, 3:7], axis=1)
    if np.max(np.abs(quaternion_norms - 1.0)) > QUATERNION_TOLERANCE:
        k = int(np.argmax(np.abs(quaternion_norms - 1.0)))
        _fail(source, "xs", f"base quaternion xs[{k}, 3:7] is not unit (norm {quaternion_norms[k]})")
    _check_array(source, "us", t.us, (n, nu), f" (N = {n} intervals, nu = {nu} joint torques)")
    contacts = t.contacts
    if contacts.shape != (n, 4):
        _fail(source, "contacts", f"expected shape {(n, 4)}, got {contacts.shape}")
    if not np.all(np.isin(contacts, (0, 1))):
        _fail(source, "contacts", "stance flags must be 0 or 1")
    _check_array(source, "forces", t.forces, (n, 4, 3))
    n_phases = len(t.phase_contacts)
    if n_phases == 0:
        _fail(source, "phase_contacts", "needs at least one phase")
    stances = []
    for index, code in enumerate(t.phase_contacts):
        try:
            stances.append(parse_contact_code(code))
        except ValueError as error:
            _fail(source, "phase_contacts", f"phase {index}: {error}")
    if len(t.phase_names) != n_phases:
        _fail(source, "phase_names", f"expected {n_phases} names (one per phase), got {len(t.phase_names)}")
    switching = t.switching_times
    _check_array(source, "switching_times", switching, (n_phases + 1,))
    if np.any(np.diff(switching) <= 0):
        _fail(source, "switching_times", f"not strictly increasing: {switching.tolist()}")
    if abs(switching[0] - times[0]) > 1e-6 or abs(switching[-1] - times[-1]) > 1e-6:
        _fail(
            source,
            "switching_times",
            f"must run from times[0] = {times[0]} to times[-1] = {times[-1]}, got {switching.tolist()}",
        )
    offsets = (switching - times[0]) / t.dt
    if np.max(np.abs(offsets - np.rint(offsets))) > 1e-6:
        _fail(source, "switching_times", f"not on the knot grid (dt = {t.dt}): {switching.tolist()}")
    for index, (knots, stance) in enumerate(zip(t.phase_knots(), stances, strict=True)):
        expected = np.array(stance, dtype=contacts.dtype)
        if np.any(contacts[knots.start : knots.stop] != expected):
            _fail(
                source,
                "contacts",
                f"knots {knots.start}..{knots.stop - 1} differ from phase {index}: {t.phase_contacts[index]}",
            )
    swing = contacts == 0
    if np.any(t.forces[swing] != 0.0):
        _fail(source, "forces", "non-zero force on a swing foot")


# --------------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------------


def save_trajectory(path: str | Path, trajectory: WholeBodyTrajectory, robot: Robot | None = None) -> Path:
    """Validate (against ``robot`` when given) and write ``trajectory`` to ``path`` (``.npz``)."""
    path = Path(path)
    if robot is not None:
        trajectory.validate(robot.nq, robot.nv, robot.nu, path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as handle:
        np.savez(
            handle,
            format_version=np.array(FORMAT_VERSION),
            name=np.array(trajectory.name),
            robot=np.array(trajectory.robot),
            dt=np.array(float(trajectory.dt)),
            times=np.asarray(trajectory.times, dtype=float),
            xs=np.asarray(trajectory.xs, dtype=float),
            us=np.asarray(trajectory.us, dtype=float),
            contacts=np.asarray(trajectory.contacts, dtype=np.uint8),
            forces=np.asarray(trajectory.forces, dtype=float),
            phase_contacts=np.array(trajectory.phase_contacts, dtype=str),
            switching_times=np.asarray(trajectory.switching_times, dtype=float),
            phase_names=np.array(trajectory.phase_names, dtype=str),
        )
    return path


def _scalar(source: str, archive, field: str, kind: type):
    value = archive[field]
    if value.shape != ():
        _fail(source, field, f"expected a single value, got shape {value.shape}")
    item = value.item()
    if kind is str:
        if not isinstance(item, str):
            _fail(source, field, f"expected a string, got {type(item).__name__}")
        return item
    if kind is int:
        if not isinstance(item, int | np.integer) or isinstance(item, bool):
            _fail(source, field, f"expected an integer, got {item!r}")
        return int(item)
    if not isinstance(item, float | int) or isinstance(item, bool):
        _fail(source, field, f"expected a number, got {item!r}")
    return float(item)


def _numeric(source: str, archive, field: str) -> np.ndarray:
    value = archive[field]
    if value.dtype.kind not in "fiub":
        _fail(source, field, f"expected numbers, got dtype {value.dtype}")
    return np.asarray(value, dtype=float)


def _strings(source: str, archive, field: str) -> tuple[str, ...]:
    value = archive[field]
    if value.ndim != 1 or value.dtype.kind != "U":
        _fail(source, field, f"expected a vector of strings, got dtype {value.dtype} and shape {value.shape}")
    return tuple(str(item) for item in value)


def load_trajectory(path: str | Path, robot: Robot | None = None) -> WholeBodyTrajectory:
    """Read and validate a trajectory file.

    ``robot``: check the dimensions against this robot (its name must match the file's); ``None`` loads the
    robot the file names. Every problem raises ``TrajectoryFileError`` naming the file and the field.
    """
    source = str(path)
    try:
        archive = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        _fail(source, None, "does not exist")
    except (OSError, ValueError, zipfile.BadZipFile) as error:
        _fail(source, None, f"is not a readable .npz file ({error})")
    if not isinstance(archive, np.lib.npyio.NpzFile):
        _fail(source, None, "is not an .npz archive of named fields")
    with archive:
        missing = [field for field in FIELDS if field not in archive.files]
        if missing:
            _fail(source, missing[0], f"missing (a trajectory file needs {', '.join(FIELDS)})")
        try:
            version = _scalar(source, archive, "format_version", int)
            if version != FORMAT_VERSION:
                _fail(source, "format_version", f"version {version} is not supported (this package reads 1)")
            robot_name = _scalar(source, archive, "robot", str)
            trajectory = WholeBodyTrajectory(
                name=_scalar(source, archive, "name", str),
                robot=robot_name,
                dt=_scalar(source, archive, "dt", float),
                times=_numeric(source, archive, "times"),
                xs=_numeric(source, archive, "xs"),
                us=_numeric(source, archive, "us"),
                contacts=_numeric(source, archive, "contacts"),
                forces=_numeric(source, archive, "forces"),
                phase_contacts=_strings(source, archive, "phase_contacts"),
                switching_times=_numeric(source, archive, "switching_times"),
                phase_names=_strings(source, archive, "phase_names"),
            )
        except (ValueError, zipfile.BadZipFile) as error:
            if isinstance(error, TrajectoryFileError):
                raise
            _fail(source, None, f"cannot be read ({error})")
    if robot is None:
        from cafe_mpc.robots.robot import RobotLoadError, load_robot

        try:
            robot = load_robot(robot_name)
        except RobotLoadError as error:
            _fail(source, "robot", str(error))
    elif robot.name != robot_name:
        _fail(source, "robot", f"trajectory is for {robot_name!r}, not {robot.name!r}")
    trajectory.validate(robot.nq, robot.nv, robot.nu, source)
    trajectory.contacts = trajectory.contacts.astype(np.uint8)
    return trajectory


def packaged_trajectory_path(name: str, robot_name: str | None = None) -> Path:
    """Path of a trajectory shipped with the package (``PACKAGED_TRAJECTORIES``). With ``robot_name``, that
    robot's own solution of the task when one is shipped (``<stem>.<robot_name>.npz`` next to the task's
    file, written by ``cafe-mpc optimize TASK --set robot=ROBOT``), else the task's file (for the robot it
    names)."""
    if name not in PACKAGED_TRAJECTORIES:
        raise ValueError(f"no packaged trajectory {name!r}; packaged: {', '.join(PACKAGED_TRAJECTORIES)}")
    default = DATA_DIR / PACKAGED_TRAJECTORIES[name]
    if robot_name is not None:
        own = default.with_name(f"{default.stem}.{robot_name}.npz")
        if own.exists():
            return own
    return default


def packaged_trajectory_robots(name: str) -> list[str]:
    """Robots a packaged trajectory is shipped for: the robot its file names, then those with their own
    file."""
    default = packaged_trajectory_path(name)
    with np.load(default, allow_pickle=False) as archive:
        robots = [str(archive["robot"])]
    return robots + sorted(path.suffixes[-2][1:] for path in DATA_DIR.glob(f"{default.stem}.*.npz"))


def load_packaged_trajectory(name: str, robot: Robot | None = None) -> WholeBodyTrajectory:
    """Load a trajectory shipped with the package (e.g. ``"barrel-roll"``; regenerate it with
    ``cafe-mpc optimize barrel-roll``, see the README): ``robot``'s own when one is shipped
    (``packaged_trajectory_path``); ``TrajectoryFileError`` naming the robots it is shipped for otherwise."""
    path = packaged_trajectory_path(name, robot.name if robot is not None else None)
    if robot is not None:
        robots = packaged_trajectory_robots(name)
        if robot.name not in robots:
            raise TrajectoryFileError(
                path,
                "robot",
                f"packaged trajectory {name!r} is shipped for {', '.join(robots)}, not {robot.name!r}: "
                f"solve it with `cafe-mpc optimize {name} --set robot={robot.name} --out DIR` and give the "
                "written .npz as the trajectory segment's file (--set reference.segments.N.trajectory=PATH)",
            )
    return load_trajectory(path, robot)
