"""Policy and value models beside rsl-rl-lib's: image observations fed as uint8 (``ImageCNNModel``), and an actor-critic
whose hidden layers the policy and the value share (``SharedTrunkActor``, ``SharedTrunkCritic``).

Images: a task's image group ("camera") holds uint8 pixels so that rollout storage keeps one byte per pixel and channel
(float32 would take four). rsl-rl-lib's CNNs need floats, so each image group's CNN here first scales its input to
[0, 1] on the device (x / 255). The scaling sits inside the CNN modules, so training, ``share_cnn_encoders`` and the
exported ONNX / TorchScript policies all take the task's raw 0-255 images.

Train YAML: ``actor: {class_name: isaacgymenvs_mw.learning.models:ImageCNNModel, cnn_cfg: {...}, ...}``.

Two options of the image model speed its CNNs up on a GPU, both off unless a train YAML sets them (CartpoleCamera's
recipe sets both; docs/config.md):

* ``cnn_precision: bfloat16`` runs the convolutions under ``torch.autocast`` in bfloat16 (forward and backward; the
  MLP after the CNN stays float32). The pixels become bfloat16 directly (integers 0-255 are exact in bfloat16; the
  scaled value is rounded to bfloat16 as autocast would round the float32 one), sparing a float32 copy of the batch. The autocast cache is off, which CUDA graph
  capture asks for; the CNN's weights are a few thousand numbers, so casting them at each call costs nothing.
* ``cnn_channels_last: True`` hands the convolutions their input in channels-last memory order (NHWC), the order in
  which cuDNN's fastest convolution kernels read it. Only the input is reordered: the weights keep their layout, so
  the optimiser's flat gradient buffer and checkpoints are unchanged (cuDNN reorders the tiny weights by itself).

Exported policies (ONNX, TorchScript) run the CNNs in float32 and contiguous order whatever the options.
"""

from __future__ import annotations

import torch
import torch.nn as nn
from rsl_rl.models import CNNModel, MLPModel
from rsl_rl.utils import resolve_nn_activation, unpad_trajectories
from tensordict import TensorDict

from isaacgymenvs_mw.learning.train_config import CNN_PRECISIONS
from isaacgymenvs_mw.utils.config import boolean, one_of, whole_number
from isaacgymenvs_mw.utils.errors import ConfigError


_DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16}


class ByteImageEncoder(nn.Module):
    """A CNN whose input is 0-255 pixels (uint8 or float): ``cnn(x / 255)``, in ``precision`` (float32 or bfloat16
    under autocast) and optionally with its input in channels-last order. Its output is float32 either way."""

    def __init__(self, cnn: nn.Module, precision: str = CNN_PRECISIONS[0], channels_last: bool = False) -> None:
        super().__init__()
        self.cnn = cnn
        self.output_dim = cnn.output_dim
        self.output_channels = cnn.output_channels
        self.precision = precision
        self.channels_last = channels_last

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        dtype = _DTYPES[self.precision]
        layout = torch.channels_last if self.channels_last else torch.preserve_format
        pixels = x.to(dtype=dtype, memory_format=layout) * (1.0 / 255.0)  # one copy: cast and reorder together
        if dtype == torch.float32:
            return self.cnn(pixels)
        with torch.autocast(device_type=x.device.type, dtype=dtype, cache_enabled=False):
            return self.cnn(pixels).float()


