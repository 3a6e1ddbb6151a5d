"""Task YAML -> ModelRequest in the sim layer (issue 31): ``sim.request.request_from_config`` asks for the model
that ``VecTask.model_request`` asked for before the move, on every shipped task YAML; the asset is parsed once; one
drive check; name matching rules.

Reference: tests/assets/model_requests.json, written from VecTask.model_request of commit 3b2a975 (before the move;
``python tests/sim/test_model_request.py --record`` rewrites it from whatever VecTask.model_request is now, so only run
it while VecTask still has its own copy), and the live VecTask.model_request while it exists.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from omegaconf import OmegaConf

from conftest import TESTS_DIR
from isaacgymenvs_mw.sim import build_model, request_from_config
from isaacgymenvs_mw.sim import builder as builder_module
from isaacgymenvs_mw.sim.joint_tables import match_body_names, match_joint_numbers, match_joint_values
from isaacgymenvs_mw.sim.names import name_matches
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

REPO = TESTS_DIR.parent
ASSETS_DIR = REPO / "assets"
RECORD = TESTS_DIR / "assets" / "model_requests.json"
TASKS = sorted(p.stem for p in (REPO / "cfg" / "task").glob("*.yaml"))
# The tasks that existed at the move (commit 3b2a975); later tasks were written against the sim layer's request.
RECORDED_TASKS = sorted(json.loads(RECORD.read_text()))


def task_cfg(name: str) -> dict:
    cfg = compose_config([f"task={name}", "num_envs=2"])
    return OmegaConf.to_container(cfg.task, resolve=True)


def describe(request) -> dict:
    """The request as plain data: every field VecTask.model_request set, paths relative to the repository."""
    o = request.options
    return {
        "asset_file": str(Path(request.asset_file).resolve().relative_to(REPO)),
        "fix_base": request.fix_base,
        "collapse_fixed_joints": request.collapse_fixed_joints,
        "self_collisions": request.self_collisions,
        "drives": {j: [d.mode, d.stiffness, d.damping, d.torque_limit] for j, d in request.drives.items()},
        "armature": {j: float(v) for j, v in request.armature.items()},
        "joint_damping": {j: float(v) for j, v in request.joint_damping.items()},
        "ground": None if request.ground is None else request.ground.friction,
        "base_init_pos": None if request.base_init_pos is None else list(request.base_init_pos),
        "base_init_quat": None if request.base_init_quat is None else list(request.base_init_quat),
        "contact_bodies": list(request.contact_bodies),
        "options": [o.dt, list(o.gravity), o.integrator, o.solver, o.cone, o.iterations, o.ls_iterations,
                    o.ccd_iterations, o.ccd_tolerance, o.impratio, o.enable_contacts],
        "effort_limits": dict(request.effort_limits),
        "gear": {k: float(v) for k, v in request.gear.items()},
        "ctrl_range": {k: [float(x) for x in v] for k, v in request.ctrl_range.items()},
        "keep_asset_contacts": request.keep_asset_contacts,
        "torque_speed": {j: list(v) for j, v in request.torque_speed.items()},
    }


def vec_task_request(cfg: dict) -> dict:
    """What VecTask.model_request asks for with this config, without building a task (no Simulator)."""
    from isaacgymenvs_mw.tasks.base.vec_task import VecTask

    task = object.__new__(VecTask)
    task.cfg = cfg
    request = VecTask.model_request(task)
    return describe(request)


def new_request(cfg: dict):
    return request_from_config(cfg["env"], cfg.get("sim", {}), cfg.get("yaml_dir"), ASSETS_DIR)


@pytest.mark.parametrize("task", RECORDED_TASKS)
def test_request_matches_the_recorded_vec_task_request(task):
    recorded = json.loads(RECORD.read_text())
    assert task in recorded, f"{task}: no recorded request; record it (module docstring)"
    assert describe(new_request(task_cfg(task))) == recorded[task]


@pytest.mark.parametrize("task", TASKS)
def test_request_matches_vec_task_model_request_live(task):
    cfg = task_cfg(task)
    assert describe(new_request(cfg)) == vec_task_request(cfg)


def test_every_shipped_task_was_recorded_with_its_differences():
    """The record covers the 10 tasks shipped at the move, and they differ (a record of one request repeated would
    prove little)."""
    recorded = json.loads(RECORD.read_text())
    assert len(recorded) == 10 and set(recorded) <= set(TASKS)
    assert len({json.dumps(v, sort_keys=True) for v in recorded.values()}) >= 6


def test_the_asset_is_parsed_once(monkeypatch):
    """request_from_config parses the file, build_model reuses the parsed spec: one MjSpec.from_file call."""
    cfg = task_cfg("Cartpole")
    calls = []
    real = mujoco.MjSpec.from_file

    def counting(path, *args, **kwargs):
        calls.append(path)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(builder_module.mujoco.MjSpec, "from_file", staticmethod(counting))
    request = new_request(cfg)
    model = build_model(request)
    build_model(request)  # a second build from the same request sees the file's spec, not the first build's edits
    assert len(calls) == 1, calls
    # Reference: the model compiled the old way (a fresh parse inside build_model).
    request.spec = None
    reference = build_model(request)
    assert model.nq == reference.nq and model.nu == reference.nu and model.ngeom == reference.ngeom
    assert mujoco.mj_sizeModel(model) == mujoco.mj_sizeModel(reference)


def test_sim_dt_is_read_once_and_gives_the_timestep():
    cfg = task_cfg("Cartpole")
    cfg["sim"]["dt"] = 0.004
    request = new_request(cfg)
    assert build_model(request).opt.timestep == pytest.approx(0.004)


def _walker_with(control: dict) -> mujoco.MjModel:
    cfg = {"env": {"asset": {"assetRoot": str(TESTS_DIR / "assets"), "assetFileName": "walker.xml",
                             "fixBaseLink": False}, "control": control}, "sim": {}}
    return build_model(new_request(cfg))


def test_a_drive_on_a_joint_the_asset_actuates_rewrites_that_actuator_in_place():
    """A YAML drive on an MJCF-actuated joint replaces the actuator's dynamics, not its name, column or range."""
    written = _walker_with({})
    position = _walker_with({"driveMode": {"left_hip": "position"}, "stiffness": {"left_hip": 55.0},
                             "damping": {"left_hip": 3.0}})
    effort = _walker_with({"driveMode": {"left_hip": "effort"}, "effortLimit": {"left_hip": 10.0}})
    a = written.actuator("left_hip_motor").id
    assert position.nu == effort.nu == written.nu
    for m in (position, effort):
        assert m.actuator("left_hip_motor").id == a and m.actuator_trnid[a, 0] == written.actuator_trnid[a, 0]
        np.testing.assert_array_equal(m.actuator_forcerange[a], written.actuator_forcerange[a])
    # MuJoCo's position servo: force = kp * ctrl - kp * q - kv * qdot
    assert position.actuator_gainprm[a, 0] == 55.0
    np.testing.assert_array_equal(position.actuator_biasprm[a, :3], [0.0, -55.0, -3.0])
    # a motor: force = ctrl, no bias
    assert effort.actuator_gainprm[a, 0] == 1.0 and not effort.actuator_biasprm[a].any()
    # the unselected actuators are as written
    other = written.actuator("right_hip_motor").id
    np.testing.assert_array_equal(position.actuator_gainprm[other], written.actuator_gainprm[other])


