"""Sensors by name (sim/sensors.py): MJCF sensors and env.sensors entries as torch views of sensordata, checked
against MuJoCo C (``mj_forward`` on the same model and state, read by ``model.sensor(name).adr / dim``)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw.sim import JointDrive, ModelRequest, Sensor, Simulator, SolverOptions, build_model, sensor_specs
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.go1 import Go1
from isaacgymenvs_mw.utils.config import compose_config, to_dict
from isaacgymenvs_mw.utils.errors import ConfigError

# A two-link arm hanging from the world, driven at both joints, with MJCF force / torque sensors at the elbow (the
# interaction between the forearm and the upper arm) and a frame orientation sensor at the wrist.
ARM = """<mujoco model="arm">
  <worldbody>
    <body name="upper" pos="0 0 1">
      <joint name="shoulder" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="1"/>
      <body name="lower" pos="0.3 0 0" euler="20 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.025" mass="0.6"/>
        <site name="elbow_site" pos="0 0 0" euler="0 30 0"/>
        <site name="wrist" pos="0.25 0 0" euler="10 0 45"/>
      </body>
    </body>
  </worldbody>
  <sensor>
    <force name="elbow_force" site="elbow_site"/>
    <torque name="elbow_torque" site="elbow_site"/>
    <framequat name="wrist_quat" objtype="site" objname="wrist"/>
  </sensor>
</mujoco>
"""
DECLARED = {"imu": {"type": "imu", "site": "wrist"}, "forearm_pos": {"type": "framepos", "body": "lower"}}
NAMES = ["elbow_force", "elbow_torque", "wrist_quat", "imu", "forearm_pos"]
WORLDS = 3


def build(tmp_path, declared=DECLARED) -> mujoco.MjModel:
    path = tmp_path / "arm.xml"
    path.write_text(ARM)
    request = ModelRequest(asset_file=path, fix_base=True, keep_asset_contacts=True,
                           drives={j: JointDrive("position", 20.0, 1.0) for j in ("shoulder", "elbow")},
                           options=SolverOptions(dt=0.005, enable_contacts=False), declared_sensors=sensor_specs(declared),
                           stability_probe=False)
    return build_model(request)


def reference(model: mujoco.MjModel, qpos, qvel, ctrl, name: str, warmstart=None) -> np.ndarray:
    """MuJoCo C's value of sensor ``name`` (an imu: its two parts) at this state (``warmstart``: where the
    constraint solver starts, as a Warp world's carried ``qacc_warmstart``)."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:], data.ctrl[:] = qpos, qvel, ctrl
    if warmstart is not None:
        data.qacc_warmstart[:] = warmstart
    mujoco.mj_forward(model, data)
    parts = [f"{name}_accelerometer", f"{name}_gyro"] if name == "imu" else [name]
    return np.concatenate([data.sensordata[model.sensor(p).adr[0]:][:model.sensor(p).dim[0]] for p in parts])


def test_sensor_views_equal_mujoco_c_and_are_refreshed_in_place(tmp_path):
    model = build(tmp_path)
    sim = Simulator(model, WORLDS, "cpu")
    views = {name: sim.sensor(name) for name in NAMES}
    dims = {name: v.shape[1] for name, v in views.items()}
    assert dims == {"elbow_force": 3, "elbow_torque": 3, "wrist_quat": 4, "imu": 6, "forearm_pos": 3}
    storage = sim.sensordata.untyped_storage().data_ptr()
    assert all(v.untyped_storage().data_ptr() == storage for v in views.values())  # slices, not copies

    gen = torch.Generator().manual_seed(3)
    sim.qpos.copy_(torch.rand(WORLDS, 2, generator=gen) * 2 - 1)
    sim.qvel.copy_(torch.rand(WORLDS, 2, generator=gen) * 4 - 2)
    sim.ctrl.copy_(torch.rand(WORLDS, 2, generator=gen) - 0.5)
    for step in range(3):
        before = [t.clone().double().numpy() for t in (sim.qpos, sim.qvel, sim.ctrl)]
        previous = {name: v.clone() for name, v in views.items()}
        sim.simulate()  # sensors describe the state this step started from
        for name, view in views.items():
            assert not torch.equal(view, previous[name]) or step == 0 and name == "forearm_pos", name
            for w in range(WORLDS):
                expected = reference(model, before[0][w], before[1][w], before[2][w], name)
                np.testing.assert_allclose(view[w].double().numpy(), expected, rtol=1e-4, atol=1e-4,
                                           err_msg=f"{name}, world {w}, step {step}")
    # The forces are not trivial: the forearm's weight and the drives load the elbow.
    assert float(views["elbow_force"].norm(dim=1).min()) > 1.0
    assert float(views["imu"][:, 3:].norm(dim=1).min()) > 0.1  # the gyro sees the arm turning