class ImageCNNModel(CNNModel):
    """``rsl_rl.models.CNNModel`` whose image groups are 0-255 pixels; its arguments plus ``cnn_precision``
    (``float32`` or ``bfloat16``), ``cnn_channels_last`` (train YAML ``<actor|critic>.cnn_*``) and ``aux_target``.

    ``aux_target`` (train YAML ``actor.aux_target``, default None: no head): ``{group: <env obs group>, hidden_dims:
    [64], activation: elu}`` adds an auxiliary head, an MLP on the CNN features (the image encoders' outputs
    concatenated, before the flat groups join them) that predicts the named observation group of the env (e.g.
    ``critic``, the cube's pose), as Isaac Lab's vision ShadowHand regresses the cube's keypoints from its images
    (isaac-sim/IsaacLab, source/isaaclab_tasks/isaaclab_tasks/direct/shadow_hand/feature_extractor.py). Its loss
    (``aux_loss``: mean squared error against the group's raw values, the target detached) is added to PPO's by
    ``SyncFreePPO`` with ``algorithm.aux_loss_coef``, so the encoders also learn features that locate the object.

    The head is no part of the policy: the action never reads it and the exported policies (``as_jit``,
    ``as_onnx``) copy the encoders, the normaliser and the MLP only. Its weights are in the checkpoint's
    ``actor_state_dict``, so a checkpoint loads into a model built with the same ``aux_target``.

    Features: each forward keeps its CNN features with what they were computed from (as ``SharedTrunkActor`` keeps
    its trunk's), and ``aux_loss`` on that very observation object, its image tensors unchanged and in the same grad
    mode, takes them instead of running the encoders again, so that a PPO mini-batch runs the encoders once and the
    gradient of both losses reaches them in one backward pass. Any other call (another observation, tensors written
    in place since, features computed without grad) runs the encoders itself.
    """

    aux_head: nn.Module | None
    aux_group: str | None
    _handover: _TrunkFeatures | None = None  # the last forward's CNN features, while the head is there

    def __init__(self, obs: TensorDict, obs_groups: dict[str, list[str]], obs_set: str, *args,
                 cnn_precision: str = CNN_PRECISIONS[0], cnn_channels_last: bool = False,
                 aux_target: dict | None = None, **kwargs) -> None:
        precision = one_of(cnn_precision, f"train.{obs_set}.cnn_precision", CNN_PRECISIONS)
        channels_last = boolean(cnn_channels_last, f"train.{obs_set}.cnn_channels_last")
        super().__init__(obs, obs_groups, obs_set, *args, **kwargs)
        for group, cnn in list(self.cnns.items()):
            if not isinstance(cnn, ByteImageEncoder):  # CNNs shared with another model come wrapped already
                self.cnns[group] = ByteImageEncoder(cnn, precision, channels_last)
        self.aux_group, self.aux_head = None, None
        if aux_target is not None:
            self.aux_group, self.aux_head = _aux_head(aux_target, obs, self.cnn_latent_dim, f"train.{obs_set}")

    def get_latent(self, obs: TensorDict, masks: torch.Tensor | None = None, hidden_state=None) -> torch.Tensor:
        """``CNNModel``'s latent (the flat groups, normalised, then the CNN features), keeping the CNN features for
        ``aux_loss`` when the model has the head."""
        features = self.cnn_features(obs)
        if self.aux_head is not None:
            self._handover = _TrunkFeatures(obs, [obs[group] for group in self.obs_groups_2d], features)
        if not self.obs_groups:
            return features
        return torch.cat([MLPModel.get_latent(self, obs), features], dim=-1)

    def cnn_features(self, obs: TensorDict) -> torch.Tensor:
        """The image encoders' outputs, concatenated in the order of the image groups."""
        return torch.cat([self.cnns[group](obs[group]) for group in self.obs_groups_2d], dim=-1)

    def aux_prediction(self, obs: TensorDict) -> torch.Tensor:
        """The head's prediction of the ``aux_target`` group from ``obs``'s images (the last forward's features when
        it read ``obs`` itself, else the encoders run here)."""
        if self.aux_head is None:
            raise ConfigError("this model has no auxiliary head: give train.actor.aux_target, e.g. {group: critic}")
        held, self._handover = self._handover, None
        fresh = held is None or not held.read(obs, self.obs_groups_2d)
        return self.aux_head(self.cnn_features(obs) if fresh else held.features)

    def aux_loss(self, obs: TensorDict, masks: torch.Tensor | None = None) -> torch.Tensor:
        """Mean squared error of the head's prediction against ``obs[aux_group]`` (raw values, no gradient to the
        target), over samples and values, in float32. ``masks``: a recurrent learner's padded batch, unpadded as the
        forward unpads it (the encoders then run again: the unpadded batch is a new object)."""
        obs = unpad_trajectories(obs, masks) if masks is not None else obs
        prediction = self.aux_prediction(obs).float()
        target = obs[self.aux_group].detach().float()  # type: ignore[index]
        return (prediction - target).square().mean()

    def as_jit(self) -> nn.Module:
        return _plain_encoders(super().as_jit())

    def as_onnx(self, verbose: bool = False) -> nn.Module:
        return _plain_encoders(super().as_onnx(verbose))


