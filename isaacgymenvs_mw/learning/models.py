"""Policy and value models for image observations: rsl-rl-lib's ``CNNModel`` fed with uint8 images.

A task's image group ("camera") holds uint8 pixels so that rollout storage keeps one byte per pixel and channel
(float32 would take four). rsl-rl-lib's CNNs need floats, so each image group's CNN here first scales its input to
[0, 1] on the device (x / 255). The scaling sits inside the CNN modules, so training, ``share_cnn_encoders`` and the
exported ONNX / TorchScript policies all take the task's raw 0-255 images.

Train YAML: ``actor: {class_name: isaacgymenvs_mw.learning.models:ImageCNNModel, cnn_cfg: {...}, ...}``.
"""

from __future__ import annotations

import torch
import torch.nn as nn
from rsl_rl.models import CNNModel


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
