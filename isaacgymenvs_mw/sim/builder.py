"""Robot description (URDF or MJCF) + task settings -> one compiled ``mujoco.MjModel``.

MuJoCo compiles URDF directly, but a URDF cannot say which joints are driven and how, where the floor
is, or which solver to use. We load the file into an ``MjSpec`` and add those from the task YAML.

An MJCF may already say some of it. Its own actuators (gear, ctrlrange, forcerange), joint limits, armature and
contact settings are kept as written: the model's actuators are the asset's, in file order, followed by one per
joint that the YAML drives; a YAML drive on a joint the asset already actuates rewrites that actuator in place
(``position`` with the YAML gains, or ``effort``), so that a joint never has two actuators. An MJCF root body with a free joint is the floating
base; its ``pos``/``quat`` is the start pose unless the task gives one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import mujoco
import numpy as np

from isaacgymenvs_mw.sim.asset_parse import compile_error, parse_asset
from isaacgymenvs_mw.sim.cameras import CameraSpec
from isaacgymenvs_mw.sim.geom_contacts import GeomContact, add_average_friction_pairs, set_geom_contacts
from isaacgymenvs_mw.sim.names import compile_pattern, name_matches, no_match_error
from isaacgymenvs_mw.sim.scene import SCENE_TEXT_PREFIX
from isaacgymenvs_mw.sim.sensors import ContactForces, Sensor
from isaacgymenvs_mw.sim.stability import warn_unstable_drives
from isaacgymenvs_mw.sim.terrain import GROUND_PART_PREFIX, Terrain
from isaacgymenvs_mw.utils.config import real_number
from isaacgymenvs_mw.utils.errors import ConfigError, MissingFileError

DRIVE_MODES = ("none", "effort", "position")

_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}
_SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}
_CONES = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}

# Collision bits: robot geoms touch only the ground unless self-collisions are asked for.
_GROUND_BIT = 1
_ROBOT_BIT = 2


@dataclass
class JointDrive:
    """How one joint is actuated: 'effort' (torque/force command), 'position' (PD target) or 'none'."""

    mode: str = "none"
    stiffness: float = 0.0
    damping: float = 0.0
    torque_limit: float | None = None  # |force| <= this (a DC motor's continuous limit); None: the joint's own


@dataclass
class GroundPlane:
    friction: float = 1.0


@dataclass
class SolverOptions:
    """The task YAML ``sim`` section, in MuJoCo terms."""

    dt: float = 0.005
    gravity: Sequence[float] = (0.0, 0.0, -9.81)
    integrator: str = "implicitfast"
    solver: str = "newton"
    cone: str = "pyramidal"
    iterations: int = 10
    ls_iterations: int = 20
    ccd_iterations: int | None = None  # None: MuJoCo's default (35); GJK and EPA iterations of convex collisions
    ccd_tolerance: float | None = None  # None: MuJoCo's default (1e-6)
    impratio: float = 1.0
    enable_contacts: bool = True


@dataclass
class SceneAsset:
    """One asset of a scene beside the main one (``env.assets.<name>``): attached to the main model with every
    body, joint, geom, site, actuator and sensor name prefixed by ``prefix``.

    Its own actuators and sensors come along (after the main asset's actuators); YAML drives are the main asset's
    only. A free asset (``fix_base`` False) gets a free joint named ``<prefix>root`` unless its root body has one.
    """

    name: str
    asset_file: Path
    prefix: str
    fix_base: bool = False
    # The root body's pose in the world (w, x, y, z); None keeps the file's (as env.baseInitState for the main one).
    pos: Sequence[float] | None = None
    quat: Sequence[float] | None = None
    # True: the asset's own contype/conaffinity stay; False: its geoms collide as the ground does (with the main
    # asset, the ground and the other objects).
    keep_asset_contacts: bool = False
    spec: "mujoco.MjSpec | None" = None  # the parsed file (sim/request.py parses it once); None: parse asset_file
    max_angular_velocity: float | None = None  # rad/s cap on its free body's angular speed (sim/velocity_limit.py)


@dataclass
class ModelRequest:
    """Everything needed to build the task's model."""

    asset_file: Path
    fix_base: bool = True
    collapse_fixed_joints: bool = True
    self_collisions: bool = False
    drives: Mapping[str, JointDrive] = field(default_factory=dict)
    armature: Mapping[str, float] = field(default_factory=dict)
    joint_damping: Mapping[str, float] = field(default_factory=dict)
    ground: GroundPlane | None = None
    # Root pose: where a floating base starts or a fixed one is welded; None keeps the root body's own pos / quat
    # (MuJoCo order w, x, y, z).
    base_init_pos: Sequence[float] | None = None
    base_init_quat: Sequence[float] | None = None
    contact_bodies: Sequence[str] = ()
    options: SolverOptions = field(default_factory=SolverOptions)
    # {joint: N or N m}: cap on the total actuator force at the joint (MuJoCo actuatorfrcrange = ±value).
    effort_limits: Mapping[str, float] = field(default_factory=dict)
    # {actuator or joint name / regex: value}, applied to every actuator it selects (the asset's and added ones).
    gear: Mapping[str, float] = field(default_factory=dict)
    ctrl_range: Mapping[str, Sequence[float]] = field(default_factory=dict)
    # True: the asset's contype/conaffinity/condim/friction stay as written and the ground collides with every
    # geom that collides with anything (MJCF); False: robot geoms touch only the ground (+ selfCollisions) (URDF).
    keep_asset_contacts: bool = False
    # A generated height map (sim/terrain.py): the ground becomes a heightfield geom of it instead of a plane.
    terrain: "Terrain | None" = None
    # The parsed asset_file (sim/request.py parses it once); None: build_model parses asset_file.
    spec: "mujoco.MjSpec | None" = None
    # Further assets of the scene (env.assets), attached in this order under their prefixes.
    assets: Sequence[SceneAsset] = ()
    # {geom name regex: GeomContact}: contact properties of the selected geoms of the whole scene (env.contact).
    geom_contacts: Mapping[str, "GeomContact"] = field(default_factory=dict)
    # (geom regex, geom regex) pairs whose contacts average the two frictions as PhysX does (env.averageFriction).
    average_friction: Sequence[tuple[str, str]] = ()
    # Cameras (env.cameras, sim/cameras.py): sensors refreshed by the render, added on their bodies once the scene
    # is composed (all_sensors).
    cameras: Sequence[CameraSpec] = ()
    # Sensors the task YAML declares (env.sensors) and the task adds (sim/sensors.py), added once the scene is
    # composed; the contact forces of contact_bodies come after them (all_sensors). Unbound declarations: the
    # Simulator binds them into its registry, ``sim.sensors``, the one thing that name means.
    declared_sensors: Sequence[Sensor] = ()
    # Step one world in MuJoCo C at build time to see whether the drives diverge (sim.stabilityProbe, sim/stability.py).
    stability_probe: bool = True
    # {joint: (saturation torque, torque limit, no-load speed)}: the DC-motor limit of the joint's drive
    # (env.control.torqueSpeed, sim/actuators.py), applied by the Simulator built with it (``Simulator(torque_speed=)``).
    torque_speed: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    # rad/s cap on the angular speed of the main asset's free bodies (env.asset.maxAngularVelocity; None: none)
    max_angular_velocity: float | None = None

    def angular_speed_caps(self) -> dict[str, float]:
        """{asset name prefix ('' for the main asset): rad/s} of the assets that cap their free bodies' angular
        speed (``sim.velocity_limit.free_joint_speed_limits`` finds their joints in the compiled model)."""
        caps = {"": self.max_angular_velocity} if self.max_angular_velocity is not None else {}
        caps.update({a.prefix: a.max_angular_velocity for a in self.assets if a.max_angular_velocity is not None})
        return caps

    def body_names(self) -> list[str]:
        """Body names of the main asset as parsed (world body first), before fixed joints are collapsed."""
        spec = self.spec if self.spec is not None else load_spec(self.asset_file, self.collapse_fixed_joints)
        return [b.name for b in spec.bodies]

    @property
    def sensors(self) -> tuple[Sensor, ...]:
        """``declared_sensors`` by its earlier name, which an earlier contributor guide taught
        (``request.sensors = (*request.sensors, BaseSpeed())``); kept so those tasks run unchanged."""
        return tuple(self.declared_sensors)

    @sensors.setter
    def sensors(self, value: Sequence[Sensor]) -> None:
        self.declared_sensors = value

    def all_sensors(self) -> tuple[Sensor, ...]:
        """The sensors the model is built with: the ``cameras``, then, in column order, ``declared_sensors`` and the
        contact forces of ``contact_bodies``. ``Simulator(declared_sensors=...)`` binds them."""
        return (*self.cameras, *self.declared_sensors,
                *((ContactForces(self.contact_bodies),) if self.contact_bodies else ()))


def load_spec(asset_file: Path, collapse_fixed_joints: bool = True, key: str = "env.asset") -> mujoco.MjSpec:
    """Parse a URDF or MJCF file; fail with the path when it does not exist (``key``: the YAML section naming it)."""
    asset_file = Path(asset_file)
    if not asset_file.is_file():
        raise MissingFileError(
            f"Asset file not found: '{asset_file}'. Set {key}.assetRoot / {key}.assetFileName in the task "
            "YAML to an existing URDF or MJCF file."
        )
    spec = parse_asset(asset_file, key)  # a file MuJoCo refuses is one line; URDF joints with lower == upper locked
    spec.compiler.fusestatic = bool(collapse_fixed_joints)
    return spec


def movable_joint_names(spec: mujoco.MjSpec) -> list[str]:
    """Names of the hinge and slide joints, in the order MuJoCo will lay them out in qpos."""
    return [j.name for j in spec.joints if j.type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)]


