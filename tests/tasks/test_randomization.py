"""The randomisation layer (task.randomize + task.randomization_params) and actuator realism.

References are independent of the package: distribution moments written out below, MuJoCo C (mj_setConst and
mj_step on a host model given the same masses), and the DC-motor and delay formulas typed here.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf, open_dict

from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.utils.config import compose_config

GO1_QUIET = ["~task.task.randomization_params.push", "~task.task.randomization_params.observations"]


def make(task: str, params: dict | None, num_envs: int, overrides=(), control: dict | None = None):
    """The task with ``task.randomization_params`` replaced by ``params`` (None: randomize False) and
    ``control`` merged into ``env.control``."""
    cfg = compose_config([f"task={task}", f"num_envs={num_envs}", "sim_device=cpu", "rl_device=cpu",
                          "headless=True", *overrides])
    with open_dict(cfg):
        cfg.task.task = OmegaConf.create({"randomize": params is not None, "randomization_params": params or {}})
        cfg.task.env.control = OmegaConf.merge(cfg.task.env.control, control or {})
    return build_task(cfg)


TORQUE_SPEED = {"torqueSpeed": {"saturationTorque": {".*": 12.0}, "torqueLimit": {".*": 9.0},
                                "velocityLimit": {".*": 4.0}}}


def field(task, name: str) -> np.ndarray:
    return task.sim.model_field(name).numpy().copy()


# ------------------------------------------------------------------------- distributions and operations
N_STAT = 4000


def _moments_ok(x: np.ndarray, mean: float, std: float) -> None:
    """Sample mean within 5 standard errors (std / sqrt(n)); sample std within 5 % (its standard error is about
    std / sqrt(2n) = 1.1 % for a gaussian and less for a uniform at n = 4000)."""
    n = x.size
    assert abs(x.mean() - mean) < 5.0 * std / math.sqrt(n), (x.mean(), mean)
    assert abs(x.std() - std) < 0.05 * std, (x.std(), std)


def test_each_distribution_and_operation_matches_its_parameters():
    params = {"actor_params": {
        # Cartpole's motor: gain 1 (MuJoCo motor), so scaling draws are the samples themselves.
        "actuator_properties": {"gain": {"range": [0.8, 1.4], "operation": "scaling", "distribution": "uniform"}},
        # Joint damping 0 in the URDF: additive draws are the samples themselves.
        "dof_properties": {
            "damping": {"joints": "slider_to_cart", "range": [0.5, 0.1], "operation": "additive",
                        "distribution": "gaussian"},
            "armature": {"joints": "cart_to_pole", "range": [0.01, 1.0], "operation": "additive",
                         "distribution": "loguniform"},
        },
        "rigid_body_properties": {"mass": {"bodies": "pole", "range": [0.9, 0.3], "operation": "scaling",
                                           "distribution": "gaussian"}},
    }}
    task = make("Cartpole", params, N_STAT)
    m = task.sim.mj_model
    gain = field(task, "actuator_gainprm")[:, 0, 0]
    assert gain.min() >= 0.8 and gain.max() <= 1.4
    _moments_ok(gain, mean=(0.8 + 1.4) / 2, std=(1.4 - 0.8) / math.sqrt(12))  # U(a, b): (a+b)/2, (b-a)/sqrt 12

    slider, pole_joint = (m.joint(n).dofadr[0] for n in ("slider_to_cart", "cart_to_pole"))
    damping = field(task, "dof_damping")
    _moments_ok(damping[:, slider], mean=0.5, std=0.1)  # N(mean, std); clamped at 0, 5 std away
    np.testing.assert_array_equal(damping[:, pole_joint], 0.0)  # not selected: nominal

    armature = field(task, "dof_armature")[:, pole_joint]
    log_lo, log_hi = math.log(0.01), math.log(1.0)  # log of a loguniform sample is U(log a, log b)
    _moments_ok(np.log(armature), mean=(log_lo + log_hi) / 2, std=(log_hi - log_lo) / math.sqrt(12))

    pole = m.body("pole").id
    mass = field(task, "body_mass")[:, pole] / m.body_mass[pole]  # nominal x N(0.9, 0.3)
    _moments_ok(mass, mean=0.9, std=0.3)
    assert len(np.unique(field(task, "body_mass")[:, m.body("cart").id])) == 1  # not selected


def test_a_linear_schedule_shrinks_the_draws_towards_the_nominal_value():
    spec = {"range": [-2.0, 2.0], "operation": "additive", "distribution": "uniform",
            "schedule": "linear", "schedule_steps": 100}
    task = make("Cartpole", {"actor_params": {"actuator_properties": {"bias": spec}}}, N_STAT)
    # IsaacGymEnvs counts env steps: after 25 of 100 the additive range is a quarter as wide, U(-0.5, 0.5).
    task.set_train_info(25 * task.num_envs)
    task.reset()
    x = field(task, "actuator_biasprm")[:, 0, 0]  # the motor's constant force, nominal 0
    assert np.abs(x).max() <= 0.5 + 1e-6
    _moments_ok(x, mean=0.0, std=1.0 / math.sqrt(12))
    task.set_train_info(200 * task.num_envs)  # past schedule_steps: the full range
    task.reset()
    _moments_ok(field(task, "actuator_biasprm")[:, 0, 0], mean=0.0, std=4.0 / math.sqrt(12))


# ---------------------------------------------------------------------------- only reset worlds change
MASS_ALL = {"rigid_body_properties": {
    "mass": {"bodies": ".*", "range": [0.7, 1.3], "operation": "scaling", "distribution": "uniform"},
    "com": {"bodies": ".*", "range": [-0.02, 0.02], "operation": "additive", "distribution": "uniform"},
    "inertia": {"bodies": ".*", "range": [0.7, 1.3], "operation": "scaling", "distribution": "uniform"},
}, "rigid_shape_properties": {"friction": {"geoms": "ground", "range": [0.5, 1.5], "operation": "scaling"}}}


def _host_model(task, world: int) -> mujoco.MjModel:
    """The task's compiled host model given one world's randomised values, its constants recomputed by MuJoCo C."""
    m = task.sim.mj_model.__copy__()
    for name in ("body_mass", "body_ipos", "body_inertia", "geom_friction", "dof_armature"):
        values = field(task, name)
        getattr(m, name)[:] = values[world % values.shape[0]]
    mujoco.mj_setConst(m, mujoco.MjData(m))
    return m


def test_only_resetting_worlds_draw_and_their_constants_match_mujoco_c():
    task = make("Go1", {"actor_params": MASS_ALL}, 6, GO1_QUIET)
    task.reset()
    names = ("body_mass", "body_ipos", "body_inertia", "geom_friction", "body_invweight0", "dof_invweight0")
    before = {n: field(task, n) for n in names}
    mask = torch.tensor([False, True, False, False, True, False])
    task.reset_envs(mask)
    for n in names:
        after = field(task, n)
        np.testing.assert_array_equal(after[~mask.numpy()], before[n][~mask.numpy()], err_msg=n)
        assert not np.allclose(after[mask.numpy()], before[n][mask.numpy()]), n
    # The derived constants the step reads equal MuJoCo C's mj_setConst with the same masses, in every world.
    for w in range(task.num_envs):
        ref = _host_model(task, w)
        np.testing.assert_allclose(field(task, "body_invweight0")[w], ref.body_invweight0, rtol=2e-5, atol=1e-7)
        np.testing.assert_allclose(field(task, "dof_invweight0")[w], ref.dof_invweight0, rtol=2e-5, atol=1e-7)


# ------------------------------------------------------------------------ dynamics equal MuJoCo C's
def _trajectory_error(task, steps: int) -> tuple[float, float]:
    """Max |qpos| error against mj_step on each world's host model, and how far the worlds are from nominal."""
    sim, m0 = task.sim, task.sim.mj_model
    qpos0, qvel0 = sim.qpos.numpy().copy(), sim.qvel.numpy().copy()
    ctrl = sim.ctrl.numpy().copy()
    for _ in range(steps):
        sim.simulate()
    err, spread = 0.0, 0.0
    for w in range(task.num_envs):
        for model, out in ((_host_model(task, w), "err"), (m0, "spread")):
            d = mujoco.MjData(model)
            d.qpos[:], d.qvel[:], d.ctrl[:] = qpos0[w], qvel0[w], ctrl[w]
            for _ in range(steps * sim.substeps):
                mujoco.mj_step(model, d)
            diff = float(np.abs(d.qpos - sim.qpos.numpy()[w]).max())
            if out == "err":
                err = max(err, diff)
            else:
                spread = max(spread, diff)
    return err, spread