def test_imu_parts_are_named_and_survive_a_saved_model(tmp_path):
    model = build(tmp_path)
    assert [model.sensor(i).name for i in range(model.nsensor)] == [
        "elbow_force", "elbow_torque", "wrist_quat", "imu_accelerometer", "imu_gyro", "forearm_pos"]
    path = tmp_path / "arm.mjb"
    Simulator(model, 1, "cpu").save_model(str(path))
    loaded = Simulator(mujoco.MjModel.from_binary_path(str(path)), 1, "cpu")
    assert loaded.sensor("imu").shape == (1, 6)


def test_a_missing_sensor_is_one_line_naming_the_key_the_value_and_the_sensors(tmp_path):
    sim = Simulator(build(tmp_path), 1, "cpu")
    with pytest.raises(ConfigError) as err:
        sim.sensor("elbow_frc", key="env.legForceSensors")
    assert str(err.value) == ("env.legForceSensors: 'elbow_frc' is not a sensor of the model; its sensors: "
                              "['elbow_force', 'elbow_torque', 'wrist_quat', 'imu_accelerometer', 'imu_gyro', "
                              "'forearm_pos', 'imu']")


@pytest.mark.parametrize("declared, message", [
    ({"imu": {"type": "imus", "site": "wrist"}}, r"^env\.sensors\.imu\.type='imus' is invalid: give one of \['imu', "),
    ({"imu": {"type": "imu"}}, r"^env\.sensors\.imu: give exactly one site or body for a sensor of type imu "),
    ({"imu": {"type": "imu", "site": "wrist", "body": "lower"}},
     r"^env\.sensors\.imu: give exactly one site or body for a sensor of type "),
    ({"imu": {"type": "imu", "body": "hand"}}, r"^env\.sensors\.imu\.body='hand' is not a body of the model; "),
    ({"imu": {"type": "imu", "site": "wrist", "noise": 0.1}}, r"^env\.sensors\.imu: unknown key\(s\) \['noise'\]"),
    ({"imu": {"type": "imu", "site": "hand"}},
     r"^env\.sensors\.imu\.site='hand' is not a site of the model; sites: \['elbow_site', 'wrist'\]$"),
    ({"p": {"type": "framepos", "body": "hand"}}, r"^env\.sensors\.p\.body='hand' is not a body of the model; "),
    ({"wrist_quat": {"type": "gyro", "site": "wrist"}},
     r"^env\.sensors\.wrist_quat: the model already has a sensor named \['wrist_quat'\]"),
])
def test_bad_sensor_declarations_are_one_line_naming_the_key(tmp_path, declared, message):
    with pytest.raises(ConfigError, match=message) as err:
        build(tmp_path, declared)
    assert "\n" not in str(err.value)


# ------------------------------------------------------------------------------------------------ the legged IMU
# An IMU on Go1's base, declared and observed as a user would (cfg/legged/base.yaml: env.sensors, env.observeSensors);
# randomisation off, so that every world runs the host model MuJoCo C is given.
IMU_SCALE = 0.5
IMU_OVERRIDES = ["++task.env.sensors={imu: {type: imu, body: trunk}}",
                 f"++task.env.observeSensors={{imu: {IMU_SCALE}}}", "task.task.randomize=False"]


@pytest.fixture(scope="module")
def go1():
    import isaacgymenvs_mw

    return isaacgymenvs_mw.make("Go1", num_envs=WORLDS, sim_device="cpu", rl_device="cpu", seed=0,
                                overrides=IMU_OVERRIDES)


