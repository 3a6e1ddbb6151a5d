"""Task YAML (``env`` and ``sim`` sections) -> ``ModelRequest``: what the sim layer is asked to build.

Each asset file is parsed once, here; the parsed ``MjSpec`` travels in the request (``ModelRequest.spec``,
``SceneAsset.spec``) so that ``build_model`` and the tasks that look at body names do not parse it again. The
drive-mode clash (a YAML drive on a joint the asset's own actuator drives) is checked in one place, ``build_model``;
``sim.dt`` is read in one place, ``sim_dt``.

A scene is the main asset (``env.asset``, names unprefixed) plus the named assets of ``env.assets`` (objects and
fixtures, IsaacGymEnvs' actors), each attached to the main model under its own name prefix (``<name>/`` unless
``prefix`` says otherwise); see ``sim/scene.py`` for the views the built Simulator gives each of them.

Names in YAML mappings (``driveMode``, ``stiffness``, ``contactBodies``, ...) are regular expressions that must
match the whole name: one rule, ``name_matches`` in ``sim/names.py`` (used by ``match_joint_values`` and
``match_body_names``), documented in docs/config.md below the ``env.asset`` table.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

from isaacgymenvs_mw.sim.asset_loading import (
    SceneAsset,
    actuated_joints,
    is_mjcf,
    load_spec,
    movable_joint_names,
)
from isaacgymenvs_mw.sim.builder import ModelRequest
from isaacgymenvs_mw.sim.cameras import camera_specs
from isaacgymenvs_mw.sim.drives import JointDrive
from isaacgymenvs_mw.sim.geom_contacts import GeomContact
from isaacgymenvs_mw.sim.ground import GroundPlane
from isaacgymenvs_mw.sim.joint_tables import (
    match_body_names,
    match_joint_numbers,
    match_joint_values,
)
from isaacgymenvs_mw.sim.options import SolverOptions
from isaacgymenvs_mw.sim.sensors import sensor_specs
from isaacgymenvs_mw.utils.config import check_entry, real_number
from isaacgymenvs_mw.utils.errors import ConfigError, MissingFileError

# Every key the task YAML's `sim` section may hold (docs/config.md, "sim"); any other is a typo or a key of another
# simulator, and is refused rather than ignored.
SIM_KEYS = ("dt", "gravity", "integrator", "solver", "cone", "iterations", "ls_iterations", "ccd_iterations",
            "ccd_tolerance", "impratio", "enableContacts", "nconmax", "njmax", "overflowCheckInterval", "useGraphs",
            "captureStep", "compileStep", "deterministic", "stabilityProbe")

# Keys of one env.assets entry (docs/config.md, "Scenes of several assets").
# No collapseFixedJoints: MuJoCo's fusestatic is one compiler flag for the whole model, env.asset's.
SCENE_ASSET_KEYS = ("assetRoot", "assetFileName", "pos", "rot", "fixBaseLink", "prefix", "keepAssetContacts",
                    "maxAngularVelocity", "linearDamping", "angularDamping")

TorqueSpeed = dict[str, tuple[float, float, float]]


def request_from_config(env: Mapping, sim: Mapping, yaml_dir: str | None, assets_dir: Path) -> ModelRequest:
    """The model a task YAML asks for, from ``env.asset``, ``env.assets``, ``env.control`` (its ``torqueSpeed``
    limits included: ``ModelRequest.torque_speed``), ``env.plane``, ``env.baseInitState``, ``env.cameras`` and ``sim``.

    ``yaml_dir``: the task YAML's folder (relative asset roots are resolved against it; None: the working
    directory). ``assets_dir``: the folder an empty ``assetRoot`` means (the repository's ``assets/``).
    """
    check_sim_keys(sim)
    asset = env.get("asset", {})
    asset_file = asset_path(asset, yaml_dir, assets_dir)
    collapse = bool(asset.get("collapseFixedJoints", True))
    spec = load_spec(asset_file, collapse)
    joints = movable_joint_names(spec)
    control = env.get("control", {})
    torque_speed = torque_speed_limits(control.get("torqueSpeed"), joints)
    plane = env.get("plane", {})
    ground = GroundPlane(float(plane.get("friction", 1.0))) if plane.get("enabled", False) else None
    fix_base = bool(asset.get("fixBaseLink", True))
    base_pos, base_quat = base_init_pose(env)
    keep_contacts = bool(asset.get("keepAssetContacts", is_mjcf(asset_file)))
    if keep_contacts and "selfCollisions" in asset:
        raise ConfigError(
            "env.asset.selfCollisions is set but the asset's own contact settings are kept "
            "(env.asset.keepAssetContacts is True, the default for an MJCF): set keepAssetContacts: False to "
            "use the framework's collision filter, or remove selfCollisions and say it in the MJCF"
        )
    return ModelRequest(
        asset_file=asset_file,
        fix_base=fix_base,
        collapse_fixed_joints=collapse,
        self_collisions=bool(asset.get("selfCollisions", False)),
        drives=joint_drives(control, joints, actuated_joints(spec), torque_speed),
        armature=match_joint_numbers(asset.get("armature"), joints, "env.asset.armature", low=0.0),
        joint_damping=match_joint_numbers(asset.get("jointDamping"), joints, "env.asset.jointDamping", low=0.0),
        ground=ground,
        base_init_pos=base_pos,
        base_init_quat=base_quat,
        contact_bodies=match_body_names(asset.get("contactBodies"), [b.name for b in spec.bodies],
                                        "env.asset.contactBodies"),
        options=solver_options(sim),
        effort_limits=match_joint_numbers(control.get("effortLimit"), joints, "env.control.effortLimit", low=0.0),
        gear=dict(control.get("gear") or {}),
        ctrl_range=dict(control.get("ctrlRange") or {}),
        keep_asset_contacts=keep_contacts,
        spec=spec,
        assets=scene_assets(env.get("assets"), yaml_dir, assets_dir, collapse),
        geom_contacts=geom_contacts(env.get("contact")),
        average_friction=average_friction_pairs(env.get("averageFriction")),
        cameras=camera_specs(env.get("cameras")),
        declared_sensors=sensor_specs(env.get("sensors")),
        stability_probe=stability_probe(sim),
        torque_speed=torque_speed,
        max_angular_velocity=max_angular_velocity(asset, "env.asset"),
        damping=body_damping(asset, "env.asset"),
    )


def max_angular_velocity(asset: Mapping, key: str) -> float | None:
    """``<key>.maxAngularVelocity``: IsaacGym's ``max_angular_velocity`` (rad/s, > 0) for the asset's free bodies;
    absent or null: no cap (MuJoCo's own behaviour; IsaacGym's default is 64)."""
    value = asset.get("maxAngularVelocity")
    if value is None:
        return None
    return real_number(value, f"{key}.maxAngularVelocity", low=0.0, low_open=True)


def body_damping(asset: Mapping, key: str) -> tuple[float, float]:
    """``<key>.linearDamping`` and ``angularDamping``: IsaacGym's ``linear_damping`` and ``angular_damping`` (1/s,
    >= 0) for the asset's free bodies; absent or null: 0 (MuJoCo's own behaviour; IsaacGym's defaults are 0 and 0.5)."""
    return tuple(0.0 if asset.get(name) is None else real_number(asset.get(name), f"{key}.{name}", low=0.0)
                 for name in ("linearDamping", "angularDamping"))


