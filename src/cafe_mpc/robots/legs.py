"""Which leg is which: a quadruped's legs found in its planning model's kinematic tree and named by where
they are.

Everything in the package indexes legs in the order ``LEG_NAMES`` (``FL, FR, HL, HR``: contact flags,
feet, the 12 joints three by three). A model file orders its legs as its parser reads them (Pinocchio reads a
URDF's joints sorted by name, an MJCF's in file order), which a robot file's author cannot be expected to
know. So the legs are found from the model instead:

* **chains**: each child joint of the free-flyer starts one leg, a chain of ``JOINTS_PER_LEG`` one-joint
  links (hip abduction, hip, knee) ending at a foot;
* **feet**: the robot file's ``foot_frames`` (any order) belong to the chain whose last joint carries them;
  without ``foot_frames``, the frame on the last joint farthest from it is the foot (a body frame first);
* **names**: at the zero configuration, the two legs with the largest x (mean of the leg's joint origins
  and foot, base frame) are the front legs, the other two the hind legs; of each pair, the one with the
  larger y is the left leg.

The robot file can override the names: ``leg_names`` names the legs of ``foot_frames`` entry by entry (or,
without ``foot_frames``, the model's legs in the model's order), and ``joint_names`` gives the joints three
per leg in the order of ``leg_names`` (default ``LEG_NAMES``). A joint triple that is not one leg's chain, or
feet that are not on the named legs, is an error.

``canonical_model`` then rebuilds the model with its legs in ``LEG_NAMES`` order (a model already in that
order is returned as it is), so that joint ``k`` of leg ``i`` is configuration index ``7 + 3 i + k``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from cafe_mpc.core.contacts import LEG_NAMES

JOINTS_PER_LEG = 3  # abad, hip, knee
POSITION_MARGIN = 1e-3
"""m; the front legs must lie this much ahead of the hind legs, and a left leg this much left of its right
leg, for the names to follow from the positions."""


class LegError(ValueError):
    """The legs cannot be found in the model or do not match the robot file (with the reason)."""


@dataclass(frozen=True)
class Legs:
    """The model's legs in ``LEG_NAMES`` order.

    ``chains``: Pinocchio joint ids of each leg, trunk to foot; ``foot_frames``: each leg's foot frame;
    ``positions``: each leg's (x, y) in the base frame at the zero configuration (mean of its joint origins
    and foot); ``model_order``: the names of the model's legs in the model's order (what the model file's
    parser made of it); ``named_by``: ``"positions"``, or the robot file's key that named them.
    """

    chains: tuple[tuple[int, ...], ...]
    foot_frames: tuple[str, ...]
    positions: np.ndarray
    model_order: tuple[str, ...]
    named_by: str

    def joint_names(self, model: pin.Model) -> tuple[str, ...]:
        """The leg joints' names, ``LEG_NAMES`` order, trunk to foot in each leg (``model``: the model the
        legs were found in)."""
        return tuple(model.names[joint] for chain in self.chains for joint in chain)


def leg_chains(model: pin.Model) -> list[tuple[int, ...]]:
    """Each leg's joint ids (trunk to foot) in the model's order: the free-flyer's child joints, each followed
    down its single line of children."""
    if model.njoints < 2 or model.joints[1].shortname() != "JointModelFreeFlyer":
        raise LegError("the model's first joint is not a free-flyer (the trunk)")
    children: dict[int, list[int]] = {joint: [] for joint in range(model.njoints)}
    for joint in range(2, model.njoints):
        children[model.parents[joint]].append(joint)
    chains = []
    for root in children[1]:
        chain = [root]
        while children[chain[-1]]:
            below = children[chain[-1]]
            if len(below) != 1:
                names = ", ".join(model.names[j] for j in below)
                raise LegError(f"joint {model.names[chain[-1]]!r} has {len(below)} child joints ({names})")
            chain.append(below[0])
        chains.append(tuple(chain))
    if len(chains) != len(LEG_NAMES) or any(len(chain) != JOINTS_PER_LEG for chain in chains):
        shape = ", ".join(f"{model.names[chain[0]]}: {len(chain)}" for chain in chains)
        raise LegError(
            f"expected {len(LEG_NAMES)} legs of {JOINTS_PER_LEG} joints on the trunk, found {len(chains)} "
            f"({shape})"
        )
    for chain in chains:
        for joint in chain:
            if model.nqs[joint] != 1 or model.nvs[joint] != 1:
                raise LegError(f"joint {model.names[joint]!r} is not a one-degree-of-freedom joint")
    return chains


_FRAME_PREFERENCE = {pin.FrameType.BODY: 0, pin.FrameType.OP_FRAME: 1, pin.FrameType.FIXED_JOINT: 2}


def foot_frame_of(model: pin.Model, chain: tuple[int, ...]) -> str:
    """The foot frame of a leg: of the frames on its last joint (bodies, fixed joints, operational frames),
    the farthest from the joint; a body frame before the fixed joint at the same place."""
    knee = chain[-1]
    candidates = []
    for frame in model.frames:
        if frame.parentJoint != knee or frame.type not in _FRAME_PREFERENCE:
            continue
        distance = float(np.linalg.norm(frame.placement.translation))
        candidates.append((-round(distance, 9), _FRAME_PREFERENCE[frame.type], frame.name))
    candidates.sort()
    if not candidates or candidates[0][0] == 0.0:
        raise LegError(
            f"no frame away from joint {model.names[knee]!r} (the leg's last joint): give foot_frames"
        )
    return candidates[0][2]


def leg_positions(model: pin.Model, chains: list[tuple[int, ...]], feet: list[str]) -> np.ndarray:
    """Each leg's (x, y) in the base frame at the zero configuration: the mean of its joint origins and its
    foot."""
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    positions = []
    for chain, foot in zip(chains, feet, strict=True):
        points = [data.oMi[joint].translation for joint in chain]
        points.append(data.oMf[model.getFrameId(foot)].translation)
        positions.append(np.mean(points, axis=0)[:2])
    return np.array(positions)


def names_from_positions(positions: np.ndarray) -> tuple[str, ...]:
    """``LEG_NAMES`` names of legs at ``positions`` (n x 2: x forward, y left): the two foremost are the front
    legs, the left one of each pair has the larger y. ``LegError`` when the legs are not clearly apart."""
    order = np.argsort(-positions[:, 0], kind="stable")
    front, hind = order[:2], order[2:]
    gap = float(np.min(positions[front, 0]) - np.max(positions[hind, 0]))
    if gap < POSITION_MARGIN:
        raise LegError(
            f"the legs are not two ahead and two behind (x {np.round(positions[:, 0], 4).tolist()} m): "
            "give leg_names"
        )
    names = [""] * len(positions)
    for pair, (left, right) in ((front, ("FL", "FR")), (hind, ("HL", "HR"))):
        first, second = pair
        if abs(positions[first, 1] - positions[second, 1]) < POSITION_MARGIN:
            raise LegError(
                f"two legs at the same side offset (y {np.round(positions[pair, 1], 4).tolist()} m): "
                "give leg_names"
            )
        is_left = positions[first, 1] > positions[second, 1]
        names[first], names[second] = (left, right) if is_left else (right, left)
    return tuple(names)


def _check_names(names: tuple[str, ...], key: str) -> None:
    if sorted(names) != sorted(LEG_NAMES):
        raise LegError(f"{key} must be a permutation of {', '.join(LEG_NAMES)}, got {list(names)}")


def find_legs(
    model: pin.Model,
    foot_frames: tuple[str, ...] | None = None,
    leg_names: tuple[str, ...] | None = None,
    joint_names: tuple[str, ...] | None = None,
) -> Legs:
    """The model's legs in ``LEG_NAMES`` order, found and named as the module docstring says; the robot
    file's ``foot_frames``, ``leg_names`` and ``joint_names`` (each optional) are checked against the tree."""
    chains = leg_chains(model)
    chain_of_joint = {joint: index for index, chain in enumerate(chains) for joint in chain}
    if foot_frames is not None:
        if len(foot_frames) != len(chains):
            raise LegError(f"foot_frames needs {len(chains)} frames, got {list(foot_frames)}")
        feet_by_chain: dict[int, str] = {}
        for frame in foot_frames:
            if not model.existFrame(frame):
                raise LegError(f"foot frame {frame!r} is not in the model")
            chain = chain_of_joint.get(model.frames[model.getFrameId(frame)].parentJoint)
            if chain is None or model.frames[model.getFrameId(frame)].parentJoint != chains[chain][-1]:
                raise LegError(f"foot frame {frame!r} is not on a leg's last joint")
            if chain in feet_by_chain:
                raise LegError(f"foot frames {feet_by_chain[chain]!r} and {frame!r} are on the same leg")
            feet_by_chain[chain] = frame
        feet = [feet_by_chain[index] for index in range(len(chains))]
    else:
        feet = [foot_frame_of(model, chain) for chain in chains]
    positions = leg_positions(model, chains, feet)
    named_by = "positions"
    if leg_names is not None:
        leg_names = tuple(leg_names)
        _check_names(leg_names, "leg_names")
        named_by = "leg_names"
        if foot_frames is not None:  # leg_names[i] names the leg of foot_frames[i]
            by_frame = dict(zip(foot_frames, leg_names, strict=True))
            names = tuple(by_frame[foot] for foot in feet)
        else:  # the model's legs in the model's order
            names = leg_names
    else:
        names = names_from_positions(positions)
    if joint_names is not None:
        names = _names_from_joints(model, chains, chain_of_joint, tuple(joint_names), leg_names, names)
        named_by = "joint_names" if leg_names is None else named_by
    order = [names.index(leg) for leg in LEG_NAMES]
    return Legs(
        chains=tuple(chains[i] for i in order),
        foot_frames=tuple(feet[i] for i in order),
        positions=positions[order],
        model_order=names,
        named_by=named_by,
    )


