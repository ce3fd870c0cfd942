"""The VGG-19 perceptual term of the paper's loss, from weights the user provides.

Nothing is downloaded (these machines cannot): the weights come from a path the user gives, or
from torchvision's cache when a checkpoint is already there. Without weights the term is off,
and the method's report says so.

The module mirrors the layout of torchvision's ``vgg19().features`` (``features.<i>.weight``),
so torchvision's ImageNet checkpoint loads as it is; classifier weights in it are ignored.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import nn

from geoscaler.errors import GeoscalerError

# torchvision's configuration "E": channels of each 3 x 3 convolution, "M" a 2 x 2 max pooling.
VGG19_LAYERS = [64, 64, "M", 128, 128, "M", 256, 256, 256, 256, "M"]
VGG19_LAYERS += [512, 512, 512, 512, "M", 512, 512, 512, 512, "M"]
# Outputs compared: relu1_2, relu2_2, relu3_4, relu4_4 (indices into ``features``).
PERCEPTUAL_LAYERS = (3, 8, 17, 26)
TORCHVISION_CHECKPOINT = "vgg19-dcbb9e9d.pth"
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


class VGG19Features(nn.Module):
    """The convolutional part of VGG-19, laid out like torchvision's."""

    def __init__(self):
        super().__init__()
        layers: list[nn.Module] = []
        channels = 3
        for item in VGG19_LAYERS:
            if item == "M":
                layers.append(nn.MaxPool2d(2, 2))
            else:
                layers += [nn.Conv2d(channels, int(item), 3, padding=1), nn.ReLU(inplace=False)]
                channels = int(item)
        self.features = nn.Sequential(*layers)

    def forward(self, images: torch.Tensor, taps=PERCEPTUAL_LAYERS) -> list[torch.Tensor]:
        """``(B, 3, H, W)`` ImageNet-normalised images to the feature maps at ``taps``."""
        outputs = []
        x = images
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index in taps:
                outputs.append(x)
            if index >= max(taps):
                break
        return outputs


def cached_vgg19_weights() -> Path | None:
    """torchvision's cached ImageNet VGG-19 checkpoint, if one is on this machine."""
    path = Path(torch.hub.get_dir()) / "checkpoints" / TORCHVISION_CHECKPOINT
    return path if path.is_file() else None


def load_vgg19(path: str | os.PathLike) -> VGG19Features:
    """VGG-19 features with the weights of a torchvision-style checkpoint at ``path``.

    Raises:
        GeoscalerError: the file is missing, unreadable, or lacks VGG-19 feature weights.
    """
    path = Path(path)
    if not path.is_file():
        raise GeoscalerError(
            f"{path}: no such file; give the path of torchvision's VGG-19 checkpoint "
            f"({TORCHVISION_CHECKPOINT}) or leave the perceptual term off"
        )
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many kinds for a bad file
        raise GeoscalerError(f"{path}: not a readable torch checkpoint ({error})") from None
    if isinstance(state, dict) and "state_dict" in state:
        state = state["state_dict"]
    model = VGG19Features()
    wanted = model.state_dict()
    features = {k: v for k, v in state.items() if k in wanted} if isinstance(state, dict) else {}
    missing = sorted(set(wanted) - set(features))
    if missing:
        raise GeoscalerError(
            f"{path}: not VGG-19 weights ({len(missing)} of {len(wanted)} feature tensors "
            f"missing, e.g. {missing[0]!r})"
        )
    bad = [k for k in wanted if features[k].shape != wanted[k].shape]
    if bad:
        raise GeoscalerError(f"{path}: tensor {bad[0]!r} has the wrong shape for VGG-19")
    model.load_state_dict(features)
    return model.eval().requires_grad_(False)


class PerceptualLoss(nn.Module):
    """Mean absolute difference of VGG-19 features of two sRGB images.

    ``loss = mean_l mean |phi_l(image) - phi_l(reference)|`` over :data:`PERCEPTUAL_LAYERS`.
    """

    def __init__(self, vgg: VGG19Features):
        super().__init__()
        self.vgg = vgg
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1))

    def forward(self, image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        """``(H, W, 3)`` sRGB images in [0, 1] to a scalar."""
        pair = torch.stack([image, reference]).permute(0, 3, 1, 2)
        features = self.vgg((pair - self.mean) / self.std)
        return torch.stack([(f[0] - f[1].detach()).abs().mean() for f in features]).mean()


def perceptual_loss(
    path: str | os.PathLike | None, device: torch.device
) -> tuple[PerceptualLoss | None, str]:
    """The perceptual term and a sentence for the report saying where its weights came from.

    ``path`` None: torchvision's cache when it holds the checkpoint, otherwise the term is off.
    """
    source = Path(path) if path is not None else cached_vgg19_weights()
    if source is None:
        return None, "off: no VGG-19 weights (give --vgg19 PATH to turn it on)"
    return PerceptualLoss(load_vgg19(source)).to(device), f"VGG-19 from {source}"
