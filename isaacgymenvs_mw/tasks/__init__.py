"""The task map: task name -> VecTask subclass.

Register your own task without editing this package::

    from isaacgymenvs_mw.tasks import register_task
    register_task("MyTask", MyTask)           # or use @register_task("MyTask") on the class

and point train.py at your module with ``task_module=my_package.my_tasks`` (imported before the task is built),
plus ``cfg/task/MyTask.yaml`` and ``cfg/train/MyTaskPPO.yaml``.
"""

from __future__ import annotations

from isaacgymenvs_mw.tasks.allegro_hand import AllegroHand
from isaacgymenvs_mw.tasks.allegro_kuka import AllegroKuka
from isaacgymenvs_mw.tasks.allegro_kuka_subtasks import (
    AllegroKukaRegrasping,
    AllegroKukaThrow,
)
from isaacgymenvs_mw.tasks.ant import Ant
from isaacgymenvs_mw.tasks.anymal import Anymal
from isaacgymenvs_mw.tasks.ball_balance import BallBalance
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.tasks.cartpole import Cartpole
from isaacgymenvs_mw.tasks.cartpole_camera import CartpoleCamera
from isaacgymenvs_mw.tasks.franka_cabinet import FrankaCabinet
from isaacgymenvs_mw.tasks.franka_cube_lift import (
    FrankaCubeLift,
    FrankaCubeLiftDepth,
    FrankaCubeLiftRGB,
)
from isaacgymenvs_mw.tasks.franka_cube_stack import FrankaCubeStack
from isaacgymenvs_mw.tasks.g1 import G1
from isaacgymenvs_mw.tasks.go1 import Go1
from isaacgymenvs_mw.tasks.humanoid import Humanoid
from isaacgymenvs_mw.tasks.humanoid_amp import HumanoidAMP
from isaacgymenvs_mw.tasks.ingenuity import Ingenuity
from isaacgymenvs_mw.tasks.quadcopter import Quadcopter
from isaacgymenvs_mw.tasks.shadow_hand import ShadowHand
from isaacgymenvs_mw.tasks.trifinger import Trifinger
from isaacgymenvs_mw.utils.errors import UnknownNameError

isaacgym_task_map: dict[str, type[VecTask]] = {
    "AllegroHand": AllegroHand,
    "AllegroKuka": AllegroKuka,
    "AllegroKukaRegrasping": AllegroKukaRegrasping,  # IGE: task AllegroKuka, subtask regrasping (its class name)
    "AllegroKukaThrow": AllegroKukaThrow,  # IGE: task AllegroKuka, subtask throw (its class name)
    "Ant": Ant,
    "Anymal": Anymal,
    "AnymalTerrain": Anymal,  # same class; cfg/task/AnymalTerrain.yaml adds env.terrain
    "BallBalance": BallBalance,
    "Cartpole": Cartpole,
    "CartpoleCamera": CartpoleCamera,
    "CartpoleCameraDepth": CartpoleCamera,  # same class; cfg/task/CartpoleCameraDepth.yaml observes depth
    "FrankaCabinet": FrankaCabinet,
    "FrankaCubeLift": FrankaCubeLift,
    "FrankaCubeLiftDepth": FrankaCubeLiftDepth,
    "FrankaCubeLiftRGB": FrankaCubeLiftRGB,
    "FrankaCubeStack": FrankaCubeStack,
    "FrankaCubeStackIGE": FrankaCubeStack,  # same class; cfg/task/FrankaCubeStackIGE.yaml: IsaacGymEnvs' reward
    "G1": G1,
    "G1Terrain": G1,  # same class; cfg/task/G1Terrain.yaml adds env.terrain
    "Go1": Go1,
    "Go1Terrain": Go1,
    "Humanoid": Humanoid,
    "HumanoidAMP": HumanoidAMP,
    "Ingenuity": Ingenuity,
    "Quadcopter": Quadcopter,
    "ShadowHand": ShadowHand,
    "ShadowHandOpenAI_FF": ShadowHand,  # same class; cfg/task/ShadowHandOpenAI_FF.yaml: OpenAI's setting
    "Trifinger": Trifinger,
}


def register_task(name: str, task_class: type[VecTask] | None = None):
    """Add a task class under ``name``; usable as a call or as a class decorator."""

    def add(cls: type[VecTask]) -> type[VecTask]:
        if not (isinstance(cls, type) and issubclass(cls, VecTask)):
            raise TypeError(f"register_task('{name}'): {cls!r} is not a VecTask subclass")
        isaacgym_task_map[name] = cls
        return cls

    return add(task_class) if task_class is not None else add


def get_task_class(name: str) -> type[VecTask]:
    if name not in isaacgym_task_map:
        raise UnknownNameError(f"task.name={name!r} is not a registered task: give one of {sorted(isaacgym_task_map)}, "
                               "or import the module that registers it with task_module=<module>")
    return isaacgym_task_map[name]


__all__ = ["VecTask", "get_task_class", "isaacgym_task_map", "register_task"]