def _names_from_joints(
    model: pin.Model,
    chains: list[tuple[int, ...]],
    chain_of_joint: dict[int, int],
    joint_names: tuple[str, ...],
    leg_names: tuple[str, ...] | None,
    names: tuple[str, ...],
) -> tuple[str, ...]:
    """The legs' names (model order) that ``joint_names`` gives (three per leg, in the order of
    ``leg_names``, default ``LEG_NAMES``); they must agree with ``leg_names`` when both name the legs."""
    if len(joint_names) != JOINTS_PER_LEG * len(chains):
        raise LegError(f"joint_names needs {JOINTS_PER_LEG * len(chains)} joints, got {len(joint_names)}")
    given_order = leg_names if leg_names is not None else LEG_NAMES
    from_joints = [""] * len(chains)
    for leg_index, leg in enumerate(given_order):
        triple = joint_names[JOINTS_PER_LEG * leg_index : JOINTS_PER_LEG * (leg_index + 1)]
        for name in triple:
            if not model.existJointName(name):
                raise LegError(f"joint {name!r} (joint_names) is not in the model")
        ids = tuple(model.getJointId(name) for name in triple)
        chain = chain_of_joint.get(ids[0])
        if chain is None or chains[chain] != ids:
            raise LegError(
                f"joint_names: {', '.join(triple)} (leg {leg}) are not one leg's joints from trunk to foot"
            )
        from_joints[chain] = leg
    if leg_names is not None and tuple(from_joints) != names:
        raise LegError(
            f"joint_names and leg_names/foot_frames name the legs differently ({from_joints} against "
            f"{list(names)}, model order)"
        )
    return tuple(from_joints)


