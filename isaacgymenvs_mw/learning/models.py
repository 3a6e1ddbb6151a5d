"""Policy and value models beside rsl-rl-lib's: image observations fed as uint8 (``ImageCNNModel``), and the value head
of an actor-critic whose hidden layers the policy and the value share (``SharedTrunkCritic``).

Images: a task's image group ("camera") holds uint8 pixels so that rollout storage keeps one byte per pixel and channel
(float32 would take four). rsl-rl-lib's CNNs need floats, so each image group's CNN here first scales its input to
[0, 1] on the device (x / 255). The scaling sits inside the CNN modules, so training, ``share_cnn_encoders`` and the
exported ONNX / TorchScript policies all take the task's raw 0-255 images.

Train YAML: ``actor: {class_name: isaacgymenvs_mw.learning.models:ImageCNNModel, cnn_cfg: {...}, ...}``.
"""

from __future__ import annotations

import torch
import torch.nn as nn
from rsl_rl.models import CNNModel, MLPModel
from rsl_rl.utils import unpad_trajectories
from tensordict import TensorDict

from isaacgymenvs_mw.utils.errors import ConfigError


class ByteImageEncoder(nn.Module):
    """A CNN whose input is 0-255 pixels (uint8 or float): ``cnn(x / 255)``."""

    def __init__(self, cnn: nn.Module) -> None:
        super().__init__()
        self.cnn = cnn
        self.output_dim = cnn.output_dim
        self.output_channels = cnn.output_channels

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.cnn(x.float() * (1.0 / 255.0))


class ImageCNNModel(CNNModel):
    """``rsl_rl.models.CNNModel`` whose image groups are 0-255 pixels; same arguments."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        for group, cnn in list(self.cnns.items()):
            if not isinstance(cnn, ByteImageEncoder):  # CNNs shared with another model come wrapped already
                self.cnns[group] = ByteImageEncoder(cnn)


class SharedTrunkCritic(nn.Module):
    """The value of rl_games' shared actor-critic (``separate: False``): one MLP trunk, a linear head for the action
    means and a linear head for the value, the std a free parameter, one observation normaliser.

    Built on the actor (an ``MLPModel`` with a state-independent Gaussian): its normaliser and its MLP's hidden layers
    are the trunk, its MLP's last linear layer the mean head; this module adds the value head. The actor is held, not
    registered, so the trunk's parameters and statistics stay the actor's alone: the optimiser sees each once, the
    checkpoint's ``actor_state_dict`` holds the whole policy (test mode and the exporter use it unchanged) and
    ``critic_state_dict`` the value head. The trunk runs once in the policy's forward and once here; the gradient
    is the same as rl_games' single pass (the sum of both losses' paths through the trunk).

    Train YAML: ``algorithm.share_trunk: True`` (``SyncFreePPO.construct_algorithm`` builds it; the ``critic``
    section is then not read).
    """

    is_recurrent: bool = False

    def __init__(self, actor: MLPModel) -> None:
        super().__init__()
        head = actor.mlp[-1] if type(actor) is MLPModel else None
        if not isinstance(head, nn.Linear):
            raise ConfigError("train.algorithm.share_trunk=True needs train.actor.class_name=MLPModel with a "
                              "state-independent Gaussian (train.actor.distribution_cfg), got "
                              f"{type(actor).__name__}")
        object.__setattr__(self, "_actor", actor)  # a plain attribute: not a submodule, its parameters not ours
        self.value_head = nn.Linear(head.in_features, 1)

    def trunk(self, obs: TensorDict) -> torch.Tensor:
        """The trunk's features: the actor's normalised input through every layer of its MLP but the last."""
        actor = self._actor
        features = actor.get_latent(obs)
        for layer in list(actor.mlp)[:-1]:
            features = layer(features)
        return features

    def forward(self, obs: TensorDict, masks: torch.Tensor | None = None, hidden_state=None) -> torch.Tensor:
        if masks is not None:  # padded for a recurrent learner's batches; a shared trunk is feed-forward
            obs = unpad_trajectories(obs, masks)
        return self.value_head(self.trunk(obs))

    # What PPO asks of a critic; the observation statistics are the actor's, updated once, by the actor.
    def update_normalization(self, obs: TensorDict) -> None:
        pass

    def reset(self, dones: torch.Tensor | None = None, hidden_state=None) -> None:
        pass

    def get_hidden_state(self) -> None:
        return None

    def detach_hidden_state(self, dones: torch.Tensor | None = None) -> None:
        pass