def test_a_drive_of_none_on_an_actuated_joint_is_refused():
    with pytest.raises(ConfigError, match=r"^env\.control\.driveMode: joint 'left_hip' is driven by the asset's own "
                                          r"actuator 'left_hip_motor', which a drive mode of 'none' cannot remove"):
        _walker_with({"driveMode": {"left_hip": "none"}})


def test_unknown_sim_key_is_refused_by_the_request():
    cfg = task_cfg("Cartpole")
    cfg["sim"]["substeps"] = 2
    with pytest.raises(ConfigError, match=r"^sim: unknown key\(s\) \['substeps'\]"):
        new_request(cfg)



def test_stability_probe_key_reaches_the_request_and_refuses_a_non_boolean():
    cfg = task_cfg("Cartpole")
    assert new_request(cfg).stability_probe is True  # the default: probe
    cfg["sim"]["stabilityProbe"] = False
    assert new_request(cfg).stability_probe is False
    cfg["sim"]["stabilityProbe"] = "no"  # a string is not a switch: "no" would be truthy
    with pytest.raises(ConfigError, match=r"^sim\.stabilityProbe='no' is invalid: give True or False$"):
        new_request(cfg)

# ------------------------------------------------------------------------------------------------- name matching
NAMES = ["LF_HAA", "LF_HFE", "RF_HAA", "base", "LF_FOOT"]