CONDIMS = (1, 3, 4, 6)


def average_friction_pairs(cfg: object) -> list[tuple[str, str]]:
    """``env.averageFriction``: a list of [geom regex, geom regex] pairs (sim/geom_contacts.py). Whether each pattern
    selects a geom is checked when the scene is composed."""
    if not cfg:
        return []
    entries = list(cfg) if isinstance(cfg, Sequence) and not isinstance(cfg, str) else None
    if entries is None or not all(isinstance(e, Sequence) and not isinstance(e, str) and len(e) == 2
                                  for e in entries):
        raise ConfigError(f"env.averageFriction={cfg!r} is invalid: give a list of [geom regex, geom regex] pairs, "
                          "e.g. [['cube', 'table']]")
    return [(str(a), str(b)) for a, b in entries]


def geom_contacts(cfg: Mapping | None) -> dict[str, GeomContact]:
    """``env.contact``: {geom name regex: {condim, friction}} as ``GeomContact``s; a bad value is an error naming
    ``env.contact.<pattern>.<key>``. Whether each pattern selects a geom is checked when the scene is composed."""
    if not cfg:
        return {}
    if not hasattr(cfg, "items"):
        raise ConfigError(f"env.contact={cfg!r} is invalid: give a mapping {{geom name regex: {{condim: 4, "
                          "friction: [1.0, 0.005, 0.0001]}}}}")
    out = {}
    for pattern, entry in cfg.items():
        key = f"env.contact.{pattern}"
        if not hasattr(entry, "items") or sorted(str(k) for k in entry if k not in ("condim", "friction")):
            raise ConfigError(f"{key}={entry!r} is invalid: give a mapping with keys condim and/or friction")
        condim = entry.get("condim")
        if condim is not None and (isinstance(condim, bool) or condim not in CONDIMS):
            raise ConfigError(f"{key}.condim={condim!r} is invalid: give one of {list(CONDIMS)} (1 frictionless, "
                              "3 sliding friction, 4 + torsional, 6 + rolling)")
        friction = entry.get("friction")
        if friction is not None:
            try:
                friction = [float(v) for v in ([friction] if isinstance(friction, (int, float)) else friction)]
            except (TypeError, ValueError):
                friction = None
            if friction is None or not 1 <= len(friction) <= 3 or min(friction) < 0:
                raise ConfigError(f"{key}.friction={entry.get('friction')!r} is invalid: give 1 to 3 numbers >= 0 "
                                  "(sliding, torsional, rolling)")
            friction = friction + [0.005, 0.0001][len(friction) - 1:]  # MuJoCo's defaults for the ones not given
        out[str(pattern)] = GeomContact(None if condim is None else int(condim), friction)
    return out


