"""One folder for every compile cache a run reads and writes, so that a warmed-up set of caches can be shipped.

``ISAACGYMENVS_MW_CACHE=/path`` puts each cache a run compiles into under ``/path``:

    warp/       Warp's kernel modules (WARP_CACHE_PATH)
    inductor/   torch.compile's Inductor code for the step (TORCHINDUCTOR_CACHE_DIR)
    triton/     Inductor's Triton GPU kernels (TRITON_CACHE_DIR)
    cuda/       the CUDA driver's JIT cache (CUDA_CACHE_PATH): where Warp hands the driver PTX (a driver newer than
                Warp's toolkit), the driver compiles it to the GPU's code and keeps that here

``python -m isaacgymenvs_mw.warmup`` with the variable set fills the folder; a copy of it on another machine with the
same GPU architecture, Python packages and task overrides, with the variable pointing at the copy, starts without
compiling (docs/config.md, "A cache to ship"). None of these caches holds an absolute path to itself: Warp, Inductor
and Triton name their entries after content hashes.

A variable of one cache that is set explicitly keeps its folder, so that a cluster's own layout wins. Only the standard
library is imported: this runs before torch and Warp are, which read the variables when they first compile.
"""

from __future__ import annotations

import os

VARIABLE = "ISAACGYMENVS_MW_CACHE"
# The cache variable of each library -> its subfolder of the shipped folder.
SUBFOLDERS = {"WARP_CACHE_PATH": "warp", "TORCHINDUCTOR_CACHE_DIR": "inductor", "TRITON_CACHE_DIR": "triton",
              "CUDA_CACHE_PATH": "cuda"}
# The driver's JIT cache holds 256 MiB by default and drops the oldest entries beyond it; 4 GiB is its largest size
# (CUDA's documentation, "CUDA Environment Variables"), so that every module of several tasks stays.
CUDA_CACHE_MAXSIZE = str(4 * 1024**3)


def use_cache_folder(environ: dict[str, str] | None = None) -> str | None:
    """Point the compile caches into the folder ``ISAACGYMENVS_MW_CACHE`` names (made if missing); returns the folder,
    or None where the variable is not set (each library then keeps its own default folder)."""
    env = os.environ if environ is None else environ
    root = env.get(VARIABLE, "").strip()
    if not root:
        return None
    root = os.path.abspath(os.path.expanduser(root))
    for variable, subfolder in SUBFOLDERS.items():
        if not env.get(variable):
            env[variable] = os.path.join(root, subfolder)
        os.makedirs(env[variable], exist_ok=True)
    env.setdefault("CUDA_CACHE_MAXSIZE", CUDA_CACHE_MAXSIZE)
    return root