def test_body_patterns_match_whole_names():
    """Bodies: a pattern is a regular expression that must match the whole name (re.fullmatch)."""
    assert match_body_names([".*_FOOT"], NAMES, "k") == ["LF_FOOT"]
    assert match_body_names(["base"], NAMES, "k") == ["base"]
    with pytest.raises(ConfigError, match="'FOOT' matches no body"):
        match_body_names(["FOOT"], NAMES, "k")  # found inside LF_FOOT, but not the whole name


def test_joint_patterns_match_whole_names():
    """Joints (and the randomisation's names, the actuator overrides): the same rule as bodies, a regular expression
    that must match the whole name (re.fullmatch), as docs/config.md says. A key that is a joint's own name beats the
    other patterns; among patterns the first in YAML order wins."""
    values = match_joint_values({".*_HAA": 1.0, "LF_HFE": 2.0, "LF_.*": 3.0}, NAMES, "k")
    assert values == {"LF_HAA": 1.0, "LF_HFE": 2.0, "RF_HAA": 1.0, "LF_FOOT": 3.0}
    assert match_joint_values({"LF_.*": 3.0, "LF_HFE": 2.0}, NAMES, "k")["LF_HFE"] == 2.0  # the own name wins
    assert name_matches(".*_HAA", NAMES, "k", "joints") == [0, 2]
    assert name_matches("LF_HAA", NAMES, "k", "joints") == [0]
    assert name_matches("L._H..|base", NAMES, "k", "joints") == [0, 1, 3]


def test_a_substring_pattern_selects_nothing_and_says_so():
    """'HAA' used to select every *_HAA joint (the name contained it); under the full-match rule it selects nothing,
    and the error is one line naming the key, the pattern and the names."""
    for select in (lambda: match_joint_values({"HAA": 1.0}, NAMES, "env.control.stiffness"),
                   lambda: name_matches("HAA", NAMES, "env.control.stiffness", "joints")):
        with pytest.raises(ConfigError) as err:
            select()
        message = str(err.value)
        assert "\n" not in message
        assert message.startswith("env.control.stiffness: 'HAA' matches no joint (a pattern must match the whole name)")
        assert str(NAMES) in message
    with pytest.raises(ConfigError, match=r"^k: 'FOOT' matches no body \(a pattern must match the whole name\); "
                                          r"bodies: \['LF_HAA'"):
        match_body_names(["FOOT"], NAMES, "k")
    with pytest.raises(ConfigError, match=r"k: '\(' is not a valid regular expression"):
        name_matches("(", NAMES, "k", "joints")


def test_a_plain_number_is_every_joints_value():
    """task.env.control.stiffness=20 on the command line replaces Go1's {'.*': 20.0} with a number: it means every
    joint, so the request equals the one the YAML's own mapping gives (and a different number changes every gain)."""
    cfg = task_cfg("Go1")
    assert cfg["env"]["control"]["stiffness"] == {".*": 20.0}  # the expectation below is the shipped mapping's
    expected = describe(new_request(cfg))["drives"]
    cfg["env"]["control"]["stiffness"] = 20
    assert describe(new_request(cfg))["drives"] == expected
    cfg["env"]["control"]["stiffness"] = 35.5
    drives = describe(new_request(cfg))["drives"]
    assert len(drives) == 12 and {d[1] for d in drives.values()} == {35.5}
    assert match_joint_numbers(2, NAMES[:2], "k") == {"LF_HAA": 2.0, "LF_HFE": 2.0}
    with pytest.raises(ConfigError, match=r"^k='position' is invalid: give a mapping \{joint or regex: value\}$"):
        match_joint_values("position", NAMES, "k")  # not a number: no table of every joint (defaultDriveMode is one)