def test_legged_imu_equals_mujoco_c_in_the_air_and_on_the_ground(go1):
    sim, gen = go1.sim, torch.Generator().manual_seed(5)
    model = sim.mj_model
    site = model.site("imu_site")
    assert model.body(int(site.bodyid[0])).name == "trunk" and not site.pos.any()  # at the base's frame
    everyone = torch.ones(WORLDS, dtype=torch.bool)
    go1.reset()
    for airborne in (True, False):
        if airborne:  # high above the ground, turning and moving, legs driven: no contacts
            sim.write_state(everyone, root_pos=torch.tensor([[0.0, 0.0, 2.0]]).repeat(WORLDS, 1),
                            root_quat=torch.nn.functional.normalize(torch.rand(WORLDS, 4, generator=gen), dim=1),
                            root_lin_vel=torch.rand(WORLDS, 3, generator=gen) * 2 - 1,
                            root_ang_vel=torch.rand(WORLDS, 3, generator=gen) * 4 - 2,
                            dof_pos=go1.default_dof_pos.repeat(WORLDS, 1),
                            dof_vel=torch.rand(WORLDS, 12, generator=gen) * 4 - 2)
        else:  # standing: reset, then 0.4 s of the default pose, which lands every world on its feet
            go1.reset()
            for _ in range(20):
                go1.step(torch.zeros(WORLDS, 12))
        sim.ctrl.copy_(go1.default_dof_pos + 0.2 * (torch.rand(WORLDS, 12, generator=gen) * 2 - 1))
        state = [t.clone().double().numpy() for t in (sim.qpos, sim.qvel, sim.ctrl)]
        # Both solve the contacts in a few Newton iterations: from the same start they agree.
        warmstart = sim.save_state()["qacc_warmstart"].double().numpy()
        # A step's sensors describe the start of its last physics step (of controlFrequencyInv); forward() computes
        # them from this state, as mj_forward does.
        sim.forward()
        imu = sim.sensor("imu")
        assert imu.shape == (WORLDS, 6)
        for w in range(WORLDS):
            expected = reference(model, state[0][w], state[1][w], state[2][w], "imu", warmstart[w])
            np.testing.assert_allclose(imu[w].double().numpy(), expected, rtol=1e-4, atol=1e-4,
                                       err_msg=f"world {w}, {'in the air' if airborne else 'standing'}")
        # The gyro is the base's angular velocity in its own frame, which is MuJoCo's free-joint qvel[3:6].
        np.testing.assert_allclose(imu[:, 3:].double().numpy(), state[1][:, 3:6], atol=1e-5)
        feet = torch.stack([sim.sensor(f"contact_{foot}") for foot in go1.feet], 1).norm(dim=-1).amax(dim=1)
        if airborne:  # proper acceleration: a body in free fall reads far less than gravity
            assert float(feet.max()) == 0.0 and float(imu[:, :3].norm(dim=1).max()) < 9.81 * 0.95
        else:  # standing: the feet push the base up, and it reads that push along its up axis
            assert float(feet.min()) > 1.0 and float(imu[:, 2].min()) > 0.0


def test_contact_forces_sensor_is_a_view_of_the_contact_sensors(go1):
    forces = go1.sim.sensor("contact_forces")
    bodies = go1.sim.sensors.get("contact_forces").bodies
    assert forces.shape == (WORLDS, len(bodies), 3)
    assert forces.untyped_storage().data_ptr() == go1.sim.sensordata.untyped_storage().data_ptr()  # no copy
    go1.reset()
    go1.step(torch.zeros(WORLDS, 12))
    assert float(forces.norm(dim=-1).max()) > 1.0  # the feet stand
    # Body by body, the columns MuJoCo gives each body's contact sensor (net force: 3 values).
    m = go1.sim.mj_model
    columns = [go1.sim.sensordata[:, m.sensor(f"contact_{b}").adr[0]:][:, :3] for b in bodies]
    assert all(int(m.sensor(f"contact_{b}").dim[0]) == 3 for b in bodies)
    torch.testing.assert_close(forces, torch.stack(columns, dim=1), rtol=0, atol=0)


def test_legged_imu_observation_term_has_its_size_scale_and_values(go1):
    layout = go1.observations.obs_layout
    assert layout.names[-1] == "imu" and layout.slices["imu"] == slice(48, 54)
    assert go1.num_obs == 54 and go1.num_states == 61  # the critic's noiseless policy part has it too
    assert go1.observations.state_layout.slices["imu"] == slice(48, 54)
    go1.reset()
    for _ in range(3):
        obs, *_ = go1.step(torch.rand(WORLDS, 12) * 2 - 1)
    expected = (go1.sim.sensor("imu") * IMU_SCALE).clamp(-go1.clip_obs, go1.clip_obs)
    torch.testing.assert_close(obs["obs"][:, 48:54], expected, rtol=0, atol=0)
    torch.testing.assert_close(obs["states"][:, 48:54], expected, rtol=0, atol=0)


