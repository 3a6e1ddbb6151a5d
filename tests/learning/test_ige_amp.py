"""IsaacGymEnvs' own HumanoidAMPPPO.yaml (its amp_continuous learner, which rl_games lacks) trains unchanged with this
project's AMP on the rsl_rl learner: its keys mapped onto the recipe this project ships for the task (written by hand
from the same YAML), test mode, and one-line refusals of what the mapping cannot honour."""

from __future__ import annotations

import math

import pytest

from conftest import REPO_ROOT
from isaacgymenvs_mw.learning.ige_amp import use_ige_amp_recipe
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.utils.config import compose_config, to_dict
from isaacgymenvs_mw.utils.errors import ConfigError

IGE_CFG = REPO_ROOT / "tests" / "data" / "isaacgymenvs_cfg"  # IsaacGymEnvs' own train YAMLs, as they ship
IGE_AMP = ["task=HumanoidAMP", "train=HumanoidAMPPPO"]


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in d.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def test_isaacgymenvs_amp_yaml_maps_onto_the_shipped_recipe():
    """Every setting of the mapped YAML equals cfg/train/HumanoidAMPPPO.yaml's but four, each IsaacGymEnvs' own:
    the std exp(-2.9) unrounded, no gradient clipping (truncate_grads: False), rl_games' input normalisation, and the
    reward scale 1 stated."""
    cfg = compose_config(IGE_AMP, config_dir=IGE_CFG)
    use_ige_amp_recipe(cfg)
    mapped, shipped = _flat(to_dict(cfg.train)), _flat(to_dict(compose_config(["task=HumanoidAMP"]).train))
    differ = {k for k in set(mapped) | set(shipped) if mapped.get(k) != shipped.get(k)}
    assert differ == {"actor.distribution_cfg.init_std", "algorithm.max_grad_norm", "algorithm.obs_normalization_clip",
                      "algorithm.obs_normalization_form", "runner.reward_scale"}
    assert mapped["actor.distribution_cfg.init_std"] == pytest.approx(math.exp(-2.9))
    assert shipped["actor.distribution_cfg.init_std"] == pytest.approx(math.exp(-2.9), abs=1e-4)
    assert mapped["algorithm.max_grad_norm"] == math.inf and mapped["runner.reward_scale"] == 1.0
    assert (mapped["algorithm.obs_normalization_form"], mapped["algorithm.obs_normalization_clip"]) == ("rl_games", 5.0)
    # 4096 envs x 16 steps in minibatches of 32768: 2 of them, 6 epochs, so 12 discriminator steps per rollout
    assert mapped["algorithm.num_mini_batches"] == 2 and mapped["amp.updates_per_rollout"] == 12
    use_ige_amp_recipe(cfg)  # a second call leaves the recipe as it is
    assert _flat(to_dict(cfg.train)) == mapped


def test_isaacgymenvs_amp_yaml_trains_and_evaluates_unchanged(tmp_path, run_args, capsys):
    """2 iterations at 2 envs and test mode from the checkpoint; one line says how the YAML trains and names the keys
    read but not used; the run's config.yaml holds the recipe it trained with."""
    args = [*IGE_AMP, "num_envs=2", *run_args]
    summary = run(compose_config([*args, "max_iterations=2"], config_dir=IGE_CFG))
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 16 * 2
    printed = capsys.readouterr().out
    assert "train.params.algo.name=amp_continuous (IsaacGymEnvs' AMP) trains with this project's AMP" in printed
    assert "disc_coef (the discriminator has an Adam optimiser of its own" in printed
    (run_dir,) = (tmp_path / "runs" / "HumanoidAMP").iterdir()
    saved = (run_dir / "config.yaml").read_text()
    assert "amp:" in saved and "params:" not in saved
    result = run(compose_config([*args, "test=True", f"checkpoint={run_dir / 'model_2.pt'}",
                                 "task.env.episodeLength_s=0.5"], config_dir=IGE_CFG))
    assert result["episodes"] == 2 and math.isfinite(result["amp_d_policy"])


@pytest.mark.parametrize(("overrides", "message"), [
    (["learner=rl_games"], r"learner=rl_games cannot train train.params.algo.name=amp_continuous"),
    (["+train.params.config.amp_horizon=4"], r"train.params.config.amp_horizon: not a key of an IsaacGymEnvs AMP"),
    (["train.params.network.space.continuous.fixed_sigma=False"],
     r"train.params.network.space.continuous.fixed_sigma=False is not supported with amp_continuous here"),
    (["train.params.config.mixed_precision=True"],
     r"train.params.config.mixed_precision=True is not supported with amp_continuous here: only False"),
    (["train.params.network.disc.activation=swish"], r"train.params.network.disc.activation='swish' is not"),
])
def test_what_the_mapping_cannot_honour_is_one_line(overrides, message):
    from isaacgymenvs_mw.learning.train_config import check_before_start

    with pytest.raises(ConfigError, match=message):
        check_before_start(compose_config([*IGE_AMP, "sim_device=cpu", "rl_device=cpu", *overrides],
                                          config_dir=IGE_CFG))