@pytest.mark.parametrize("quantity", ["mass", "com", "inertia"])
def test_randomised_masses_com_and_inertia_move_the_robot_as_mujoco_c_does(quantity):
    params = {"actor_params": {"rigid_body_properties": {quantity: MASS_ALL["rigid_body_properties"][quantity]}}}
    task = make("Go1", params, 3, GO1_QUIET)
    task.reset()
    # In the air (contacts are compared through their constants in the test above), legs driven hard: the
    # base's and the legs' masses, centres of mass and inertias decide how the whole body swings.
    sim = task.sim
    sim.qpos[:, 2] = 2.0
    sim.qvel.zero_()
    sim.ctrl.copy_(task.default_dof_pos + torch.sin(torch.arange(3 * 12, dtype=torch.float32)).view(3, 12))
    err, spread = _trajectory_error(task, steps=10)
    assert spread > 20 * err, (err, spread)  # the randomised values change the motion far beyond the error
    assert err < 2e-3, err


# ----------------------------------------------------------------------------------------- action delay
def _ctrl_trace(task, steps: int) -> tuple[np.ndarray, np.ndarray]:
    # Distinct, small, alternating: the cart stays near the middle and no episode ends during the trace.
    actions = 0.01 * np.arange(1, steps + 1, dtype=np.float32) * (-1.0) ** np.arange(steps, dtype=np.float32)
    seen = []
    for a in actions:
        task.step(torch.full((task.num_envs, 1), float(a)))
        assert not task.reset_buf.any()
        seen.append(task.sim.ctrl[:, 0].numpy() / task.max_push_effort)
    return actions, np.stack(seen)