def is_mjcf(asset_file: Path) -> bool:
    """MJCF by extension (``.xml``); everything else (``.urdf``) is compiled as URDF by MuJoCo."""
    return Path(asset_file).suffix.lower() == ".xml"


def actuated_joints(spec: mujoco.MjSpec) -> dict[str, str]:
    """{joint: actuator} for the joints that the asset's own actuators drive (joint transmissions)."""
    out: dict[str, str] = {}
    for act in spec.actuators:
        if act.trntype == mujoco.mjtTrn.mjTRN_JOINT and act.target:
            out.setdefault(act.target, act.name)
    return out


def match_body_names(patterns: Sequence[str] | str | None, body_names: Sequence[str], key: str) -> list[str]:
    """Bodies that any of the patterns selects (``name_matches``: a full match), in model order; a pattern that
    selects no body is an error naming ``key``."""
    if isinstance(patterns, str):
        patterns = [patterns]
    out: list[str] = []
    for pattern in patterns or []:
        out += [body_names[i] for i in name_matches(pattern, body_names, key, "bodies") if body_names[i] not in out]
    return out


def match_joint_values(
    patterns: Mapping[str, object] | None, joint_names: Sequence[str], key: str, default: object | None = None
) -> dict[str, object]:
    """Resolve a {pattern: value} YAML mapping to {joint: value}.

    A pattern selects every joint whose whole name it matches (``name_matches``: ``".*_HAA"`` -> all *_HAA joints).
    A key that is a joint's own name wins over the other patterns; among patterns the first in YAML order wins. A
    pattern that selects no joint is an error naming the key, and so is a value that is not a mapping.
    """
    patterns = joint_table(patterns, key)
    selected = {pattern: set(name_matches(pattern, joint_names, key, "joints")) for pattern in patterns}
    resolved: dict[str, object] = {}
    for i, name in enumerate(joint_names):
        if name in patterns:
            resolved[name] = patterns[name]
            continue
        for pattern, value in patterns.items():
            if i in selected[pattern]:
                resolved[name] = value
                break
        else:
            if default is not None:
                resolved[name] = default
    return resolved