AUX_TARGET_KEYS = ("group", "hidden_dims", "activation")


def _aux_head(spec, obs: TensorDict, input_dim: int, section: str) -> tuple[str, nn.Module]:
    """``aux_target``'s group and head (Linear + activation per hidden layer, then a Linear to the group's size),
    checked against the observations; bad values fail naming ``<section>.aux_target.<key>``."""
    key = f"{section}.aux_target"
    if not isinstance(spec, dict) or "group" not in spec:
        raise ConfigError(f"{key}={spec!r} is invalid: give {{group: <observation group>, hidden_dims: [64]}}")
    unknown = sorted(set(spec) - set(AUX_TARGET_KEYS))
    if unknown:
        raise ConfigError(f"{key}.{unknown[0]} is not a key of {key}; valid: {list(AUX_TARGET_KEYS)}")
    group = spec["group"]
    flat = [name for name in obs.keys() if obs[name].dim() == 2]
    if group not in flat:
        raise ConfigError(f"{key}.group={group!r} is invalid: choose one of the flat observation groups {flat}")
    dims = spec.get("hidden_dims", [64])
    if not isinstance(dims, (list, tuple)):
        raise ConfigError(f"{key}.hidden_dims={dims!r} is invalid: give a list of layer sizes, e.g. [64]")
    dims = [whole_number(d, f"{key}.hidden_dims", 1) for d in dims]
    activation = spec.get("activation", "elu")
    try:
        resolve_nn_activation(activation)
    except (ValueError, AttributeError) as error:
        raise ConfigError(f"{key}.activation={activation!r} is invalid: {error}") from None
    layers: list[nn.Module] = []
    for size in dims:
        layers += [nn.Linear(input_dim, size), resolve_nn_activation(activation)]
        input_dim = size
    layers.append(nn.Linear(input_dim, obs[group].shape[-1]))
    return group, nn.Sequential(*layers)


def _plain_encoders(exported: nn.Module) -> nn.Module:
    """An export's copies of the encoders in float32 and contiguous order (what a deployment runtime runs), as a
    module TorchScript can compile (it cannot compile the options' autocast)."""
    for i, encoder in enumerate(exported.cnns):
        exported.cnns[i] = _ExportedImageEncoder(encoder.cnn)
    return exported


class _ExportedImageEncoder(nn.Module):
    """``ByteImageEncoder`` with its defaults, for exported policies: ``cnn(x / 255)`` in float32."""

    def __init__(self, cnn: nn.Module) -> None:
        super().__init__()
        self.cnn = cnn

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.cnn(x.float() * (1.0 / 255.0))


class SharedTrunkActor(MLPModel):
    """The policy of rl_games' shared actor-critic: rsl-rl-lib's ``MLPModel``, the same modules and outputs, computed
    as its trunk (the normaliser and every layer of its MLP but the last) then its last layer (the mean head).

    Its forward keeps the trunk's features for the value head (``SharedTrunkCritic``), which takes them when it is
    called next on the very same observation, so that PPO's pairs of calls (the rollout's act: actions then values;
    each mini-batch: the policy then the value) run the trunk once. The handover is host-side bookkeeping only (object
    identities), so a captured update records one trunk pass and no host read. Built in place of ``MLPModel`` by
    ``SyncFreePPO.construct_algorithm`` with ``algorithm.share_trunk``; checkpoints and exports are ``MLPModel``'s.
    """

    _handover: _TrunkFeatures | None = None  # the last forward's features until the value head takes them

    def forward(self, obs: TensorDict, masks: torch.Tensor | None = None, hidden_state=None,
                stochastic_output: bool = False) -> torch.Tensor:
        obs = unpad_trajectories(obs, masks) if masks is not None else obs
        features = self.trunk(obs)
        self._handover = _TrunkFeatures(obs, [obs[group] for group in self.obs_groups], features)
        mlp_output = self.mlp[-1](features)
        if self.distribution is None:
            return mlp_output
        if stochastic_output:
            self.distribution.update(mlp_output)
            return self.distribution.sample()
        return self.distribution.deterministic_output(mlp_output)

    def trunk(self, obs: TensorDict) -> torch.Tensor:
        """The trunk's features: the normalised input through every layer of the MLP but the last."""
        features = self.get_latent(obs)
        for layer in list(self.mlp)[:-1]:
            features = layer(features)
        return features

    def take_features(self, obs: TensorDict) -> torch.Tensor | None:
        """The features of the last forward if it read ``obs`` itself, else None; each forward's are handed over once.

        Once: a later call on the same object (the rollout's next observation written in place, or a second value
        of one batch) gets None and runs the trunk again. ``_TrunkFeatures.read`` says what else must match."""
        held, self._handover = self._handover, None
        return held.features if held is not None and held.read(obs, self.obs_groups) else None