def test_observed_sensors_are_checked_when_the_task_is_built():
    import isaacgymenvs_mw

    key = r"^task\.env\.observeSensors"
    for observed, message in (("{gps: 1.0}", key + r"\.gps: 'gps' is not a sensor of the model; "),
                              ("{imu: fast}", key + r"\.imu='fast' is invalid: give a finite number")):
        with pytest.raises(ConfigError, match=message):
            isaacgymenvs_mw.make("Go1", num_envs=1, sim_device="cpu", rl_device="cpu",
                                 overrides=[*IMU_OVERRIDES[::2], f"++task.env.observeSensors={observed}"])


def test_any_task_observes_sensors_after_its_own_terms():
    """env.observeSensors is VecTask's: Cartpole (no legged code) observes a frame sensor on its pole after its 4
    terms; the sensor reads the pole's centre of mass (a body frame sensor's, MuJoCo's mjOBJ_BODY) as MuJoCo C's
    kinematics puts it."""
    import isaacgymenvs_mw

    task = isaacgymenvs_mw.make("Cartpole", num_envs=3, sim_device="cpu", rl_device="cpu", seed=0,
                                overrides=["++task.env.sensors={tip: {type: framepos, body: pole}}",
                                           "++task.env.observeSensors={tip: 0.5}"])
    layout = task.observations.obs_layout
    assert layout.names[-1] == "tip" and layout.slices["tip"] == slice(4, 7) and task.num_obs == 7
    task.reset()
    for _ in range(3):
        obs, *_ = task.step(torch.rand(3, 1) * 2 - 1)
    tip = task.sim.sensor("tip")
    expected = (tip * 0.5).clamp(-task.clip_obs, task.clip_obs)
    torch.testing.assert_close(obs["obs"][:, 4:7], expected, rtol=0, atol=0)
    task.sim.forward()  # the sensor from the current state, as MuJoCo C computes the body's inertial frame from it
    model, data = task.sim.mj_model, mujoco.MjData(task.sim.mj_model)
    for world in range(3):
        data.qpos[:] = task.sim.qpos[world].double().numpy()
        mujoco.mj_kinematics(model, data)
        np.testing.assert_allclose(tip[world].numpy(), data.xipos[model.body("pole").id], atol=1e-5)


# ------------------------------------------------------------------------------------- a sensor of the user's own
class BaseSpeed(Sensor):
    """docs/contributing.md's computed sensor as the guide wrote it before sensors bound to a context (``bind(sim)``,
    ``sim.root_lin_vel``): the context reads the same state views by name, so it runs unchanged."""

    name = "base_speed"

    def bind(self, sim):
        self._vel, self._out = sim.root_lin_vel, torch.zeros(sim.num_worlds, 1, device=sim.device)
        return self._out

    def sense(self):
        self._out[:] = self._vel[:, :2].norm(dim=1, keepdim=True)


class SpeedGo1(Go1):
    def __init__(self, cfg, *args, **kwargs):
        super().__init__(cfg, *args, **kwargs)
        self.speed = self.sim.sensor("base_speed")

    def model_request(self):
        request = super().model_request()
        # the guide's earlier name of ModelRequest.declared_sensors, which a task of that guide uses unchanged
        request.sensors = (*request.sensors, BaseSpeed())
        return request

    def observation_terms(self):
        return super().observation_terms() + [ObsTerm("base_speed", 1, 0.5, compute=lambda: self.speed)]


def test_a_computed_sensor_is_refreshed_by_the_sense_phase_after_the_resets():
    cfg = to_dict(compose_config(["task=Go1", f"num_envs={WORLDS}", "task.task.randomize=False",
                                  "task.env.episodeLength_s=0.1"]).task)  # 5 steps: resets happen in the step
    task = SpeedGo1(cfg, rl_device="cpu", sim_device="cpu", graphics_device_id=0, headless=True)
    speed = task.sim.sensor("base_speed")
    assert speed is task.speed and speed.shape == (WORLDS, 1) and task.observations.obs_layout.slices["base_speed"] == slice(48, 49)
    obs = task.reset()["obs"]
    seen, ended = [], 0
    for _ in range(8):
        expected = task.sim.root_lin_vel[:, :2].norm(dim=1, keepdim=True)  # the state after the step's resets
        torch.testing.assert_close(speed, expected, rtol=0, atol=0)
        torch.testing.assert_close(obs[:, 48:49], expected * 0.5, rtol=0, atol=0)
        seen.append(speed.clone())
        obs_dict, _, reset, _ = task.step(torch.rand(WORLDS, 12) * 2 - 1)
        obs, ended = obs_dict["obs"], ended + int(reset.sum())
    assert ended > 0 and len({tuple(s.flatten().tolist()) for s in seen}) == len(seen)  # new values every step