def joint_table(patterns: object, key: str, one_for_all: bool = False) -> dict[str, object]:
    """A per-joint YAML value as a {pattern: value} dict: a mapping as given, nothing as {}, and with
    ``one_for_all`` a plain number as every joint's value; anything else (text, a list) is an error naming ``key``."""
    if patterns is None:
        return {}
    if hasattr(patterns, "items"):
        return dict(patterns)
    number = isinstance(patterns, (int, float)) and not isinstance(patterns, bool)
    if one_for_all and number:
        return {".*": patterns}
    also = ", e.g. {'.*': 20.0}, or one number for every joint" if one_for_all else ""
    raise ConfigError(f"{key}={patterns!r} is invalid: give a mapping {{joint or regex: value}}{also}")


def match_joint_numbers(patterns: Mapping[str, object] | float | None, joint_names: Sequence[str], key: str,
                        default: float | None = None, low: float | None = None) -> dict[str, float]:
    """``match_joint_values`` for a per-joint number (gains, armature, limits, angles): each value must be a
    number (>= ``low`` when given); a bad one is an error naming ``key``, the pattern and the value. A plain number
    stands for every joint (``stiffness: 20`` is ``{'.*': 20}``): the command line's
    ``task.env.control.stiffness=20`` replaces the YAML's mapping, and means that."""
    table = joint_table(patterns, key, one_for_all=True)
    single = not hasattr(patterns, "items")  # a plain number: its key is the whole key, as the user typed it
    for pattern, value in table.items():
        real_number(value, key if single else f"{key}[{pattern!r}]", low=low)
    return {name: float(value) for name, value in match_joint_values(table, joint_names, key, default).items()}


