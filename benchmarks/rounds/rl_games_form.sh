# Sourced by rounds that give a task the hands' rl_games settings as overrides (cfg/train/AllegroHandPPO.yaml ships
# them). RL_GAMES_STEERING: the KL measured once per epoch in rl_games' form, one global gradient clip, its
# learning-rate floor, the normalised observations clamped to +-5 and std = exp(a free parameter); any actor takes
# them. RL_GAMES_FORM adds the shared trunk and rl_games' input normaliser (an MLP actor whose critic reads the
# policy's observation). A task whose recipe lacks value normalisation adds +train.algorithm.normalize_value=True.
# shellcheck disable=SC2034  # read by the sourcing round
RL_GAMES_STEERING="+train.algorithm.kl_schedule=per_epoch +train.algorithm.kl_form=rl_games \
+train.algorithm.grad_clip_scope=global +train.algorithm.obs_normalization_clip=5.0 \
+train.algorithm.learning_rate_min=1e-6 train.actor.distribution_cfg.std_type=log"
RL_GAMES_FORM="$RL_GAMES_STEERING +train.algorithm.share_trunk=True +train.algorithm.obs_normalization_form=rl_games"
