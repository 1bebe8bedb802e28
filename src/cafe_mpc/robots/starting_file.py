"""A starting robot file for a URDF or MJCF model file (``cafe-mpc robot --init MODEL_FILE``).

The file holds what the model tells (the source, the feet, the limits it gives, for an MJCF the foot geoms)
and, as comments, what loading derives (leg order, standing height, footholds, the standing seed) and what
the model file does not give: those keys get a placeholder marked ``FILL IN`` so that the file loads and the
robot can be tried at once, and the comment says what the value should be. A URDF that ships with
example-robot-data becomes ``source: example-robot-data`` (its plant is generated from Pinocchio's model;
MuJoCo's URDF compiler refuses several of those files).
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from cafe_mpc.core.contacts import LEG_NAMES
from cafe_mpc.robots.legs import JOINTS_PER_LEG, Legs, canonical_model, find_legs, knees_back_guess
from cafe_mpc.robots.model_file import ModelFileError, load_planning_model

PLACEHOLDER_VELOCITY = 20.0
"""rad/s written for a joint speed limit the model file does not give (marked FILL IN)."""
PLACEHOLDER_CAPACITY = 0.5
"""Torque written for a joint the model file gives no torque limit, in units of the robot's weight times its
leg length (the Mini Cheetah's motors give 0.48; marked FILL IN)."""
PLACEHOLDER_FOOT_RADIUS = 0.02
"""m written for a URDF foot without a collision sphere (marked FILL IN)."""
IMPLAUSIBLE_LIMIT = 500.0
"""A torque (Nm) or speed (rad/s) limit at or above this in a model file is a placeholder, not a motor's."""
FOOT_GEOM_TOLERANCE = 1e-6
"""m; an MJCF geom is a foot geom when its centre is this close to the foot frame."""


class StartingFileError(ValueError):
    """The model file cannot start a robot file (with the reason)."""


@dataclass
class _Lines:
    """The YAML text being written: key lines and comments."""

    lines: list[str] = field(default_factory=list)

    def add(self, text: str, comment: str = "") -> None:
        self.lines.append(f"{text}   # {comment}" if comment and text else (text or f"# {comment}"))

    def text(self) -> str:
        return "\n".join(self.lines) + "\n"


def _numbers(values: np.ndarray) -> str:
    return "[" + ", ".join(f"{float(v):.6g}" for v in values) + "]"


def _per_kind(values: np.ndarray) -> np.ndarray:
    """3 values (one per joint kind) when every leg has the same, else all 12."""
    kinds = values.reshape(-1, JOINTS_PER_LEG)
    return kinds[0] if np.all(kinds == kinds[0]) else values


def example_robot_data_name(path: Path) -> str | None:
    """The example-robot-data loader whose URDF is ``path`` (None: not one of that package's files)."""
    try:
        from example_robot_data.robots_loader import ROBOTS
    except ImportError:
        return None
    parts = path.resolve().parts
    for name, loader in ROBOTS.items():
        if not getattr(loader, "urdf_filename", ""):
            continue
        inside = Path(loader.path, loader.urdf_subpath, loader.urdf_filename).parts
        if (
            len(parts) > len(inside) + 1
            and parts[-len(inside) :] == inside
            and parts[-len(inside) - 1] == "robots"
            and getattr(loader, "free_flyer", False)
        ):
            return name
    return None


def _urdf_foot_radius(path: Path, frame: str) -> float | None:
    """Radius of the URDF link ``frame``'s collision sphere at its origin (None: none there)."""
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError):
        return None
    for link in root.iter("link"):
        if link.get("name") != frame:
            continue
        for collision in link.iter("collision"):
            origin = collision.find("origin")
            xyz = np.fromstring(origin.get("xyz", "0 0 0"), sep=" ") if origin is not None else np.zeros(3)
            sphere = collision.find("geometry/sphere")
            if sphere is not None and np.allclose(xyz, 0.0):
                return float(sphere.get("radius"))
    return None