def build_model(request: ModelRequest) -> mujoco.MjModel:
    """Compile the task's model: asset + base + ground + actuators + scene assets + cameras + declared sensors +
    contact sensors + solver options."""
    # A copy: building edits the spec, and the request's parsed spec must stay as the file says for a second build.
    spec = request.spec.copy() if request.spec is not None else load_spec(request.asset_file,
                                                                          request.collapse_fixed_joints)
    joints = movable_joint_names(spec)
    # A floating base starts at the pose (its qpos0); a fixed one is welded there (IsaacGymEnvs' hand pose).
    _place_root(spec, request.asset_file, request.fix_base, request.base_init_pos, request.base_init_quat,
                "env.asset")

    collide_bits = _set_collision_filter(spec, request.self_collisions, request.keep_asset_contacts)
    ground = []
    if request.ground is not None:
        parts = _terrain_parts(spec, request.terrain) if request.terrain is not None else [("ground", dict(
            type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 0.05]))]  # zero half-sizes: an infinite plane
        for name, shape in parts:
            ground.append(spec.worldbody.add_geom(
                name=name,
                **shape,
                friction=[request.ground.friction, 0.005, 0.0001],
                contype=collide_bits[0],
                conaffinity=collide_bits[1],
                # Framework filter: the ground's friction and condim decide the contact. Asset contacts kept:
                # equal priority, so MuJoCo's mixing (the larger friction, the larger condim) lets the asset's
                # settings count.
                condim=1 if request.keep_asset_contacts else 3,
                priority=0 if request.keep_asset_contacts else 1,
            ))

    for name, value in request.armature.items():
        spec.joint(name).armature = float(value)
    for name, value in request.joint_damping.items():
        spec.joint(name).damping = [float(value)] + list(spec.joint(name).damping)[1:]
    for name, value in request.effort_limits.items():
        _check_joint(spec, name, "env.control.effortLimit")
        joint = spec.joint(name)
        joint.actfrcrange = [-float(value), float(value)]
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE

    owned = actuated_joints(spec)
    for name in request.drives:
        _check_joint(spec, name, "env.control.driveMode")
    # A YAML drive on a joint the asset's own actuator drives rewrites that actuator in place (its name, ctrl column
    # and force range stay): one actuator per joint, so ctrl[:, i] never silently reaches only one of two.
    for name, drive in request.drives.items():
        if name in owned:
            _rewrite_actuator(spec.actuator(owned[name]), spec.joint(name), drive)
    for name in joints:
        if name not in owned:
            _add_actuator(spec, name, request.drives.get(name, JointDrive()))
    _override_actuators(spec, request.gear, "env.control.gear", _set_gear)
    _override_actuators(spec, request.ctrl_range, "env.control.ctrlRange", _set_ctrl_range)

    # After the main asset's actuators, so that its ctrl columns come first and the YAML's gear / ctrlRange
    # patterns reach only them; the scene assets' own actuators follow, in env.assets order.
    for asset in request.assets:
        _attach(spec, asset)
    if request.assets and request.keep_asset_contacts:
        contype, conaffinity = _set_collision_filter(spec, False, True)  # now the objects' geoms count too
        for geom in ground:
            geom.contype, geom.conaffinity = contype, conaffinity
    set_geom_contacts(spec, request.geom_contacts)
    add_average_friction_pairs(spec, request.average_friction)
    for body_name in request.contact_bodies:
        if spec.body(body_name) is None:
            raise ConfigError(f"contact body '{body_name}' is not a body of {request.asset_file}")
    for sensor in request.all_sensors():
        sensor.add_to(spec)

    _apply_options(spec, request.options)
    try:
        model = spec.compile()
    except ValueError as err:  # one line naming the asset: a repeated name, a root with joints, a mesh, ...
        raise compile_error(err, request.asset_file) from err
    # Here, where the timestep, the inertias and the constraints are final: a drive too stiff for them (alone, or
    # coupled to others through a closed chain) blows up every world.
    warn_unstable_drives(model, {j for j, d in request.drives.items() if d.mode == "position"},
                         probe=request.stability_probe)
    return model


