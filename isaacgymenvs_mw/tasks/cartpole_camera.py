"""CartpoleCamera: Cartpole from pixels. The policy sees only camera images; the critic reads the state.

The problem is Cartpole's (tasks/cartpole.py: the same reward, resets and failure); what changes is what the policy
observes: the images of camera ``front`` (``env.cameras.front``) named by ``env.imageOutputs`` (rgb and/or depth),
with the frames before them (``env.history.camera``) so that speeds can be told from pixels. The flat observation,
cart and pole positions and velocities, remains the task's ``obs_buf``: the train YAML gives it to the critic
(``obs_groups: {actor: [camera], critic: [policy]}``).
"""

from __future__ import annotations

from isaacgymenvs_mw.tasks.base.observations import ImageTerm
from isaacgymenvs_mw.tasks.cartpole import Cartpole

CAMERA = "front"


class CartpoleCamera(Cartpole):
    """Cartpole whose policy observes ``env.imageOutputs`` of camera ``front``."""

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        self.image_outputs = list(cfg["env"].get("imageOutputs", ["rgb"]))
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)

    def image_terms(self) -> list[ImageTerm]:
        return [ImageTerm(output, camera=CAMERA, output=output) for output in self.image_outputs]
