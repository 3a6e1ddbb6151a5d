"""Training glue: the rsl_rl VecEnv adapter, the runner, and the train/test entry used by train.py."""