def _terrain_parts(spec: mujoco.MjSpec, terrain: Terrain) -> list[tuple[str, dict]]:
    """The ground of a generated height map as (geom name, shape arguments): one heightfield per cell, each holding
    its cell's samples plus the first row and column after it (and on the grid's low edges the border's last sample
    before it), so the surface between samples is the one a single heightfield would have; and four flat boxes with
    their tops at z = 0 for the border.

    One heightfield per cell, not one for the map: MuJoCo Warp 4.0's heightfield collision loses precision with
    the distance from the heightfield's centre. On a 130 m x 210 m map, 5-10 % of foot spheres more than 20 m from
    it got a contact metres deep at a wrong place, which blew the world up.
    Within a cell, no point is more than ~6 m from its heightfield's centre. MuJoCo stores heights normalised to
    [0, 1] times the elevation range, above the geom's z; rows run along y, columns along x.
    """
    cfg, h, hs = terrain.config, terrain.heights, terrain.spacing
    px, py, b, _ = cfg.sample_counts()
    edge = 1 if b > 0 else 0  # cells on the grid's low edges also take the border's last sample before them
    parts = []
    for i in range(cfg.numLevels):
        for j in range(cfg.numTerrains):
            a0, b0 = b + i * px - (edge if i == 0 else 0), b + j * py - (edge if j == 0 else 0)
            tile = h[a0:b + (i + 1) * px + 1, b0:b + (j + 1) * py + 1]
            low, span = float(tile.min()), max(float(np.ptp(tile)), 1e-3)  # flat tiles need a positive range
            nx, ny = tile.shape
            rx, ry = 0.5 * (nx - 1) * hs, 0.5 * (ny - 1) * hs
            name = f"{GROUND_PART_PREFIX}cell_{i}_{j}"
            field = spec.add_hfield(name=name, nrow=ny, ncol=nx, size=[rx, ry, span, 1.0])  # 1 m thick base
            field.userdata = ((tile - low) / span).T.astype(np.float32).ravel().tolist()
            parts.append((name, dict(type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=name,
                                     pos=[terrain.x0 + a0 * hs + rx, terrain.y0 + b0 * hs + ry, low])))
    if b > 0:
        # Border strips, flat at 0 where the heightfields end: x below and above the grid over the full width,
        # then y below and above along the grid.
        x_lo, y_lo = terrain.x0, terrain.y0
        x_hi, y_hi = terrain.x0 + (h.shape[0] - 1) * hs, terrain.y0 + (h.shape[1] - 1) * hs
        gx, gy = cfg.numLevels * px * hs, cfg.numTerrains * py * hs  # the grid spans [0, gx] x [0, gy]
        for k, (x0, x1, y0, y1) in enumerate([(x_lo, -hs, y_lo, y_hi), (gx, x_hi, y_lo, y_hi),
                                              (-hs, gx, y_lo, -hs), (-hs, gx, gy, y_hi)]):
            if x1 - x0 > 1e-9 and y1 - y0 > 1e-9:
                # 0.1 mm wider on every side: no seam for a ray or a contact where a box meets a heightfield or
                # where the map ends (both are at height 0 there).
                parts.append((f"{GROUND_PART_PREFIX}border_{k}", dict(
                    type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.5 * (x1 - x0) + 1e-4, 0.5 * (y1 - y0) + 1e-4, 0.5],
                    pos=[0.5 * (x0 + x1), 0.5 * (y0 + y1), -0.5])))
    return parts