@pytest.mark.parametrize("value, message", [
    ("abc", "k='abc' is invalid: give a mapping {joint or regex: value}, e.g. {'.*': 20.0}, or one number for "
            "every joint"),
    ([1.0, 2.0], "k=[1.0, 2.0] is invalid: give a mapping"),
    (True, "k=True is invalid: give a mapping"),
    ({".*_HAA": 1.0, "LF_.*": "abc"}, "k['LF_.*']='abc' is invalid: give a number >= 0.0"),
    ({".*": -1.0}, "k['.*']=-1.0 is invalid: give a number >= 0.0"),
    (-1, "k=-1 is invalid: give a number >= 0.0"),
])
def test_a_per_joint_number_that_is_not_one_is_refused_naming_the_key(value, message):
    with pytest.raises(ConfigError) as err:
        match_joint_numbers(value, NAMES, "k", low=0.0)
    assert str(err.value).startswith(message), str(err.value)


def _record() -> None:
    out = {task: vec_task_request(task_cfg(task)) for task in TASKS}
    RECORD.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    print(f"wrote {RECORD} ({len(out)} tasks)")


if __name__ == "__main__" and "--record" in sys.argv:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    _record()


# --------------------------------------------------------------------------------------------- env.contact
def test_env_contact_sets_condim_and_friction_of_the_geoms_it_selects():
    written = _walker_with({})
    cfg = {"env": {"asset": {"assetRoot": str(TESTS_DIR / "assets"), "assetFileName": "walker.xml",
                             "fixBaseLink": False},
                   "contact": {".*_foot_geom": {"condim": 4, "friction": [1.5, 0.01]}}}, "sim": {}}
    m = build_model(new_request(cfg))
    feet = [g for g in range(m.ngeom) if (m.geom(g).name or "").endswith("_foot_geom")]
    assert feet, "walker.xml has foot geoms"
    for g in range(m.ngeom):
        if g in feet:
            assert m.geom_condim[g] == 4
            np.testing.assert_allclose(m.geom_friction[g], [1.5, 0.01, 0.0001])
        else:  # the others as the file writes them
            assert m.geom_condim[g] == written.geom_condim[g]
            np.testing.assert_array_equal(m.geom_friction[g], written.geom_friction[g])


@pytest.mark.parametrize("entry, message", [
    ({"condim": 2}, r"^env\.contact\.\.\*_foot\.condim=2 is invalid: give one of \[1, 3, 4, 6\]"),
    ({"friction": [1.0, -0.1]}, r"^env\.contact\.\.\*_foot\.friction=\[1\.0, -0\.1\] is invalid: give 1 to 3 "),
    ({"mu": 1.0}, r"^env\.contact\.\.\*_foot=\{'mu': 1\.0\} is invalid: give a mapping with keys condim"),
])
def test_env_contact_bad_values_are_refused_naming_the_key(entry, message):
    cfg = {"env": {"asset": {"assetRoot": str(TESTS_DIR / "assets"), "assetFileName": "walker.xml",
                             "fixBaseLink": False}, "contact": {".*_foot": entry}}, "sim": {}}
    with pytest.raises(ConfigError, match=message):
        build_model(new_request(cfg))


def test_env_contact_pattern_that_selects_no_geom_is_refused():
    cfg = {"env": {"asset": {"assetRoot": str(TESTS_DIR / "assets"), "assetFileName": "walker.xml",
                             "fixBaseLink": False}, "contact": {"gripper_pad": {"condim": 4}}}, "sim": {}}
    with pytest.raises(ConfigError, match=r"^env\.contact\.gripper_pad"):
        build_model(new_request(cfg))
