from __future__ import annotations

import os
import random

import numpy as np
import torch


def set_seed(seed: int, torch_deterministic: bool = False, rank: int = 0) -> int:
    """Seed python, numpy and torch; -1 picks a random seed (42 when deterministic). Returns the seed used."""
    if seed == -1:
        seed = 42 if torch_deterministic else int(np.random.randint(0, 10000))
    seed = int(seed) + int(rank)
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    os.environ["PYTHONHASHSEED"] = str(seed)
    if torch_deterministic:
        os.environ["CUBLAS_WORKSPACE_CONFIG"] = ":4096:8"
        torch.backends.cudnn.benchmark = False
        torch.backends.cudnn.deterministic = True
        torch.use_deterministic_algorithms(True)
    else:
        # cuDNN times its convolution algorithms once per input shape and keeps the fastest: the image models'
        # shapes never change within a run. (Deterministic mode cannot: the fastest one may not be reproducible.)
        torch.backends.cudnn.benchmark = True
    return seed
