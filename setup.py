"""isaacgymenvs_mw: IsaacGymEnvs-style vectorised RL tasks on MuJoCo Warp."""

import re
from pathlib import Path

from setuptools import find_packages, setup

# The version lives in isaacgymenvs_mw/_version.py (read as text: setup.py must not import the package).
VERSION = re.search(r'__version__ = "([^"]+)"',
                    (Path(__file__).parent / "isaacgymenvs_mw" / "_version.py").read_text()).group(1)

# Pinned where a minor release can change simulator behaviour or the training API:
# mujoco / mujoco-warp / warp-lang move together (MJWarp 4.0 is built against warp 1.19),
# and rsl-rl-lib 5 is the config schema (separate actor/critic) that cfg/train/*.yaml uses.
INSTALL_REQUIRES = [
    "torch>=2.5",
    "warp-lang==1.19.0",
    "mujoco==4.0.0",
    "mujoco-warp==4.0.0",
    "rsl-rl-lib>=5.5,<6",
    "tensordict>=0.10",
    "hydra-core>=1.3,<1.4",
    "omegaconf>=2.3,<2.4",
    "tensorboard>=2.14",
    "gymnasium>=0.29",
    "numpy>=1.26",
    # capture_video: mp4 through the ffmpeg binary that imageio-ffmpeg's wheels ship
    "imageio>=2.30,<3",
    "imageio-ffmpeg>=0.5,<1",
    # a sweep (train.py -m) draws its jobs' learning curves as a PNG
    "matplotlib>=3.7",
]

RL_GAMES = "rl-games>=1.6.5,<1.7"

setup(
    name="isaacgymenvs_mw",
    version=VERSION,
    description="IsaacGymEnvs-style vectorised RL tasks (VecTask + YAML + train.py) on MuJoCo Warp",
    packages=find_packages(include=["isaacgymenvs_mw", "isaacgymenvs_mw.*"]),
    python_requires=">=3.10,<3.13",
    install_requires=INSTALL_REQUIRES,
    # rl_games: IsaacGymEnvs' learner, the second learner (learner=rl_games); 1.6.5 is the first release that installs
    # on Python 3.11 and 3.12 (earlier ones pin gym). onnxruntime: the exported-policy test.
    extras_require={"rl-games": [RL_GAMES],  # the spelling every pip accepts (PEP 685)
                    "test": ["pytest>=7", "onnxruntime>=1.17", RL_GAMES]},
    license="BSD-3-Clause",
)
