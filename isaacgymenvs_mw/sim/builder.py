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

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import mujoco

from isaacgymenvs_mw.sim.asset_loading import (
    SceneAsset,
    attach,
    check_joint,
    load_spec,
    movable_joint_names,
    place_root,
)
from isaacgymenvs_mw.sim.asset_parse import compile_error
from isaacgymenvs_mw.sim.cameras import CameraSpec
from isaacgymenvs_mw.sim.drives import JointDrive, add_drives
from isaacgymenvs_mw.sim.geom_contacts import (
    GeomContact,
    add_average_friction_pairs,
    set_geom_contacts,
)
from isaacgymenvs_mw.sim.ground import GroundPlane, add_ground, set_collision_filter
from isaacgymenvs_mw.sim.options import SolverOptions, apply_options
from isaacgymenvs_mw.sim.sensors import ContactForces, Sensor
from isaacgymenvs_mw.sim.stability import warn_unstable_drives
from isaacgymenvs_mw.sim.terrain import Terrain
from isaacgymenvs_mw.utils.errors import ConfigError


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
    terrain: Terrain | None = None
    # The parsed asset_file (sim/request.py parses it once); None: build_model parses asset_file.
    spec: mujoco.MjSpec | None = None
    # Further assets of the scene (env.assets), attached in this order under their prefixes.
    assets: Sequence[SceneAsset] = ()
    # {geom name regex: GeomContact}: contact properties of the selected geoms of the whole scene (env.contact).
    geom_contacts: Mapping[str, GeomContact] = field(default_factory=dict)
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
    # (linear, angular) velocity damping of the main asset's free bodies, 1/s (env.asset.linearDamping, angularDamping)
    damping: tuple[float, float] = (0.0, 0.0)

    def free_body_damping(self) -> dict[str, tuple[float, float]]:
        """{asset name prefix ('' for the main asset): (linear, angular)} of the assets that damp their free bodies'
        velocity (``sim.velocity_limit.free_joint_damping`` finds their joints in the compiled model)."""
        out = {"": self.damping} if any(self.damping) else {}
        out.update({a.prefix: a.damping for a in self.assets if any(a.damping)})
        return out

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



def build_model(request: ModelRequest) -> mujoco.MjModel:
    """Compile the task's model: asset + base + ground + actuators + scene assets + cameras + declared sensors +
    contact sensors + solver options."""
    # A copy: building edits the spec, and the request's parsed spec must stay as the file says for a second build.
    spec = request.spec.copy() if request.spec is not None else load_spec(request.asset_file,
                                                                          request.collapse_fixed_joints)
    joints = movable_joint_names(spec)
    # A floating base starts at the pose (its qpos0); a fixed one is welded there (IsaacGymEnvs' hand pose).
    place_root(spec, request.asset_file, request.fix_base, request.base_init_pos, request.base_init_quat,
               "env.asset")

    collide_bits = set_collision_filter(spec, request.self_collisions, request.keep_asset_contacts)
    ground = []
    if request.ground is not None:
        ground = add_ground(spec, request.ground, request.terrain, collide_bits, request.keep_asset_contacts)

    for name, value in request.armature.items():
        spec.joint(name).armature = float(value)
    for name, value in request.joint_damping.items():
        spec.joint(name).damping = [float(value)] + list(spec.joint(name).damping)[1:]
    for name, value in request.effort_limits.items():
        check_joint(spec, name, "env.control.effortLimit")
        joint = spec.joint(name)
        joint.actfrcrange = [-float(value), float(value)]
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
    add_drives(spec, joints, request.drives, request.gear, request.ctrl_range)

    # After the main asset's actuators, so that its ctrl columns come first and the YAML's gear / ctrlRange
    # patterns reach only them; the scene assets' own actuators follow, in env.assets order.
    for asset in request.assets:
        attach(spec, asset)
    if request.assets and request.keep_asset_contacts:
        contype, conaffinity = set_collision_filter(spec, False, True)  # now the objects' geoms count too
        for geom in ground:
            geom.contype, geom.conaffinity = contype, conaffinity
    set_geom_contacts(spec, request.geom_contacts)
    add_average_friction_pairs(spec, request.average_friction)
    for body_name in request.contact_bodies:
        if spec.body(body_name) is None:
            raise ConfigError(f"contact body '{body_name}' is not a body of {request.asset_file}")
    for sensor in request.all_sensors():
        sensor.add_to(spec)

    apply_options(spec, request.options)
    try:
        model = spec.compile()
    except ValueError as err:  # one line naming the asset: a repeated name, a root with joints, a mesh, ...
        raise compile_error(err, request.asset_file) from err
    # Here, where the timestep, the inertias and the constraints are final: a drive too stiff for them (alone, or
    # coupled to others through a closed chain) blows up every world.
    warn_unstable_drives(model, {j for j, d in request.drives.items() if d.mode == "position"},
                         probe=request.stability_probe)
    return model
