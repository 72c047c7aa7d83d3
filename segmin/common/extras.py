"""Which install extra brings which optional dependency, so a missing one is named, not a traceback.

`pip install segmin` is the robot runtime (numpy, OpenCV, onnxruntime, PyYAML). Simulation and
figures come with `[sim]`, training and export with `[train]`, ROS bags (replay and recording)
with `[ros]`, the live view in Foxglove with `[live]`; `[all]` is these four. Ray, for
`--executor ray`, comes with `[cluster]`; the LiteRT runtime with `[litert]` and the LiteRT export
(`segmin export --format tflite`) with `[litert-export]`. The table must follow pyproject.toml's extras (a test
checks it).
"""

from __future__ import annotations

# Top-level module -> the extra that installs it.
EXTRA_OF_MODULE: dict[str, str] = {
    "pybullet": "sim",
    "matplotlib": "sim",
    "markdown": "sim",
    "tqdm": "sim",
    "gymnasium": "sim",
    "moderngl": "sim",
    "torch": "train",
    "torchvision": "train",
    "albumentations": "train",
    "onnx": "train",
    "onnxscript": "train",
    "tensorboard": "train",
    "rosbags": "ros",
    "ray": "cluster",
    "foxglove": "live",
    "ai_edge_litert": "litert",
    "litert_torch": "litert-export",
    "ai_edge_quantizer": "litert-export",
}
ALL_EXTRAS = ("sim", "train", "ros", "live")
"""What `segmin[all]` installs (not [cluster]: Ray is for the machines that fan jobs out)."""


def missing_extra_message(exc: ModuleNotFoundError) -> str | None:
    """The one-line advice for a missing optional module, or None when it is not one of ours."""
    top = (exc.name or "").split(".")[0]
    extra = EXTRA_OF_MODULE.get(top)
    if extra is None:
        return None
    also = " (or 'segmin[all]')" if extra in ALL_EXTRAS else ""
    return (
        f"this command needs the [{extra}] extra (module {top!r} is not installed): pip install 'segmin[{extra}]'{also}"
    )