def scene_assets(cfg: Mapping | None, yaml_dir: str | None, assets_dir: Path,
                 collapse_fixed_joints: bool = True) -> tuple[SceneAsset, ...]:
    """``env.assets``: {name: {assetRoot, assetFileName, pos, rot, fixBaseLink, prefix, ...}} as ``SceneAsset``s,
    in YAML order. A mapping, not a list, so that an override can address one asset by name
    (``task.env.assets.cube.pos=[0,0,1]``)."""
    if not cfg:
        return ()
    if not hasattr(cfg, "items"):
        raise ConfigError(f"env.assets={cfg!r} is invalid: give a mapping {{name: {{assetFileName: ..., ...}}}}")
    out: list[SceneAsset] = []
    taken: dict[str, str] = {}  # prefix -> the asset that has it
    for name, entry in cfg.items():
        key = f"env.assets.{name}"
        check_entry(entry, key, SCENE_ASSET_KEYS)
        prefix = str(entry.get("prefix", f"{name}/"))
        if not prefix:
            # The main asset's names are unprefixed: an empty prefix would let this asset's names clash with them.
            raise ConfigError(f"{key}.prefix='' is invalid: give a non-empty prefix (default '{name}/')")
        if prefix in taken:
            raise ConfigError(f"{key}.prefix='{prefix}' is also the prefix of env.assets.{taken[prefix]}: give each "
                              "asset its own prefix")
        taken[prefix] = str(name)
        path = asset_path(entry, yaml_dir, assets_dir, key)
        pos, quat = _pose(entry, key)
        out.append(SceneAsset(
            name=str(name),
            asset_file=path,
            prefix=prefix,
            fix_base=bool(entry.get("fixBaseLink", False)),
            pos=pos,
            quat=quat,
            keep_asset_contacts=bool(entry.get("keepAssetContacts", is_mjcf(path))),
            spec=load_spec(path, collapse_fixed_joints, key),
            max_angular_velocity=max_angular_velocity(entry, key),
            damping=body_damping(entry, key),
        ))
    return tuple(out)