def _check_joint(spec: mujoco.MjSpec, name: str, key: str) -> None:
    if spec.joint(name) is None:
        raise ConfigError(f"{key}: '{name}' is not a joint of the asset; joints: {movable_joint_names(spec)}")


def _check_joint_types(spec: mujoco.MjSpec, asset_file: Path, root: mujoco.MjsBody) -> bool:
    """Only hinge/slide joints, plus at most a free joint on the root body (the floating base); True if it has one."""
    free_root = False
    for j in spec.joints:
        if j.type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            continue
        if j.type == mujoco.mjtJoint.mjJNT_FREE and j.parent.name == root.name and not free_root:
            free_root = True
            continue
        raise ConfigError(
            f"{asset_file}: joint '{j.name}' is a {j.type.name}; only revolute/continuous/prismatic (hinge/slide) "
            "joints are supported, plus one free joint on the root body (the floating base; without it the "
            "framework adds one when env.asset.fixBaseLink is False)"
        )
    if free_root and next(iter(root.joints)).type != mujoco.mjtJoint.mjJNT_FREE:
        raise ConfigError(f"{asset_file}: the free joint of root body '{root.name}' must be its first joint")
    return free_root


def _place_root(spec: mujoco.MjSpec, asset_file: Path, fix_base: bool, pos: Sequence[float] | None,
                quat: Sequence[float] | None, key: str) -> mujoco.MjsBody:
    """Fixed or free root body (a free joint added where the asset has none) at ``pos`` / ``quat`` where given."""
    root = _root_body(spec)
    has_free_root = _check_joint_types(spec, asset_file, root)
    if has_free_root and fix_base:
        raise ConfigError(
            f"{asset_file}: the root body '{root.name}' has a free joint (a floating base) but "
            f"{key}.fixBaseLink is True; set fixBaseLink: False, or remove the free joint to weld it to the world"
        )
    if not fix_base and not has_free_root:
        root.add_freejoint(name="root")
    if pos is not None:
        root.pos = list(pos)
    if quat is not None:
        root.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT  # replaces an euler/axisangle in the file
        root.quat = list(quat)
    return root