def is_canonical(model: pin.Model, legs: Legs) -> bool:
    """Whether the model's joints already come leg by leg in ``LEG_NAMES`` order."""
    flat = [joint for chain in legs.chains for joint in chain]
    return flat == list(range(2, 2 + len(flat)))


_Q_VECTORS = ("lowerPositionLimit", "upperPositionLimit", "positionLimitMargin")
_V_VECTORS = (
    "effortLimit",
    "lowerEffortLimit",
    "upperEffortLimit",
    "velocityLimit",
    "lowerVelocityLimit",
    "upperVelocityLimit",
    "armature",
    "damping",
    "friction",
    "lowerDryFrictionLimit",
    "upperDryFrictionLimit",
    "rotorInertia",
    "rotorGearRatio",
)


def canonical_model(model: pin.Model, legs: Legs) -> pin.Model:
    """``model`` with its legs in ``LEG_NAMES`` order (the same model when they already are).

    The tree is rebuilt joint by joint (trunk first, then each leg trunk to foot): joint models, placements,
    names and body inertias, then every frame on its new parent joint, then the per-degree-of-freedom vectors
    (limits, armature, damping, friction, rotor data) permuted with the joints."""
    if is_canonical(model, legs):
        return model
    new_model = pin.Model()
    new_model.name = model.name
    new_model.gravity = model.gravity
    new_id = {0: 0}
    for old in (1, *(joint for chain in legs.chains for joint in chain)):
        new_id[old] = new_model.addJoint(
            new_id[model.parents[old]], model.joints[old], model.jointPlacements[old], model.names[old]
        )
        new_model.appendBodyToJoint(new_id[old], model.inertias[old], pin.SE3.Identity())
    frame_id = {}
    for old_index, frame in enumerate(model.frames):
        if old_index == 0:  # the universe frame, which every model has
            frame_id[0] = 0
            continue
        copy = pin.Frame(
            frame.name,
            new_id[frame.parentJoint],
            frame_id.get(frame.parentFrame, 0),
            frame.placement,
            frame.type,
            frame.inertia,
        )
        frame_id[old_index] = new_model.addFrame(copy, False)
    q_index, v_index = [], []
    for old in (1, *(joint for chain in legs.chains for joint in chain)):
        q_index += range(model.idx_qs[old], model.idx_qs[old] + model.nqs[old])
        v_index += range(model.idx_vs[old], model.idx_vs[old] + model.nvs[old])
    for names, index in ((_Q_VECTORS, q_index), (_V_VECTORS, v_index)):
        for name in names:
            if hasattr(model, name):
                setattr(new_model, name, np.asarray(getattr(model, name))[index].copy())
    for entry in list(model.referenceConfigurations):  # (name, configuration) pairs
        name, configuration = entry.key(), np.asarray(entry.data())
        new_model.referenceConfigurations[name] = configuration[q_index].copy()
    return new_model