def asset_path(asset_cfg: Mapping, yaml_dir: str | None, assets_dir: Path, key: str = "env.asset") -> Path:
    """``<key>.assetRoot`` / ``assetFileName``. An empty root is ``assets_dir``; a relative root is relative to the
    task YAML's folder (``yaml_dir``, recorded when train.py / ``make()`` compose the config), or to the working
    directory for a config built by hand."""
    name = asset_cfg.get("assetFileName")
    if not name:
        raise ConfigError(f"{key}.assetFileName is not set in the task YAML")
    root = str(asset_cfg.get("assetRoot") or "")
    if not root:
        base, how = Path(assets_dir), "empty assetRoot: the repository's assets/ folder"
    elif Path(root).expanduser().is_absolute():
        base, how = Path(root).expanduser(), "absolute assetRoot"
    elif yaml_dir:
        base, how = Path(yaml_dir) / root, f"relative assetRoot, resolved against the task YAML's folder {yaml_dir}"
    else:
        base, how = Path.cwd() / root, ("relative assetRoot, resolved against the working directory: the config "
                                        "records no task YAML folder (task.yaml_dir)")
    path = base / name
    if not path.is_file():
        raise MissingFileError(
            f"{key}: asset file '{path}' does not exist (assetRoot='{root}', assetFileName='{name}'; {how})"
        )
    return path


def base_init_pose(env: Mapping) -> tuple[tuple[float, ...] | None, tuple[float, ...] | None]:
    """``env.baseInitState`` pos / rot (w, x, y, z): where a floating base starts, or where a fixed one is welded;
    None where the YAML gives none (the asset's root body pose is kept)."""
    return _pose(env.get("baseInitState") or {}, "env.baseInitState")


def _pose(cfg: Mapping, key: str) -> tuple[tuple[float, ...] | None, tuple[float, ...] | None]:
    out = []
    for name, size in (("pos", 3), ("rot", 4)):
        value = cfg.get(name)
        if value is not None and len(value) != size:
            raise ConfigError(f"{key}.{name}={list(value)} is invalid: give {size} numbers")
        out.append(None if value is None else tuple(float(v) for v in value))
    if out[1] is not None and not math.isclose(sum(v * v for v in out[1]), 1.0, rel_tol=1e-3):
        raise ConfigError(f"{key}.rot={list(out[1])} is not a unit quaternion (w, x, y, z)")
    return out[0], out[1]


def joint_drives(control: Mapping, joints: list[str], owned: Mapping[str, str],
                 torque_speed: TorqueSpeed) -> dict[str, JointDrive]:
    """``env.control`` drive settings per joint. ``defaultDriveMode`` covers the joints the asset does not actuate;
    a ``driveMode`` entry on a joint the asset's own actuator drives is passed on as given, and ``build_model``
    refuses it (the one drive check). A torque-speed limit (saturation, limit, no-load speed) caps the drive's
    force at its continuous limit."""
    explicit = match_joint_values(control.get("driveMode"), joints, "env.control.driveMode")
    default_mode = str(control.get("defaultDriveMode", "none"))
    stiffness = match_joint_numbers(control.get("stiffness"), joints, "env.control.stiffness", 0.0, low=0.0)
    damping = match_joint_numbers(control.get("damping"), joints, "env.control.damping", 0.0, low=0.0)
    return {
        j: JointDrive(str(explicit.get(j, default_mode)), stiffness[j], damping[j],
                      torque_speed[j][1] if j in torque_speed else None)
        for j in joints if j not in owned or j in explicit
    }


