"""IsaacGymEnvs env keys that a ported YAML carries but that have no counterpart here are named in one warning when the
task is built, each with its reason; a YAML without them builds silently.

The expected key list is written out here by hand (the IsaacGymEnvs keys a port meets), not read from the code.
"""

from __future__ import annotations

import warnings

import torch

import isaacgymenvs_mw

IGE_KEYS = {"envSpacing": 4.0, "enableDebugVis": False, "enableCameraSensors": False, "aggregateMode": 1}
IGE_PLANE_KEYS = {"staticFriction": 1.0, "dynamicFriction": 1.0, "restitution": 0.0}


def build(overrides: list[str]):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        task = isaacgymenvs_mw.make("Cartpole", num_envs=2, sim_device="cpu", rl_device="cpu", overrides=overrides)
    return task, [str(w.message) for w in caught if "IsaacGymEnvs key" in str(w.message)]


def test_ige_keys_are_named_once_with_their_reason():
    overrides = [f"+task.env.{k}={v}" for k, v in IGE_KEYS.items()]
    overrides += [f"+task.env.plane.{k}={v}" for k, v in IGE_PLANE_KEYS.items()]
    task, messages = build(overrides)
    assert len(messages) == 1, messages  # one warning for all of them
    (message,) = messages
    for key in [*IGE_KEYS, *(f"plane.{k}" for k in IGE_PLANE_KEYS)]:
        assert f"env.{key} (" in message, (key, message)
    assert "its own MuJoCo world" in message and "no debug drawing" in message
    assert message.count("set env.plane.friction") == 2

    # envSpacing has nothing to act on: two worlds in the same state have their bodies at the same place.
    task.reset()
    task.sim.write_state(torch.ones(2, dtype=torch.bool), dof_pos=torch.zeros(2, 2), dof_vel=torch.zeros(2, 2))
    assert torch.equal(task.sim.xpos[0], task.sim.xpos[1])


def test_only_the_keys_present_are_named():
    _, (message,) = build(["+task.env.envSpacing=2.0"])
    assert "env.envSpacing (" in message
    assert not any(f"env.{k} (" in message for k in ("enableDebugVis", "aggregateMode", "plane.restitution"))


def test_a_yaml_without_them_builds_silently():
    _, messages = build([])
    assert messages == []
