"""The segmentation network: torchvision's LR-ASPP MobileNetV3-Large with one logit channel.

The paper (and AgriSeg) use this model for real-time crop segmentation. We keep torchvision's
implementation and weights API, and only add three things: a forward that returns the logit
tensor (not torchvision's dict, which ONNX export and losses do not want), an offline-safe
resolution of the ImageNet backbone weights that never falls back silently to random weights,
and a choice of where the backbone is cut (`models.architectures`, with the reason). A cut
architecture is the same torchvision modules (the dilated MobileNetV3-Large `features`,
`IntermediateLayerGetter`, `LRASPP`) with the high-level branch fed from an earlier block; the
blocks after it are never built into the model, and the ImageNet weights of the kept blocks load
as they are.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NoReturn

import torch
from torch import nn
from torchvision.models import MobileNet_V3_Large_Weights, mobilenet_v3_large
from torchvision.models._utils import IntermediateLayerGetter
from torchvision.models.segmentation.lraspp import LRASPP

from segmin.common.outputs import make_dirs
from segmin.models.architectures import ARCHITECTURE, check_architecture
from segmin.models.safe_load import load_failure_reason, load_tensors

IMAGENET_WEIGHTS = MobileNet_V3_Large_Weights.IMAGENET1K_V1


class WeightsUnavailableError(FileNotFoundError):
    """ImageNet weights are neither cached nor downloadable; the message says what to do.

    A FileNotFoundError (the file to place is missing or unusable), so the command line reports
    it as one line like any other missing input.
    """


class SegmentationNet(nn.Module):
    """LR-ASPP MobileNetV3-Large whose forward returns vegetation logits, N x 1 x H x W."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.net(images)["out"]


def imagenet_weights_path() -> Path:
    """Where torchvision looks for the cached ImageNet backbone file ($TORCH_HOME/hub/checkpoints)."""
    filename = IMAGENET_WEIGHTS.url.rsplit("/", 1)[-1]
    return Path(torch.hub.get_dir()) / "checkpoints" / filename


def imagenet_weights_cached() -> bool:
    """True when the ImageNet backbone file is present, so no network is needed to use it."""
    return imagenet_weights_path().is_file()


def _lraspp(architecture: str) -> LRASPP:
    """torchvision's LR-ASPP on the dilated MobileNetV3-Large, its high branch fed from the cut block.

    For the full network this is exactly what `lraspp_mobilenet_v3_large(num_classes=1)` builds
    (same modules, names and random draws); `IntermediateLayerGetter` drops the blocks after the
    last one it returns, so a cut model holds no unused weights.
    """
    arch = check_architecture(architecture)
    features = mobilenet_v3_large(weights=None, dilated=True).features
    backbone = IntermediateLayerGetter(
        features, return_layers={str(arch.low_block): "low", str(arch.high_block): "high"}
    )
    return LRASPP(backbone, features[arch.low_block].out_channels, features[arch.high_block].out_channels, 1)


def build_model(
    backbone_weights: str | os.PathLike = "imagenet",
    *,
    allow_download: bool = False,
    architecture: str = ARCHITECTURE,
) -> SegmentationNet:
    """Build the network (`architecture`, a name in `ARCHITECTURES`) with one output logit channel.

    `backbone_weights`:
      - "imagenet": torchvision's ImageNet MobileNetV3-Large backbone (the paper's setting), read
        from $TORCH_HOME/hub/checkpoints/; downloaded only when `allow_download` is true.
      - "none": random initialisation (offline demos, tests).
      - a path to a state dict (of the backbone or of a whole SegmentationNet).
    """
    spec = str(backbone_weights)
    if spec == "none":
        return SegmentationNet(_lraspp(architecture))
    if spec == "imagenet":
        return SegmentationNet(_with_imagenet_backbone(architecture, allow_download))
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(
            f"backbone_weights={spec!r}: no such file (expected 'imagenet', 'none' or a state-dict path)"
        )
    model = SegmentationNet(_lraspp(architecture))
    _load_partial_state_dict(model, path)
    return model