HIP_GUESS = 0.8
"""rad; the hip angle of the default standing-pose seed (the knee bends twice as far back)."""


def knees_back_guess(model: pin.Model, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """A seed for the standing pose of a model with its legs in ``LEG_NAMES`` order: per leg abduction 0, the
    hip turned ``HIP_GUESS`` and the knee twice as far the other way (relative to the hip's axis), the sign
    chosen so that the knee lies behind the hip (the usual quadruped stance) unless only the other sign fits
    the joint limits ``lower``/``upper``; clipped to the limits."""
    data = model.createData()
    guess = np.zeros(model.nv - 6)
    neutral = pin.neutral(model)
    pin.computeJointJacobians(model, data, neutral)
    for leg in range(len(LEG_NAMES)):
        first = JOINTS_PER_LEG * leg
        hip, knee = 3 + first, 4 + first  # joint ids: universe 0, free-flyer 1, then the legs
        hip_axis = pin.getJointJacobian(model, data, hip, pin.WORLD)[3:, 6 + first + 1]
        knee_axis = pin.getJointJacobian(model, data, knee, pin.WORLD)[3:, 6 + first + 2]
        knee_sign = -1.0 if float(hip_axis @ knee_axis) > 0 else 1.0
        candidates = []
        for sign in (1.0, -1.0):
            angles = np.array([0.0, sign * HIP_GUESS, knee_sign * sign * 2.0 * HIP_GUESS])
            q = neutral.copy()
            q[7 + first : 10 + first] = angles
            pin.forwardKinematics(model, data, q)
            knee_behind = data.oMi[knee].translation[0] < data.oMi[hip].translation[0]
            inside = bool(
                np.all(angles >= lower[first : first + 3]) and np.all(angles <= upper[first : first + 3])
            )
            candidates.append((not inside, not knee_behind, angles))
        candidates.sort(key=lambda entry: (entry[0], entry[1]))
        guess[first : first + 3] = np.clip(
            candidates[0][2], lower[first : first + 3], upper[first : first + 3]
        )
    return guess