def _attach(spec: mujoco.MjSpec, asset: SceneAsset) -> None:
    """Attach one scene asset's root body (and the actuators, sensors and assets that refer to its subtree) under
    the world body, every name prefixed; record its name and prefix in the model."""
    key = f"env.assets.{asset.name}"
    # Fixed joints are collapsed (or not) as the main asset says: fusestatic is one compiler flag for the model.
    child = asset.spec.copy() if asset.spec is not None else load_spec(asset.asset_file, spec.compiler.fusestatic,
                                                                       key)
    root = _place_root(child, asset.asset_file, asset.fix_base, asset.pos, asset.quat, key)
    if not asset.keep_asset_contacts:
        # Like the ground (bit 1 both ways): the main asset's geoms (conaffinity holds bit 1), the ground and the
        # other objects all meet it.
        for geom in child.geoms:
            geom.contype = _GROUND_BIT
            geom.conaffinity = _GROUND_BIT | _ROBOT_BIT
    spec.worldbody.add_frame().attach_body(root, asset.prefix, "")
    spec.add_text(name=f"{SCENE_TEXT_PREFIX}{asset.name}", data=asset.prefix)


def _root_body(spec: mujoco.MjSpec) -> mujoco.MjsBody:
    children = [b for b in spec.bodies if b.parent is not None and b.parent.name == spec.worldbody.name]
    children = [b for b in children if b.name != spec.worldbody.name]
    if len(children) != 1:
        raise ConfigError(f"expected one root link under the world, found {[b.name for b in children]}")
    return children[0]


def _set_collision_filter(spec: mujoco.MjSpec, self_collisions: bool, keep: bool) -> tuple[int, int]:
    """Set the robot's collision bits; returns the ground's (contype, conaffinity)."""
    if keep:
        # Collide with every geom that collides with anything: MuJoCo pairs geoms when
        # (contype1 & conaffinity2) | (contype2 & conaffinity1) is non-zero.
        contype = conaffinity = 0
        for geom in spec.geoms:
            contype |= int(geom.conaffinity)
            conaffinity |= int(geom.contype)
        return contype or _GROUND_BIT, conaffinity or _GROUND_BIT
    for geom in spec.geoms:
        geom.contype = _ROBOT_BIT if self_collisions else 0
        geom.conaffinity = _GROUND_BIT | (_ROBOT_BIT if self_collisions else 0)
    return _GROUND_BIT, _ROBOT_BIT | _GROUND_BIT


def _add_actuator(spec: mujoco.MjSpec, joint_name: str, drive: JointDrive) -> None:
    if drive.mode not in DRIVE_MODES:
        raise ConfigError(f"drive mode '{drive.mode}' of joint '{joint_name}' is not one of {DRIVE_MODES}")
    if drive.mode == "none":
        return
    joint = spec.joint(joint_name)
    if drive.mode == "effort" and drive.torque_limit is None and not _force_capped(joint):
        raise ConfigError(
            f"env.control.driveMode: joint '{joint_name}' has an effort drive but no torque cap: the asset gives "
            "none (URDF <limit effort>, MJCF actuatorfrcrange); set env.control.effortLimit: {" + joint_name
            + ": <N m>}"
        )
    act = spec.add_actuator(name=joint_name, target=joint_name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    if drive.mode == "effort":
        act.set_to_motor()
    else:
        act.set_to_position(kp=float(drive.stiffness), kv=float(drive.damping))
    # Command ranges stay open: the joint's actuatorfrcrange (URDF effort limit / effortLimit) clamps the force.
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    if drive.torque_limit is not None:
        # A torque-speed limit (sim/actuators.py) rewrites this range per world and physics step.
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-float(drive.torque_limit), float(drive.torque_limit)]