class _TrunkFeatures:
    """A forward's trunk features and what they were computed from: the observation object, the group tensors it
    held, their in-place write counters (tensors made under ``torch.inference_mode`` keep none) and the grad mode."""

    def __init__(self, obs: TensorDict, inputs: list[torch.Tensor], features: torch.Tensor) -> None:
        self.obs, self.inputs, self.features = obs, inputs, features
        self.versions = _versions(inputs)
        self.grad = torch.is_grad_enabled()

    def read(self, obs: TensorDict, groups: list[str]) -> bool:
        """Whether these features are the trunk's of ``obs`` as it is now, for a caller in the current grad mode (a
        value whose loss needs the trunk's gradient must not take features computed without one)."""
        if obs is not self.obs or self.grad != torch.is_grad_enabled():
            return False
        inputs = [obs[group] for group in groups]
        return all(a is b for a, b in zip(inputs, self.inputs)) and _versions(inputs) == self.versions


def _versions(tensors: list[torch.Tensor]) -> list[int | None]:
    return [None if t.is_inference() else t._version for t in tensors]


class SharedTrunkCritic(nn.Module):
    """The value of rl_games' shared actor-critic (``separate: False``): one MLP trunk, a linear head for the action
    means and a linear head for the value, the std a free parameter, one observation normaliser.

    Built on the actor (a ``SharedTrunkActor``, rsl-rl-lib's ``MLPModel`` with a state-independent Gaussian): its
    normaliser and its MLP's hidden layers are the trunk, its MLP's last linear layer the mean head; this module adds
    the value head. The actor is held, not registered, so the trunk's parameters and statistics stay the actor's
    alone: the optimiser sees each once, the checkpoint's ``actor_state_dict`` holds the whole policy (test mode and
    the exporter use it unchanged) and ``critic_state_dict`` the value head.

    The trunk runs once per observation: called on the observation that the actor's forward has just read (the
    rollout's act, each PPO mini-batch), the value head takes that forward's features (``take_features``), so the
    loss's gradient reaches the trunk through both heads in one backward pass, as in rl_games' single network; called
    alone (the bootstrap value of ``compute_returns``), it runs the actor's trunk itself.

    Train YAML: ``algorithm.share_trunk: True`` (``SyncFreePPO.construct_algorithm`` builds it; the ``critic``
    section is then not read).
    """

    is_recurrent: bool = False

    def __init__(self, actor: MLPModel) -> None:
        super().__init__()
        head = actor.mlp[-1] if isinstance(actor, SharedTrunkActor) else None
        if not isinstance(head, nn.Linear):
            raise ConfigError("train.algorithm.share_trunk=True needs train.actor.class_name=MLPModel with a "
                              "state-independent Gaussian (train.actor.distribution_cfg), got "
                              f"{type(actor).__name__}")
        object.__setattr__(self, "_actor", actor)  # a plain attribute: not a submodule, its parameters not ours
        self.value_head = nn.Linear(head.in_features, 1)

    def forward(self, obs: TensorDict, masks: torch.Tensor | None = None, hidden_state=None) -> torch.Tensor:
        if masks is not None:  # padded for a recurrent learner's batches; a shared trunk is feed-forward
            obs = unpad_trajectories(obs, masks)
        features = self._actor.take_features(obs)
        return self.value_head(self._actor.trunk(obs) if features is None else features)

    # What PPO asks of a critic; the observation statistics are the actor's, updated once, by the actor.
    def update_normalization(self, obs: TensorDict) -> None:
        pass

    def reset(self, dones: torch.Tensor | None = None, hidden_state=None) -> None:
        pass

    def get_hidden_state(self) -> None:
        return None

    def detach_hidden_state(self, dones: torch.Tensor | None = None) -> None:
        pass
