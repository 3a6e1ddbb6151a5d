# Sourced by rounds that give a task the hands' rl_games settings as overrides (cfg/train/AllegroHandPPO.yaml ships
# them): the KL measured once per epoch in rl_games' form, one global gradient clip, rl_games' input normaliser with
# its +-5 clamp, its learning-rate floor, a shared trunk and std = exp(a free parameter). A task whose recipe lacks
# value normalisation adds +train.algorithm.normalize_value=True itself.
# shellcheck disable=SC2034  # read by the sourcing round
RL_GAMES_FORM="+train.algorithm.kl_schedule=per_epoch +train.algorithm.kl_form=rl_games \
+train.algorithm.grad_clip_scope=global +train.algorithm.obs_normalization_clip=5.0 \
+train.algorithm.learning_rate_min=1e-6 +train.algorithm.share_trunk=True \
+train.algorithm.obs_normalization_form=rl_games train.actor.distribution_cfg.std_type=log"