def check_backbone_weights(backbone_weights: str | os.PathLike, *, allow_download: bool = False) -> None:
    """Fail now, naming the file, when `build_model(backbone_weights)` would fail for want of it.

    Cheap (no weights are read): training calls it before reading any data, so a missing
    ImageNet file is reported at once rather than after the dataset scan and frame check.
    """
    spec = str(backbone_weights)
    if spec == "none":
        return
    if spec == "imagenet":
        if not imagenet_weights_path().is_file() and not allow_download:
            _missing_imagenet()
        return
    if not Path(spec).is_file():
        raise FileNotFoundError(
            f"backbone_weights={spec!r}: no such file (expected 'imagenet', 'none' or a state-dict path)"
        )


def _missing_imagenet() -> NoReturn:
    cached = imagenet_weights_path()
    digest = IMAGENET_WEIGHTS.url.rsplit("-", 1)[-1].split(".")[0]
    raise WeightsUnavailableError(
        f"backbone_weights=imagenet: ImageNet backbone weights are not cached. Place torchvision's file "
        f"{cached.name} in $TORCH_HOME/hub/checkpoints/ (here: {cached}; sha256 starts with {digest}; from "
        f"{IMAGENET_WEIGHTS.url}), or use backbone_weights=none to train from scratch."
    )


def _with_imagenet_backbone(architecture: str, allow_download: bool) -> nn.Module:
    """torchvision's LR-ASPP with the ImageNet backbone, its file read with `weights_only=True`.

    A cut backbone takes the tensors of the blocks it keeps (all of them, strictly) and leaves
    those of the dropped blocks and the classifier unused.

    torchvision's own `weights_backbone=` loads the cached file through torch.hub, which unpickles
    with `weights_only=False`: any code pickled into a file placed there would run. Building the
    net without weights and then loading the backbone's tensors gives the same network (the same
    modules built in the same order draw the same random numbers; loading draws none).
    """
    cached = imagenet_weights_path()
    digest = IMAGENET_WEIGHTS.url.rsplit("-", 1)[-1].split(".")[0]
    if not cached.is_file() and not allow_download:
        _missing_imagenet()
    net = _lraspp(architecture)
    kept = set(net.backbone.state_dict())
    try:
        if not cached.is_file():  # what torch.hub does for torchvision: download, check the hash prefix
            make_dirs(cached.parent)
            torch.hub.download_url_to_file(IMAGENET_WEIGHTS.url, str(cached), hash_prefix=digest)
        state = torch.load(cached, map_location="cpu", weights_only=True)
        # The classification file's `features.N...` are the backbone's `N...`; its classifier is not used.
        backbone = {k.removeprefix("features."): v for k, v in state.items() if k.startswith("features.")}
        net.backbone.load_state_dict({k: v for k, v in backbone.items() if k in kept})
    except Exception as exc:  # URLError (OSError), hash mismatch, corrupt or pickled file, tensors that do not fit
        raise WeightsUnavailableError(
            f"could not load ImageNet backbone weights ({load_failure_reason(exc)}). Place the file at {cached} "
            f"(sha256 starts with {digest}) or use backbone_weights=none."
        ) from exc
    return net


def _load_partial_state_dict(model: SegmentationNet, path: Path) -> None:
    """Load a whole-model or backbone-only state dict; refuse files that match nothing."""
    state = load_tensors(path, "PyTorch state dict")
    if isinstance(state, dict) and "model" in state and isinstance(state["model"], dict):
        state = state["model"]
    if not isinstance(state, dict):
        raise ValueError(f"{path}: expected a state dict, got {type(state).__name__}")
    own = model.state_dict()
    candidates = {}
    for key, value in state.items():
        backbone_key = key.removeprefix("features.")  # torchvision MobileNetV3 classifier files
        for name in (key, f"net.{key}", f"net.backbone.{backbone_key}"):
            if name in own and own[name].shape == value.shape:
                candidates[name] = value
                break
    if not candidates:
        raise ValueError(f"{path}: no tensor matches the LR-ASPP MobileNetV3 model")
    model.load_state_dict(candidates, strict=False)