def _urdf_base_box(path: Path, model: pin.Model) -> list[float] | None:
    """Size of the largest collision box on the URDF link that the free-flyer carries."""
    base_link = next(
        (f.name for f in model.frames if f.parentJoint == 1 and f.type == pin.FrameType.BODY), None
    )
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError):
        return None
    boxes = []
    fixed_children = {base_link}
    for joint in root.iter("joint"):  # links fixed to the base (e.g. A1's 'trunk' under 'base')
        parent, child = joint.find("parent"), joint.find("child")
        if joint.get("type") == "fixed" and parent is not None and parent.get("link") in fixed_children:
            fixed_children.add(child.get("link"))
    for link in root.iter("link"):
        if link.get("name") in fixed_children:
            for box in link.iter("box"):
                boxes.append([float(v) for v in box.get("size", "").split()])
    boxes = [b for b in boxes if len(b) == 3]
    return max(boxes, key=lambda b: float(np.prod(b))) if boxes else None


def _mjcf_foot_geoms(
    path: Path, model: pin.Model, feet: tuple[str, ...]
) -> tuple[list[str | None], list[float]]:
    """For each foot frame, the MJCF's named geom centred on it (a sphere first) and its radius (NaN: not a
    sphere), from MuJoCo's compilation at the zero configuration."""
    import mujoco

    try:
        compiled = mujoco.MjModel.from_xml_path(str(path))
    except Exception as error:  # mujoco.FatalError / ValueError with MuJoCo's message
        raise StartingFileError(f"MuJoCo cannot compile {path}: {error}") from error
    data = mujoco.MjData(compiled)
    data.qpos[:] = 0.0
    data.qpos[3] = 1.0
    mujoco.mj_kinematics(compiled, data)
    pin_data = model.createData()
    pin.framesForwardKinematics(model, pin_data, pin.neutral(model))
    names, radii = [], []
    for foot in feet:
        target = pin_data.oMf[model.getFrameId(foot)].translation
        best = None
        for geom in range(compiled.ngeom):
            name = compiled.geom(geom).name
            if not name or np.linalg.norm(data.geom_xpos[geom] - target) > FOOT_GEOM_TOLERANCE:
                continue
            is_sphere = int(compiled.geom_type[geom]) == mujoco.mjtGeom.mjGEOM_SPHERE
            candidate = (not is_sphere, name, float(compiled.geom_size[geom, 0]) if is_sphere else np.nan)
            best = candidate if best is None or candidate < best else best
        names.append(None if best is None else best[1])
        radii.append(np.nan if best is None else best[2])
    return names, radii


def _mjcf_torque_limits(path: Path, joint_names: tuple[str, ...]) -> np.ndarray:
    """What the MJCF's motors can apply at each joint (inf: nothing limits it)."""
    from cafe_mpc.robots.model_file import read_extras

    return read_extras(path, "mjcf", joint_names, ()).torque_limits


def starting_robot_file(model_file: str | Path, name: str | None = None) -> str:
    """The text of a starting robot file for ``model_file`` (URDF or MJCF); ``name``: the robot's (default:
    the file's stem). See the module docstring."""
    path = Path(model_file).expanduser().resolve()
    if not path.is_file():
        raise StartingFileError(f"model file {path} does not exist")
    source = "urdf" if path.suffix.lower() == ".urdf" else "mjcf"
    try:
        model = load_planning_model(path, source)
        legs = find_legs(model)
    except (ModelFileError, ValueError) as error:
        raise StartingFileError(str(error)) from error
    joint_names = legs.joint_names(model)
    canonical = canonical_model(model, legs)
    name = name or path.stem.replace("-", "_")
    erd_name = example_robot_data_name(path) if source == "urdf" else None
    out = _Lines()
    out.add("", f"Robot file for {path.name}, written by 'cafe-mpc robot --init' (docs/robots.md): check the")
    out.add("", "lines marked FILL IN, then run 'cafe-mpc robot THIS_FILE' and")
    out.add("", "'cafe-mpc run trot --set robot=THIS_FILE'.")
    out.add(f"name: {name}")
    if erd_name is not None:
        out.add("source: example-robot-data", "the plant is generated from Pinocchio's reading of the URDF")
        out.add(f"example_robot_data_name: {erd_name}")
    else:
        out.add(f"source: {source}")
        out.add(
            f"model_file: {path}", "or a path relative to this file, or package://<python package>/<path>"
        )
    _legs_comment(out, model, legs)
    out.add(
        f"foot_frames: [{', '.join(legs.foot_frames)}]", "found: the farthest frame on each leg's last joint"
    )
    limits = _joints_section(out, canonical, path, source, legs, joint_names)
    foot_radius = _geometry_and_plant(out, canonical, model, path, source, legs, erd_name)
    _standing_comment(out, canonical, legs, limits, foot_radius)
    return out.text()


