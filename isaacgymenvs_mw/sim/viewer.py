"""MuJoCo's interactive viewer on world 0, fed from the device state at a bounded frame rate."""

from __future__ import annotations

import os
import sys
import time

import mujoco

from isaacgymenvs_mw.sim.simulator import Simulator


class WorldViewer:
    """Mirrors world 0 into a host MjData and shows it; copies at most ``max_fps`` times a second.

    Each copy reads world 0's state back from the device (a sync), which is why it is rate-limited: at 30 fps the
    cost is 30 small transfers per second, whatever the training speed.
    """

    def __init__(self, sim: Simulator, handle, max_fps: float = 30.0) -> None:
        self.sim = sim
        self.handle = handle
        self.host_data = mujoco.MjData(sim.mj_model)
        self.min_interval = 1.0 / max_fps
        self._last = 0.0

    def sync(self, control_dt: float) -> bool:
        """Refresh the window if a frame is due; False once the user has closed it."""
        if not self.handle.is_running():
            return False
        now = time.perf_counter()
        if now - self._last < self.min_interval:
            return True
        self._last = now
        self.host_data.qpos[:] = self.sim.qpos[0].detach().cpu().numpy()
        self.host_data.qvel[:] = self.sim.qvel[0].detach().cpu().numpy()
        mujoco.mj_forward(self.sim.mj_model, self.host_data)
        self.handle.sync()
        return True

    def close(self) -> None:
        self.handle.close()


def open_viewer(sim: Simulator) -> WorldViewer | None:
    """A viewer on world 0, or None (with one message) where no display is available."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        print("[isaacgymenvs_mw] headless=False but no display was found: running headless.", flush=True)
        return None
    try:
        import mujoco.viewer

        handle = mujoco.viewer.launch_passive(sim.mj_model, mujoco.MjData(sim.mj_model))
    except Exception as err:  # GLFW missing, display refused, ...
        print(f"[isaacgymenvs_mw] could not open MuJoCo's viewer ({err}): running headless.", flush=True)
        return None
    return WorldViewer(sim, handle)
