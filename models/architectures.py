"""The networks segmin can build, by name: where the MobileNetV3-Large backbone is cut.

Torch-free on purpose: training configs validate `architecture=` without importing torch, and
checkpoints and ONNX metadata record the name. `models.lraspp` builds them.

Why cuts: the paper's released model is a MobileNetV3 cut after block `expanded_conv_12` (about
1 M parameters); torchvision's full LR-ASPP MobileNetV3-Large (3.2 M) takes about 1.7x its time
a frame on 2 CPU cores. Indices are torchvision's `features[i]` of the dilated backbone; Keras'
`expanded_conv_K` is `features[K + 1]`. `low_block` feeds the head's 1/8-resolution branch,
`high_block` its 1/16 attention branch; the blocks after `high_block` are not part of the model.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Architecture:
    """Which backbone blocks feed the LR-ASPP head (see the module docstring)."""

    name: str
    high_block: int
    low_block: int = 4  # the 40-channel block at 1/8 resolution, as in torchvision's LR-ASPP
    summary: str = ""


# torchvision's full network: what every checkpoint written before the cuts existed holds.
ARCHITECTURE = "lraspp_mobilenet_v3_large"
ARCHITECTURES: dict[str, Architecture] = {
    arch.name: arch
    for arch in (
        Architecture(ARCHITECTURE, 16, summary="torchvision's full LR-ASPP MobileNetV3-Large, 3.2 M parameters"),
        Architecture(
            "lraspp_mobilenet_v3_large_cut13",
            13,
            summary="cut after features[13] (Keras expanded_conv_12, the paper's cut), 160 channels, 1.3 M parameters",
        ),
        Architecture(
            "lraspp_mobilenet_v3_large_cut12",
            12,
            summary="cut after features[12] (Keras expanded_conv_11), 112 channels, 0.8 M parameters",
        ),
        Architecture(
            "lraspp_mobilenet_v3_large_cut10",
            10,
            summary="cut after features[10] (Keras expanded_conv_9), 80 channels, 0.2 M parameters",
        ),
    )
}


def check_architecture(name: object, field: str = "architecture") -> Architecture:
    """The named architecture; ValueError naming `field` and the known names otherwise."""
    arch = ARCHITECTURES.get(name) if isinstance(name, str) else None
    if arch is None:
        raise ValueError(f"{field}={name!r}: unknown architecture (expected one of {', '.join(ARCHITECTURES)})")
    return arch