def _legs_comment(out: _Lines, model: pin.Model, legs: Legs) -> None:
    out.add(
        "", "Legs, found from the kinematic tree and named from their x and y at the zero configuration (give"
    )
    out.add("", "leg_names, the legs of foot_frames entry by entry, only to override this):")
    for leg, foot, chain, (x, y) in zip(
        LEG_NAMES, legs.foot_frames, legs.chains, legs.positions, strict=True
    ):
        joints = ", ".join(model.names[j] for j in chain)
        out.add("", f"  {leg}: foot {foot}, joints {joints} (x {x:+.3f} m, y {y:+.3f} m)")


def _joints_section(
    out: _Lines, model: pin.Model, path: Path, source: str, legs: Legs, joint_names: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The ``joints`` section (limits the model file lacks get placeholders); returns the position limits."""
    torque = np.array(model.effortLimit[6:], dtype=float)
    if source == "mjcf":
        torque = np.minimum(torque, _mjcf_torque_limits(path, joint_names))
    velocity = np.array(model.velocityLimit[6:], dtype=float)
    lower = np.array(model.lowerPositionLimit[7:], dtype=float)
    upper = np.array(model.upperPositionLimit[7:], dtype=float)
    out.add("joints:")
    if np.all(np.isfinite(torque)) and np.all(torque < IMPLAUSIBLE_LIMIT):
        out.add("", f"  torque_limits: null -> the model file's: {_numbers(_per_kind(torque))} Nm")
    else:
        weight_torque = (
            float(sum(i.mass for i in model.inertias)) * 9.81 * float(np.mean(_leg_lengths(model, legs)))
        )
        placeholder = np.where(np.isfinite(torque), torque, round(PLACEHOLDER_CAPACITY * weight_torque, 1))
        out.add(
            f"  torque_limits: {_numbers(_per_kind(placeholder))}",
            f"FILL IN: Nm per joint kind (abad, hip, knee); the model file gives "
            f"{_numbers(_per_kind(torque))}",
        )
    if np.all(np.isfinite(velocity)) and np.all(velocity < IMPLAUSIBLE_LIMIT):
        out.add("", f"  velocity_limits: null -> the model file's: {_numbers(_per_kind(velocity))} rad/s")
    else:
        given = "none" if source == "mjcf" else _numbers(_per_kind(velocity))
        out.add(
            f"  velocity_limits: {_numbers(np.full(3, PLACEHOLDER_VELOCITY))}",
            f"FILL IN: rad/s per joint kind; the model file gives {given}",
        )
    bounded = np.isfinite(lower) & np.isfinite(upper) & (lower < upper)
    if np.all(bounded):
        out.add("", f"  position limits: the model file's, lower {_numbers(_per_kind(lower))},")
        out.add(
            "", f"    upper {_numbers(_per_kind(upper))} rad (position_lower/position_upper override them)"
        )
    else:
        lower = np.where(bounded, lower, -np.pi)
        upper = np.where(bounded, upper, np.pi)
        out.add(
            f"  position_lower: {_numbers(_per_kind(lower))}",
            "FILL IN: rad; the model file leaves joints unlimited",
        )
        out.add(f"  position_upper: {_numbers(_per_kind(upper))}", "FILL IN")
    return lower, upper


def _leg_lengths(model: pin.Model, legs: Legs) -> np.ndarray:
    from cafe_mpc.robots.robot import leg_lengths

    return leg_lengths(model, tuple(model.getFrameId(foot) for foot in legs.foot_frames))


def _geometry_and_plant(
    out: _Lines,
    canonical: pin.Model,
    model: pin.Model,
    path: Path,
    source: str,
    legs: Legs,
    erd_name: str | None,
) -> float:
    """The ``geometry`` and ``plant`` sections; returns the foot radius."""
    foot_geoms: list[str | None] = []
    if source == "mjcf":
        foot_geoms, radii = _mjcf_foot_geoms(path, model, legs.foot_frames)
        radius = float(radii[0]) if np.all(np.isfinite(radii)) and np.ptp(radii) < 1e-9 else None
        if radius is not None:
            out.add("", f"geometry.foot_radius: null -> the foot geoms' spheres, {radius:.6g} m")
        else:
            radius = float(np.nanmedian(radii)) if np.any(np.isfinite(radii)) else PLACEHOLDER_FOOT_RADIUS
            out.add("geometry:")
            out.add(
                f"  foot_radius: {radius:.6g}", "FILL IN: m; the foot geoms are not spheres of one radius"
            )
    else:
        found = [_urdf_foot_radius(path, foot) for foot in legs.foot_frames]
        radius = found[0] if found[0] is not None and all(r == found[0] for r in found) else None
        out.add("geometry:")
        if radius is not None:
            out.add(f"  foot_radius: {radius:.6g}", "the URDF's foot collision spheres")
        else:
            radius = PLACEHOLDER_FOOT_RADIUS
            out.add(
                f"  foot_radius: {radius:.6g}",
                "FILL IN: m, the foot sphere (no collision sphere at the feet)",
            )
        box = _urdf_base_box(path, model)
        if erd_name is not None or box is not None:
            comment = "the URDF's trunk collision box" if box is not None else "FILL IN: m, the trunk's box"
            box = box or _hip_box(canonical, legs)
            out.add(f"  body_box: {_numbers(np.array(box))}", comment)
    out.add("plant:")
    if source == "mjcf":
        geoms = [g if g is not None else "FILL_IN" for g in foot_geoms]
        comment = (
            "the model file's geoms at the foot frames"
            if None not in foot_geoms
            else ("FILL IN: the MJCF's foot geoms (none found at some foot frames)")
        )
        out.add(f"  foot_geoms: [{', '.join(geoms)}]", comment)
    out.add("  floor_friction: 0.6")
    out.add("  timestep: 0.001", "s, MuJoCo's step")
    out.add("", "  armature, joint_damping, joint_friction: null -> the model file's (a URDF has none: 0)")
    return radius


def _hip_box(model: pin.Model, legs: Legs) -> list[float]:
    """A trunk box spanning the legs' first joints (when the URDF has none)."""
    data = model.createData()
    pin.forwardKinematics(model, data, pin.neutral(model))
    hips = np.array([data.oMi[chain[0]].translation for chain in legs.chains])
    length, width = np.ptp(hips[:, 0]), np.ptp(hips[:, 1])
    return [float(length), float(width), float(0.25 * width)]


def _standing_comment(
    out: _Lines, model: pin.Model, legs: Legs, limits: tuple[np.ndarray, np.ndarray], foot_radius: float
) -> None:
    from cafe_mpc.robots.robot import default_foothold_offsets, leg_lengths, reference_standing_ratio

    canonical_feet = tuple(model.getFrameId(foot) for foot in legs.foot_frames)
    offsets = default_foothold_offsets(model, canonical_feet)
    height = foot_radius + reference_standing_ratio() * float(np.mean(leg_lengths(model, canonical_feet)))
    guess = knees_back_guess(model, *limits)
    out.add("", "standing: every key derived when unset (docs/robots.md); set one to override it:")
    out.add("", f"  height: {height:.3f}   (m: foot radius + 0.569 x leg length)")
    pairs = ", ".join(f"[{x:.3f}, {y:.3f}]" for x, y in offsets)
    out.add("", f"  foothold_offsets: [{pairs}]   (feet under the hips)")
    out.add("", f"  joint_guess: {_numbers(_per_kind(guess))}   (the pose's seed: knees behind the hips;")
    out.add("", "    give 12 values for a robot whose hind knees point forward, as Solo12's)")
