"""Device strings: 'auto', 'cpu', 'cuda', 'cuda:N'. Validated before anything is allocated."""

from __future__ import annotations

import re

import torch

from isaacgymenvs_mw.utils.errors import ConfigError


def resolve_device(device: str, key: str = "sim_device") -> str:
    """Turn a user device string into 'cpu' or 'cuda:N', or fail naming the key and the valid choices."""
    device = str(device).strip().lower()
    n_gpu = torch.cuda.device_count() if torch.cuda.is_available() else 0
    valid = ["auto", "cpu"] + (["cuda"] + [f"cuda:{i}" for i in range(n_gpu)] if n_gpu else [])
    if device == "auto":
        return "cuda:0" if n_gpu else "cpu"
    if device == "cpu":
        return "cpu"
    match = re.fullmatch(r"(cuda|gpu)(?::(\d+))?", device)
    if match is None:
        raise ConfigError(f"{key}='{device}' is not a device string; valid choices here: {valid}")
    index = int(match.group(2) or 0)
    if index >= n_gpu:
        raise ConfigError(
            f"{key}='{device}' asks for a CUDA GPU but this machine has {n_gpu}; valid choices here: {valid}"
        )
    return f"cuda:{index}"


def check_device_pair(sim_device: str, rl_device: str) -> None:
    """The simulator and the learner may share a GPU, or the learner may sit on the CPU; two GPUs are not supported."""
    if sim_device.startswith("cuda") and rl_device.startswith("cuda") and sim_device != rl_device:
        raise ConfigError(
            f"sim_device='{sim_device}' and rl_device='{rl_device}' are different GPUs, which is not supported: "
            "use the same cuda:N for both (or rl_device=cpu)"
        )


def check_multi_gpu(multi_gpu: bool, world_size: int, local_rank: int) -> None:
    """Training across processes (multi_gpu=True, or torchrun starting ``world_size`` > 1 processes, which
    rsl-rl-lib's runner joins through NCCL) puts each process on its own GPU, cuda:LOCAL_RANK: fail naming what this
    machine lacks."""
    if not multi_gpu and world_size <= 1:
        return
    n_gpu = torch.cuda.device_count() if torch.cuda.is_available() else 0
    how = "multi_gpu=True" if multi_gpu else f"torchrun (WORLD_SIZE={world_size})"
    if n_gpu == 0:
        raise ConfigError(f"{how} needs one CUDA GPU per process, but torch sees none on this machine: train in one "
                          "process (python train.py, without torchrun and multi_gpu=True), e.g. on the CPU")
    if local_rank >= n_gpu:
        raise ConfigError(f"{how}: process LOCAL_RANK={local_rank} needs cuda:{local_rank} but this machine has "
                          f"{n_gpu} GPU(s): start at most {n_gpu} processes per machine (torchrun --nproc_per_node)")