def check_sim_keys(sim: Mapping) -> None:
    """Refuse a ``sim`` key that is not in ``SIM_KEYS``."""
    unknown = sorted(str(k) for k in sim if k not in SIM_KEYS)
    if unknown:
        raise ConfigError(f"sim: unknown key(s) {unknown} (IsaacGymEnvs' PhysX keys such as physx, substeps and "
                         f"use_gpu_pipeline have no counterpart here); valid keys: {list(SIM_KEYS)}")


def sim_dt(sim: Mapping) -> float:
    """``sim.dt``, the physics timestep in seconds (the one place it is read, and checked: the randomiser reads it
    before the model is built)."""
    return real_number(sim.get("dt", SolverOptions().dt), "sim.dt", 0.0, low_open=True)


def stability_probe(sim: Mapping) -> bool:
    """``sim.stabilityProbe``: whether the build steps one world in MuJoCo C to see if the drives diverge."""
    value = sim.get("stabilityProbe", True)
    if not isinstance(value, bool):
        raise ConfigError(f"sim.stabilityProbe={value!r} is invalid: give True or False")
    return value


def solver_options(sim: Mapping) -> SolverOptions:
    """The task YAML ``sim`` section as solver options (IsaacGymEnvs' ``dt`` and ``gravity`` keep their names)."""
    defaults = SolverOptions()
    return SolverOptions(
        dt=sim_dt(sim),
        gravity=tuple(sim.get("gravity", defaults.gravity)),
        integrator=str(sim.get("integrator", defaults.integrator)),
        solver=str(sim.get("solver", defaults.solver)),
        cone=str(sim.get("cone", defaults.cone)),
        iterations=int(sim.get("iterations", defaults.iterations)),
        ls_iterations=int(sim.get("ls_iterations", defaults.ls_iterations)),
        ccd_iterations=None if sim.get("ccd_iterations") is None else int(sim["ccd_iterations"]),
        ccd_tolerance=None if sim.get("ccd_tolerance") is None else float(sim["ccd_tolerance"]),
        impratio=float(sim.get("impratio", defaults.impratio)),
        enable_contacts=bool(sim.get("enableContacts", defaults.enable_contacts)),
    )


def torque_speed_limits(cfg: Mapping | None, joints: list[str]) -> TorqueSpeed:
    """``env.control.torqueSpeed`` per joint: (saturation torque, torque limit, no-load speed); {} when absent."""
    if not cfg:
        return {}
    key = "env.control.torqueSpeed"
    unknown = sorted(set(cfg) - {"saturationTorque", "torqueLimit", "velocityLimit"})
    if unknown:
        raise ConfigError(f"{key}: unknown key(s) {unknown}; valid: saturationTorque, torqueLimit, velocityLimit")
    for required in ("saturationTorque", "velocityLimit"):
        if not cfg.get(required):
            raise ConfigError(f"{key}.{required} is required ({{joint pattern: value}})")
    sat = match_joint_numbers(cfg["saturationTorque"], joints, f"{key}.saturationTorque")
    speed = match_joint_numbers(cfg["velocityLimit"], joints, f"{key}.velocityLimit")
    limit = match_joint_numbers(cfg.get("torqueLimit"), joints, f"{key}.torqueLimit")
    out = {}
    for j in sat:
        if j not in speed:
            raise ConfigError(f"{key}.velocityLimit gives no value for joint '{j}', which has a saturationTorque")
        values = (float(sat[j]), float(limit.get(j, sat[j])), float(speed[j]))
        if not all(v > 0 for v in values):
            raise ConfigError(f"{key}: joint '{j}' has {values} (saturationTorque, torqueLimit, velocityLimit); "
                             "each must be > 0")
        out[j] = values
    return out
