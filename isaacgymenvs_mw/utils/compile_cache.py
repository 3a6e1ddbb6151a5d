"""One folder for every compile cache a run reads and writes, so that a warmed-up set of caches can be shipped.

``ISAACGYMENVS_MW_CACHE=/path`` puts each cache a run compiles into under ``/path``:

    warp/       Warp's kernel modules (WARP_CACHE_PATH)
    inductor/   torch.compile's Inductor code for the step (TORCHINDUCTOR_CACHE_DIR)
    triton/     Inductor's Triton GPU kernels (TRITON_CACHE_DIR)
    cuda/       the CUDA driver's JIT cache (CUDA_CACHE_PATH): where Warp hands the driver PTX (a driver newer than
                Warp's toolkit), the driver compiles it to the GPU's code and keeps that here

``python -m isaacgymenvs_mw.warmup`` with the variable set fills the folder; a copy of it on another machine with the
same GPU architecture, Python packages and task overrides, with the variable pointing at the copy, starts without
compiling (docs/config.md, "A cache to ship"). Warp, Inductor and Triton name their entries after content hashes, but
Triton's entries also hold absolute paths: each kernel's folder has a group file (``__grp__<kernel>.json``) that lists
the kernel's files by absolute path, and Triton takes a listed file that is not there as a cache miss and compiles the
kernel again (``FileCacheManager.get_group``, triton-lang/triton python/triton/runtime/cache.py). Inductor's cache
holds the same kernels, but where a kernel's folder exists it leaves the folder as it is
(``TritonBundler.read_and_emit``, pytorch/pytorch torch/_inductor/triton_bundler.py). So, in a folder that was moved,
the step's graph is read back from Inductor's cache, but each of its kernels that Inductor does not launch itself (it
finds the binaries of those it does by the cache folder, not by the group file) goes through Triton and is compiled
again; ``use_cache_folder`` therefore points each group file at the files beside it.

A variable of one cache that is set explicitly keeps its folder, so that a cluster's own layout wins. Only the standard
library is imported: this runs before torch and Warp are, which read the variables when they first compile.
"""

from __future__ import annotations

import contextlib
import json
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
    relocate_triton_groups(env["TRITON_CACHE_DIR"])
    return root


def relocate_triton_groups(folder: str) -> int:
    """Point every Triton group file in ``folder`` (a ``TRITON_CACHE_DIR``) at the files beside it, where it names
    them somewhere else; returns how many group files were rewritten. A group file that cannot be read or rewritten
    (another process writing it, a read-only copy) is left as it is: Triton then compiles that kernel again."""
    rewritten = 0
    try:
        kernels = [entry.path for entry in os.scandir(folder) if entry.is_dir()]
    except OSError:
        return 0
    for kernel in kernels:
        try:
            groups = [entry.path for entry in os.scandir(kernel) if entry.name.startswith("__grp__")
                      and entry.name.endswith(".json") and entry.is_file()]
        except OSError:
            continue
        for group in groups:
            rewritten += _relocate_group(group)
    return rewritten


def _relocate_group(group: str) -> int:
    """1 where the group file ``group`` was rewritten to name the files of its own folder, else 0."""
    try:
        with open(group) as file:
            data = json.load(file)
    except (OSError, ValueError):
        return 0
    children = data.get("child_paths") if isinstance(data, dict) else None
    if not isinstance(children, dict) or not all(isinstance(p, str) for p in children.values()):
        return 0
    folder = os.path.dirname(group)
    here = {name: os.path.join(folder, os.path.basename(path)) for name, path in children.items()}
    if here == children or not all(os.path.isfile(path) for path in here.values()):
        return 0
    # Written beside it and renamed over it, so that a Triton reading it meanwhile sees the old or the new file.
    temporary = f"{group}.{os.getpid()}.tmp"
    try:
        with open(temporary, "w") as file:
            json.dump({**data, "child_paths": here}, file)
        os.replace(temporary, group)
    except OSError:
        with contextlib.suppress(OSError):
            os.remove(temporary)
        return 0
    return 1
