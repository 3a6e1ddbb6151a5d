"""CartpoleCamera: Cartpole from pixels. The policy sees only camera images; the critic reads the state.

The problem is Cartpole's (tasks/cartpole.py: the same reward, resets and failure); what changes is what the policy
observes: the images its camera renders (``env.cameras``: CartpoleCamera's ``front`` renders rgb, CartpoleCameraDepth's
depth), with the frames before them (``env.history.camera``) so that speeds can be told from pixels. The flat
observation, cart and pole positions and velocities, remains the task's ``obs_buf``: the train YAML gives it to the
critic (``obs_groups: {actor: [camera], critic: [policy]}``).
"""

from __future__ import annotations

from isaacgymenvs_mw.tasks.base.observation_terms import ImageTerm, camera_terms
from isaacgymenvs_mw.tasks.cartpole import Cartpole


class CartpoleCamera(Cartpole):
    """Cartpole whose policy observes what its ``env.cameras`` render."""

    def image_terms(self) -> list[ImageTerm]:
        return camera_terms(self.sim.cameras)
