"""IsaacGymEnvs' randomisation keys (issue 59): the per-actor level ``actor_params.<actor>.<group>``, ``frequency``,
``range_correlated``, ``setup_only``, ``num_buckets``, ``dof_properties.lower/upper/friction``, the torsional and
rolling friction; and a one-line refusal, saying why, for the keys with no MuJoCo counterpart. References: the
nominal values of the compiled host model (MuJoCo C) and distribution moments written out here."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from omegaconf import OmegaConf, open_dict

from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.utils.config import compose_config


def make(task: str, params: dict, num_envs: int):
    """The task on the CPU with ``task.randomization_params`` replaced by ``params`` (randomize on)."""
    cfg = compose_config([f"task={task}", f"num_envs={num_envs}", "sim_device=cpu", "rl_device=cpu", "headless=True"])
    with open_dict(cfg):
        cfg.task.task = OmegaConf.create({"randomize": True, "randomization_params": params})
    return build_task(cfg)


def field(task, name: str) -> np.ndarray:
    return task.sim.model_field(name).numpy().copy()


def _host(task, name: str) -> np.ndarray:
    return np.asarray(getattr(task.sim.mj_model, name))


def test_an_actor_level_group_randomises_that_actor_only():
    params = {"actor_params": {"cubeA": {"rigid_body_properties": {"mass": {"range": [2.0, 2.0],
                                                                            "operation": "scaling"}}}}}
    task = make("FrankaCubeLift", params, 2)
    m = task.sim.mj_model
    cube = [b for b in range(m.nbody) if m.body(b).name.startswith("cubeA/")]
    assert cube
    expected = _host(task, "body_mass").copy()
    expected[cube] *= 2.0
    np.testing.assert_allclose(field(task, "body_mass"), np.broadcast_to(expected, (2, m.nbody)), rtol=1e-6)


def test_the_main_asset_is_the_actor_named_asset():
    params = {"actor_params": {"asset": {"rigid_body_properties": {"mass": {"range": [1.0, 1.0]}}}}}
    task = make("FrankaCubeLift", params, 2)
    m = task.sim.mj_model
    main = [b for b in range(1, m.nbody) if not m.body(b).name.startswith(("cubeA/", "table/"))]
    expected = _host(task, "body_mass").copy()
    expected[main] += 1.0
    np.testing.assert_allclose(field(task, "body_mass")[0], expected, rtol=1e-6)


def test_joint_limits_dof_friction_and_the_other_friction_columns_are_drawn():
    params = {"actor_params": {
        "dof_properties": {"lower": {"joints": "slider_to_cart", "range": [-0.5, -0.5]},
                           "upper": {"joints": "slider_to_cart", "range": [2.0, 2.0], "operation": "scaling"},
                           "friction": {"joints": "cart_to_pole", "range": [0.3, 0.3]}},
        "rigid_shape_properties": {"torsion_friction": {"range": [0.01, 0.01]},
                                   "rolling_friction": {"range": [3.0, 3.0], "operation": "scaling"}}}}
    task = make("Cartpole", params, 2)
    m = task.sim.mj_model
    slider, hinge = m.joint("slider_to_cart").id, m.joint("cart_to_pole").id
    ranges = field(task, "jnt_range")
    low, high = m.jnt_range[slider]
    np.testing.assert_allclose(ranges[:, slider], [[low - 0.5, 2.0 * high]] * 2, rtol=1e-6)
    np.testing.assert_allclose(ranges[:, hinge], np.tile(m.jnt_range[hinge], (2, 1)))
    loss = field(task, "dof_frictionloss")
    np.testing.assert_allclose(loss[:, m.jnt_dofadr[hinge]], m.dof_frictionloss[m.jnt_dofadr[hinge]] + 0.3)
    np.testing.assert_allclose(loss[:, m.jnt_dofadr[slider]], m.dof_frictionloss[m.jnt_dofadr[slider]])
    friction = field(task, "geom_friction")
    np.testing.assert_allclose(friction[..., 0], np.broadcast_to(m.geom_friction[:, 0], friction.shape[:2]))
    np.testing.assert_allclose(friction[..., 1], np.broadcast_to(m.geom_friction[:, 1] + 0.01,
                                                                 friction.shape[:2]), rtol=1e-6)
    np.testing.assert_allclose(friction[..., 2], np.broadcast_to(m.geom_friction[:, 2] * 3.0,
                                                                 friction.shape[:2]), rtol=1e-6)


def test_num_buckets_draws_from_that_many_values():
    params = {"actor_params": {"rigid_shape_properties": {"friction": {"range": [0.5, 1.5], "num_buckets": 3,
                                                                       "operation": "scaling"}}}}
    task = make("Cartpole", params, 64)
    m = task.sim.mj_model
    ratio = field(task, "geom_friction")[..., 0] / m.geom_friction[:, 0]
    values = np.unique(np.round(ratio, 6))
    assert len(values) == 3 and values.min() >= 0.5 and values.max() <= 1.5


def _gain(task) -> np.ndarray:
    return field(task, "actuator_gainprm")[:, 0, 0]


def test_frequency_holds_an_envs_reset_draws_and_setup_only_draws_once():
    spec = {"range": [0.5, 1.5], "operation": "scaling"}
    task = make("Cartpole", {"frequency": 3, "actor_params": {"actuator_properties": {"gain": spec}}}, 4)
    task.reset()
    everyone = torch.ones(4, dtype=torch.bool)
    before = _gain(task)
    for _ in range(2):
        task.step(task.zero_actions())
    task.reset_envs(everyone)  # 2 steps since the draw at startup: fewer than frequency, kept
    np.testing.assert_array_equal(_gain(task), before)
    task.step(task.zero_actions())
    task.reset_envs(everyone)  # 3 steps: drawn anew
    assert np.all(_gain(task) != before)

    once = make("Cartpole", {"actor_params": {"actuator_properties": {"gain": {**spec, "setup_only": True}}}}, 4)
    once.reset()
    first = _gain(once)
    once.step(once.zero_actions())
    once.reset_envs(everyone)
    np.testing.assert_array_equal(_gain(once), first)
    assert len(np.unique(first)) == 4  # drawn, per world


def test_range_correlated_adds_an_offset_kept_for_frequency_steps():
    params = {"frequency": 10, "observations": {"range": [0.0, 0.0], "distribution": "gaussian",
                                                "operation": "additive", "range_correlated": [0.0, 0.5]}}
    task = make("Cartpole", params, 500)
    layer = task.randomizer
    layer.step_count.fill_(1.0)
    first = torch.zeros(500, 4)
    layer.observations(first)
    again = torch.zeros(500, 4)
    layer.step_count.fill_(9.0)
    layer.observations(again)
    torch.testing.assert_close(again, first)  # the same offsets until frequency steps have passed
    x = first.numpy().ravel()
    assert abs(x.mean()) < 5 * 0.5 / math.sqrt(x.size) and abs(x.std() - 0.5) < 0.05 * 0.5
    layer.step_count.fill_(10.0)
    new = torch.zeros(500, 4)
    layer.observations(new)
    assert not torch.allclose(new, first)


def test_range_correlated_actions_keep_their_offset_between_draws():
    params = {"frequency": 4, "actions": {"range": [0.0, 0.0], "range_correlated": [-0.2, 0.2]}}
    task = make("Cartpole", params, 8)
    layer = task.randomizer
    layer.step_count.fill_(1.0)
    first = layer.actions(torch.zeros(8, 1))
    layer.step_count.fill_(3.0)
    torch.testing.assert_close(layer.actions(torch.zeros(8, 1)), first)
    assert first.abs().max() <= 0.2 and len(torch.unique(first)) == 8
    layer.step_count.fill_(4.0)
    assert not torch.allclose(layer.actions(torch.zeros(8, 1)), first)


@pytest.mark.parametrize("params, message", [
    ({"actor_params": {"cubeA": {"color": True}}},
     "task.task.randomization_params.actor_params.cubeA.color=True has no counterpart here: MuJoCo Warp renders no "
     "per-env colours for randomisation; remove it"),
    ({"actor_params": {"cubeA": {"scale": {"range": [0.9, 1.1]}}}},
     "task.task.randomization_params.actor_params.cubeA.scale={'range': [0.9, 1.1]} has no counterpart here: MuJoCo Warp "
     "shares one geometry"),
    ({"actor_params": {"rigid_shape_properties": {"restitution": {"range": [0.0, 1.0]}}}},
     "task.task.randomization_params.actor_params.rigid_shape_properties.restitution={'range': [0.0, 1.0]} has no "
     "counterpart here: MuJoCo's contacts are soft constraints without a restitution coefficient"),
    ({"actor_params": {"franka": {"rigid_body_properties": {"mass": {"range": [0, 1]}}}}},
     "task.task.randomization_params.actor_params.franka.rigid_body_properties.mass: 'franka' is no actor of this "
     "scene; actors: ['asset (task.env.asset)', 'table', 'cubeA']"),
    ({"frequency": 0}, "task.task.randomization_params.frequency=0 is invalid: give a whole number >= 1"),
    ({"actor_params": {"dof_properties": {"damping": {"range": [0, 1], "num_buckets": 4}}}},
     "task.task.randomization_params.actor_params.dof_properties.damping: unknown key(s) ['num_buckets']"),
    ({"actor_params": {"rigid_shape_properties": {"friction": {"range": [0.5, 1], "num_buckets": 4,
                                                              "schedule": "linear", "schedule_steps": 10}}}},
     "task.task.randomization_params.actor_params.rigid_shape_properties.friction.num_buckets=4 and "
     "task.task.randomization_params.actor_params.rigid_shape_properties.friction.schedule='linear' cannot go together"),
    ({"actions": {"range_correlated": [0, 1]}},
     "task.task.randomization_params.actions.range_correlated=[0, 1] needs task.task.randomization_params.actions.range"),
])
def test_keys_without_a_counterpart_are_refused_in_one_line(params, message):
    with pytest.raises(ValueError) as err:
        make("FrankaCubeLift", params, 2)
    assert str(err.value).startswith(message), str(err.value)
    assert "\n" not in str(err.value)