def test_an_action_delay_of_k_shows_the_action_k_steps_later():
    k = 3
    task = make("Cartpole", None, 2, ["+task.env.control.actionDelay=3"])
    task.reset()
    sent, seen = _ctrl_trace(task, 8)
    expected = np.concatenate((np.zeros(k), sent[:-k]))  # nothing sent before the first step: zero action
    np.testing.assert_allclose(seen, np.tile(expected[:, None], (1, 2)), rtol=1e-6)
    # A reset clears the env's history: it acts on zeros again for k steps, the other env goes on.
    task.reset_envs(torch.tensor([True, False]))
    sent2, seen2 = _ctrl_trace(task, 4)
    np.testing.assert_allclose(seen2[:k, 0], 0.0)
    np.testing.assert_allclose(seen2[k:, 0], sent2[:-k], rtol=1e-6)
    np.testing.assert_allclose(seen2[:, 1], np.concatenate((sent[-k:], sent2[:-k])), rtol=1e-6)


def test_a_randomised_delay_gives_each_env_a_whole_delay_in_its_range():
    params = {"actions": {"delay": {"range": [0, 2]}}}
    task = make("Cartpole", params, 64, ["+task.env.control.actionDelay=1"])
    task.reset()
    sent, seen = _ctrl_trace(task, 8)
    padded = np.concatenate((np.zeros(3), sent))
    delays = []
    for e in range(task.num_envs):
        matches = [d for d in range(0, 4) if np.allclose(seen[:, e], padded[3 - d:3 - d + 8])]
        assert len(matches) == 1, (e, seen[:, e])
        delays.append(matches[0])
    assert set(delays) == {1, 2, 3}  # nominal 1 + U{0, 1, 2}; 64 envs draw every value


# ---------------------------------------------------------------------------------- torque-speed limit
def test_the_torque_speed_limit_clips_as_its_formula_says():
    sat, lim, speed = 12.0, 9.0, 4.0
    task = make("Go1", None, 4, ["task.env.controlFrequencyInv=1"], control=TORQUE_SPEED)
    task.reset()
    m, sim = task.sim.mj_model, task.sim
    kp, kv = m.actuator_gainprm[:, 0], -m.actuator_biasprm[:, 2]
    dof = m.jnt_dofadr[m.actuator_trnid[:, 0]]
    qadr = m.jnt_qposadr[m.actuator_trnid[:, 0]]
    actuator_force = sim.actuator_force
    gen = torch.Generator().manual_seed(1)
    clipped = 0
    for _ in range(30):
        q, qd = sim.qpos.numpy()[:, qadr].copy(), sim.qvel.numpy()[:, dof].copy()
        task.step(4.0 * (2.0 * torch.rand(task.num_envs, 12, generator=gen) - 1.0))
        target = sim.ctrl.numpy()
        pd = kp * (target - q) - kv * qd
        upper = np.clip(sat * (1.0 - qd / speed), 0.0, lim)   # tau_max(qd) = clip(sat (1 - qd/qd_max), 0, lim)
        lower = np.clip(sat * (-1.0 - qd / speed), -lim, 0.0)  # tau_min(qd) = clip(sat (-1 - qd/qd_max), -lim, 0)
        expected = np.clip(pd, lower, upper)
        np.testing.assert_allclose(actuator_force.numpy(), expected, rtol=1e-4, atol=1e-3)
        clipped += int(np.sum(np.abs(expected - pd) > 1e-3))
    assert clipped > 50  # the curve, not only the PD law, decided many forces


def test_torque_speed_parameters_are_randomisable_per_world():
    params = {"actor_params": {"actuator_properties": {
        "torque_limit": {"range": [0.5, 1.0], "operation": "scaling"}}}}
    task = make("Go1", params, 8, control=TORQUE_SPEED)
    limit = task.sim.torque_speed.limit.numpy()
    assert limit.shape == (8, 12)
    assert limit.min() >= 4.5 and limit.max() <= 9.0 and len(np.unique(limit)) > 8


# ------------------------------------------------------------------------- pushes, noise and gravity
def test_gravity_is_drawn_per_world():
    params = {"sim_params": {"gravity": {"range": [0.0, 0.5], "operation": "additive", "distribution": "gaussian"}}}
    task = make("Go1", params, 6, GO1_QUIET)
    g = field(task, "opt.gravity")
    assert g.shape == (6, 3)
    assert np.all(np.abs(g - np.array([0.0, 0.0, -9.81])) < 5 * 0.5) and len(np.unique(g[:, 0])) == 6


def test_observation_noise_adds_the_terms_noise_and_the_section_noise():
    params = {"observations": {"terms": {"dof_vel": 2.0}, "range": [0.0, 0.5], "distribution": "gaussian",
                               "operation": "additive"}}
    task = make("Go1", params, 400, [])
    obs = task.reset()["obs"]
    states = task.get_state()  # the critic's copy is noiseless
    noise = (obs - states[:, :48]).numpy()
    dof_vel = task.observations.obs_layout.slices["dof_vel"]
    scale = task.observations.obs_layout.terms[5].scale
    # U(-2 scale, 2 scale) + N(0, 0.5): variance (4 scale)^2 / 12 + 0.25
    expected_std = math.sqrt((4 * scale) ** 2 / 12 + 0.25)
    _moments_ok(noise[:, dof_vel].ravel(), mean=0.0, std=expected_std)
    _moments_ok(noise[:, :3].ravel(), mean=0.0, std=0.5)  # base_lin_vel: only the section noise


def test_pushes_set_the_base_velocity_every_interval():
    params = {"push": {"interval_steps": 3, "range": [0.7, 0.7], "operation": "set"}}
    task = make("Go1", params, 4, [])
    task.reset()
    seen = []
    task_pre_physics = task.pre_physics_step

    def record(actions):  # the push comes before the actions, in the same step
        seen.append(task.sim.root_lin_vel[:, :2].numpy().copy())
        task_pre_physics(actions)

    task.pre_physics_step = record
    for _ in range(8):
        task.step(torch.zeros(4, 12))
    # Steps start at episode step 0; pushes come when 3 and 6 steps have run, never at a reset.
    for step, vel in enumerate(seen):
        pushed = np.all(vel == np.float32(0.7))
        assert pushed == (step in (3, 6)), (step, vel)


# -------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("params, words", [
    ({"actor_params": {"rigid_body_properties": {"volume": {"range": [0, 1], "operation": "additive"}}}},
     ["rigid_body_properties.volume", "unknown parameter", "mass"]),
    ({"actor_params": {"rigid_body_properties": {"mass": {"bodies": "wing", "range": [0, 1],
                                                          "operation": "additive"}}}},
     ["rigid_body_properties.mass.bodies", "'wing' matches no body", "pole"]),
    ({"actor_params": {"rigid_shape_properties": {"friction": {"geoms": "^sand$", "range": [0.5, 1],
                                                              "operation": "scaling"}}}},
     ["rigid_shape_properties.friction.geoms", "'^sand$' matches no geom"]),
    ({"actor_params": {"rigid_body_properties": {"mass": {"range": [-1.0, 1.0], "operation": "scaling"}}}},
     ["rigid_body_properties.mass.range", "must stay > 0"]),
    ({"actor_params": {"rigid_body_properties": {"mass": {"range": [-100.0, 0.0], "operation": "additive"}}}},
     ["rigid_body_properties.mass.range", "must stay > 0", "nominal + low"]),
    ({"actor_params": {"rigid_shape_properties": {"friction": {"range": [-0.5, 1.0], "operation": "scaling"}}}},
     ["rigid_shape_properties.friction.range", "must stay > 0"]),
    ({"actor_params": {"dof_properties": {"damping": {"range": [0, 1], "operation": "additive",
                                                      "distribution": "normal"}}}},
     ["dof_properties.damping.distribution='normal'", "uniform", "gaussian", "loguniform"]),
    ({"actor_params": {"dof_properties": {"stiffness": {"range": [0, 1], "operation": "additive"}}}},
     ["dof_properties.stiffness", "actuator_properties.stiffness"]),
    ({"actor_params": {"dof_properties": {"damping": {"range": [0, 1], "operation": "multiply"}}}},
     ["damping.operation='multiply'", "additive", "scaling"]),
    ({"gravity": {"range": [0, 1]}}, ["task.randomization_params", "unknown section", "sim_params"]),
    ({"actor_params": {"actuator_properties": {"torque_limit": {"range": [0.5, 1], "operation": "scaling"}}}},
     ["torque_limit", "env.control.torqueSpeed"]),
    ({"actions": {"delay": {"range": [0, 1.5]}}}, ["actions.delay", "whole"]),
])
def test_bad_randomisation_input_fails_naming_the_key(params, words):
    with pytest.raises(ValueError) as err:
        make("Cartpole", params, 2)
    for word in words:
        assert word in str(err.value), (word, str(err.value))


def test_disabled_randomisation_batches_nothing_and_draws_nothing():
    task = make("Go1", None, 3, [])
    assert task.sim.model_field("body_mass").shape[0] == 1
    assert task.sim.model_field("geom_friction").shape[0] == 1
    obs = task.reset()["obs"]
    np.testing.assert_array_equal(obs.numpy(), task.get_state()[:, :48].numpy())  # no noise