def _rewrite_actuator(act: mujoco.MjsActuator, joint: mujoco.MjsJoint, drive: JointDrive) -> None:
    """Turn the asset's own actuator on ``joint_name`` into the YAML's drive, keeping its name, ctrl column and
    force range: ``position`` -> a PD servo with the YAML gains, ``effort`` -> a motor (commands uncapped, the force
    capped by the actuator's forcerange or the joint's actuatorfrcrange)."""
    joint_name = joint.name
    if drive.mode not in DRIVE_MODES:
        raise ConfigError(f"drive mode '{drive.mode}' of joint '{joint_name}' is not one of {DRIVE_MODES}")
    if drive.mode == "none":
        raise ConfigError(
            f"env.control.driveMode: joint '{joint_name}' is driven by the asset's own actuator '{act.name}', which "
            "a drive mode of 'none' cannot remove: give 'position' or 'effort', or remove the entry"
        )
    if drive.mode == "effort":
        capped = act.forcelimited != mujoco.mjtLimited.mjLIMITED_FALSE and act.forcerange[0] < act.forcerange[1]
        if not (capped or _force_capped(joint)) and drive.torque_limit is None:
            raise ConfigError(
                f"env.control.driveMode: joint '{joint_name}' has an effort drive but its actuator '{act.name}' "
                "and its joint have no force range: set env.control.effortLimit: {" + joint_name + ": <N m>}"
            )
        act.set_to_motor()
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE  # a range of joint targets must not clamp torques
    else:
        act.set_to_position(kp=float(drive.stiffness), kv=float(drive.damping))  # the ctrlrange of targets stays
    if drive.torque_limit is not None:
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-float(drive.torque_limit), float(drive.torque_limit)]


def _force_capped(joint: mujoco.MjsJoint) -> bool:
    lo, hi = (float(v) for v in joint.actfrcrange)
    return joint.actfrclimited != mujoco.mjtLimited.mjLIMITED_FALSE and lo < hi


def _override_actuators(spec: mujoco.MjSpec, patterns: Mapping[str, object], key: str, apply) -> None:
    """Apply {pattern: value} to the actuators selected (``name_matches``' rule: a full match of the actuator's own
    name or of the joint it drives)."""
    actuators = list(spec.actuators)
    for pattern, value in (patterns or {}).items():
        regex = compile_pattern(pattern, key)
        hits = [a for a in actuators if any(n and regex.fullmatch(n) for n in (a.name, a.target))]
        if not hits:
            raise no_match_error(key, pattern, "actuators", [f"{a.name} -> {a.target}" for a in actuators],
                                 " by actuator name or by the joint it drives")
        for act in hits:
            apply(act, value, f"{key}.{pattern}")


def _set_gear(act: mujoco.MjsActuator, value: object, key: str) -> None:
    try:
        gear = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{key}={value!r} is invalid: give a number (the actuator's gear ratio)") from None
    act.gear = [gear] + [0.0] * 5


def _set_ctrl_range(act: mujoco.MjsActuator, value: object, key: str) -> None:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(f"{key}={value!r} is invalid: give [low, high]") from None
    if not lo < hi:
        raise ConfigError(f"{key}={value!r} is invalid: low must be < high")
    act.ctrlrange = [lo, hi]
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE


def _apply_options(spec: mujoco.MjSpec, o: SolverOptions) -> None:
    for key, table in (("integrator", _INTEGRATORS), ("solver", _SOLVERS), ("cone", _CONES)):
        if getattr(o, key) not in table:
            raise ConfigError(f"sim.{key}: '{getattr(o, key)}' is not one of {sorted(table)}")
    if o.dt <= 0:
        raise ConfigError(f"sim.dt must be > 0, got {o.dt}")
    spec.option.timestep = float(o.dt)
    spec.option.gravity = np.asarray(o.gravity, dtype=float)
    spec.option.integrator = _INTEGRATORS[o.integrator]
    spec.option.solver = _SOLVERS[o.solver]
    spec.option.cone = _CONES[o.cone]
    spec.option.iterations = int(o.iterations)
    spec.option.ls_iterations = int(o.ls_iterations)
    if o.ccd_iterations is not None:
        if o.ccd_iterations < 1:
            raise ConfigError(f"sim.ccd_iterations must be >= 1, got {o.ccd_iterations}")
        spec.option.ccd_iterations = int(o.ccd_iterations)
    if o.ccd_tolerance is not None:
        if o.ccd_tolerance <= 0:
            raise ConfigError(f"sim.ccd_tolerance must be > 0, got {o.ccd_tolerance}")
        spec.option.ccd_tolerance = float(o.ccd_tolerance)
    spec.option.impratio = float(o.impratio)
    if not o.enable_contacts:
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT

