"""Model factory (offline ImageNet resolution, state-dict paths) and the checkpoint format."""

from __future__ import annotations

import pickle
import subprocess
import sys

import pytest
import torch
from torchvision.models import mobilenet_v3_large

from segmin.models import WeightsUnavailableError, build_model
from segmin.models.checkpoint import FORMAT, load_model, model_info, read_checkpoint, save_checkpoint
from segmin.models.lraspp import imagenet_weights_path

WEIGHTS_FILE = "mobilenet_v3_large-8738ca79.pth"


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture()
def torch_home(tmp_path, monkeypatch):
    """An empty TORCH_HOME, so the test never sees (or writes) the user's cache."""
    home = tmp_path / "torch_home"
    monkeypatch.setenv("TORCH_HOME", str(home))
    monkeypatch.setattr(torch.hub, "_hub_dir", None)  # in case something called torch.hub.set_dir
    return home


def _random_classifier_state(seed: int = 1) -> dict[str, torch.Tensor]:
    """torchvision MobileNetV3-Large classification state dict (its key layout), random values."""
    torch.manual_seed(seed)
    state = mobilenet_v3_large(weights=None).state_dict()
    return {k: (torch.randn_like(v) if v.is_floating_point() else v) for k, v in state.items()}


def test_forward_gives_one_logit_channel_at_input_size():
    model = build_model("none").eval()
    with torch.no_grad():
        out = model(torch.zeros(2, 3, 64, 96))
    assert out.shape == (2, 1, 64, 96)


def test_imagenet_weights_read_from_the_cache_without_network(torch_home):
    state = _random_classifier_state()
    path = torch_home / "hub" / "checkpoints" / WEIGHTS_FILE
    path.parent.mkdir(parents=True)
    torch.save(state, path)
    assert imagenet_weights_path() == path
    model = build_model("imagenet")
    own = model.state_dict()
    # the backbone holds the file's feature weights, the head stays freshly initialised
    assert torch.equal(own["net.backbone.0.0.weight"], state["features.0.0.weight"])
    assert torch.equal(own["net.backbone.16.0.weight"], state["features.16.0.weight"])
    assert own["net.classifier.low_classifier.weight"].shape[0] == 1


def test_imagenet_backbone_is_the_one_torchvision_builds_from_the_same_file(torch_home):
    """segmin reads the ImageNet file itself (weights_only=True) instead of torchvision (which
    unpickles it with weights_only=False): the same network, the same random draws after it."""
    from torchvision.models.segmentation import lraspp_mobilenet_v3_large

    from segmin.models.lraspp import IMAGENET_WEIGHTS

    path = torch_home / "hub" / "checkpoints" / WEIGHTS_FILE
    path.parent.mkdir(parents=True)
    torch.save(_random_classifier_state(), path)
    torch.manual_seed(7)
    theirs = lraspp_mobilenet_v3_large(weights=None, weights_backbone=IMAGENET_WEIGHTS, num_classes=1).state_dict()
    their_next = torch.rand(3)
    torch.manual_seed(7)
    ours = build_model("imagenet").net.state_dict()
    assert torch.equal(torch.rand(3), their_next)
    assert ours.keys() == theirs.keys() and all(torch.equal(ours[k], theirs[k]) for k in ours)


CUT13 = "lraspp_mobilenet_v3_large_cut13"


def test_a_cut_architecture_keeps_torchvisions_blocks_up_to_the_cut_and_loads_their_imagenet_weights(torch_home):
    state = _random_classifier_state()
    path = torch_home / "hub" / "checkpoints" / WEIGHTS_FILE
    path.parent.mkdir(parents=True)
    torch.save(state, path)
    model = build_model("imagenet", architecture=CUT13)
    own = model.net.state_dict()
    assert torch.equal(own["backbone.13.block.0.0.weight"], state["features.13.block.0.0.weight"])
    assert not any(key.startswith(("backbone.14.", "backbone.16.")) for key in own)
    assert own["classifier.cbr.0.weight"].shape[1] == 160  # the head reads block 13's 160 channels
    assert sum(p.numel() for p in model.parameters()) < 0.45 * sum(p.numel() for p in build_model("none").parameters())
    with torch.no_grad():
        assert model.eval()(torch.zeros(1, 3, 64, 96)).shape == (1, 1, 64, 96)


def test_the_full_architecture_is_torchvisions_lraspp():
    """Old checkpoints hold torchvision's key layout: the generic builder must give the same."""
    from torchvision.models.segmentation import lraspp_mobilenet_v3_large

    torch.manual_seed(3)
    theirs = lraspp_mobilenet_v3_large(weights=None, weights_backbone=None, num_classes=1).state_dict()
    torch.manual_seed(3)
    ours = build_model("none").net.state_dict()
    assert ours.keys() == theirs.keys() and all(torch.equal(ours[k], theirs[k]) for k in ours)


def test_an_unknown_architecture_names_the_known_ones():
    with pytest.raises(ValueError, match="architecture='mobilenet_v4'.*lraspp_mobilenet_v3_large_cut13"):
        build_model("none", architecture="mobilenet_v4")


def test_a_checkpoint_records_and_rebuilds_its_architecture(tmp_path):
    torch.manual_seed(0)
    model = build_model("none", architecture=CUT13).eval()
    payload = _payload(model)
    payload["model_info"]["architecture"] = CUT13
    save_checkpoint(tmp_path / "cut.pt", payload)
    loaded, info = load_model(tmp_path / "cut.pt")
    x = torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        assert info["architecture"] == CUT13 and torch.equal(loaded(x), model(x))
    payload["model_info"]["architecture"] = "resnet"
    save_checkpoint(tmp_path / "foreign_arch.pt", payload)
    with pytest.raises(ValueError, match="foreign_arch.pt: model_info.architecture 'resnet'"):
        read_checkpoint(tmp_path / "foreign_arch.pt")


def test_a_training_config_validates_the_architecture_without_torch():
    from segmin.train.config import TrainConfig

    assert TrainConfig(architecture=CUT13).architecture == CUT13
    with pytest.raises(ValueError, match="architecture='cut99'"):
        TrainConfig(architecture="cut99")
    probe = "import sys, segmin.train.config, segmin.models.architectures; print('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout == "False\n"


def test_imagenet_weights_missing_names_the_file(torch_home):
    with pytest.raises(WeightsUnavailableError) as info:
        build_model("imagenet")
    message = str(info.value)
    assert WEIGHTS_FILE in message and "8738ca79" in message
    assert str(torch_home / "hub" / "checkpoints") in message and "none" in message


def test_corrupt_imagenet_file_is_reported(torch_home):
    path = torch_home / "hub" / "checkpoints" / WEIGHTS_FILE
    path.parent.mkdir(parents=True)
    path.write_bytes(b"not a torch file")
    with pytest.raises(WeightsUnavailableError, match="could not load"):
        build_model("imagenet")


def test_state_dict_paths_whole_model_and_backbone_only(tmp_path):
    torch.manual_seed(3)
    source = build_model("none")
    whole = tmp_path / "whole.pt"
    torch.save(source.state_dict(), whole)
    rebuilt = build_model(whole)
    for key, value in source.state_dict().items():
        assert torch.equal(rebuilt.state_dict()[key], value), key

    backbone_only = tmp_path / "classifier.pth"
    state = _random_classifier_state(seed=5)
    torch.save(state, backbone_only)
    model = build_model(str(backbone_only))
    assert torch.equal(model.state_dict()["net.backbone.3.block.0.0.weight"], state["features.3.block.0.0.weight"])


def test_bad_state_dict_paths(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        build_model(tmp_path / "missing.pt")
    unrelated = tmp_path / "unrelated.pt"
    torch.save({"foo.weight": torch.zeros(3)}, unrelated)
    with pytest.raises(ValueError, match="no tensor matches"):
        build_model(unrelated)
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"\x00" * 64)
    with pytest.raises(ValueError, match="garbage.pt: not a readable"):
        build_model(garbage)


def _payload(model: torch.nn.Module) -> dict:
    return {
        "model": model.state_dict(),
        "model_info": model_info(backbone_weights="none", input_size=(64, 64), family="vineyards", train_data="test"),
        "epoch": 3,
        "metrics": {"val_iou": 0.5},
    }


def test_checkpoint_round_trip_loads_with_weights_only(tmp_path):
    torch.manual_seed(0)
    model = build_model("none").eval()
    path = tmp_path / "ckpt" / "best.pt"
    save_checkpoint(path, _payload(model))
    raw = torch.load(path, map_location="cpu", weights_only=True)
    assert raw["format"] == FORMAT and raw["epoch"] == 3
    loaded, info = load_model(path)
    assert info["input_size"] == [64, 64] and info["backbone_weights"] == "none" and info["family"] == "vineyards"
    x = torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        assert torch.equal(loaded(x), model(x))
    assert not any(p.name.endswith(".tmp") for p in path.parent.iterdir())


def test_corrupt_or_foreign_checkpoints_give_clear_errors(tmp_path):
    model = build_model("none")
    good = tmp_path / "good.pt"
    save_checkpoint(good, _payload(model))
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(ValueError, match="truncated.pt: not a readable segmin checkpoint"):
        read_checkpoint(truncated)
    foreign = tmp_path / "foreign.pt"
    torch.save(model.state_dict(), foreign)
    with pytest.raises(ValueError, match="foreign.pt: not a segmin checkpoint"):
        read_checkpoint(foreign)
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        read_checkpoint(tmp_path / "missing.pt")
    wrong_shape = tmp_path / "wrong.pt"
    payload = _payload(model)
    payload["model"] = {k: v[:1] if v.ndim else v for k, v in payload["model"].items()}
    save_checkpoint(wrong_shape, payload)
    with pytest.raises(ValueError, match="wrong.pt: weights do not fit"):
        load_model(wrong_shape)


def _never_advises_unsafe_loading(message: str) -> None:
    for advice in ("weights_only", "add_safe_globals", "safe_globals", "trust"):
        assert advice not in message, message


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")  # torch, on the plain pickle file
def test_pickled_code_is_refused_without_torchs_advice_to_load_it_unsafely(tmp_path, torch_home, capsys):
    """A file that needs arbitrary unpickling is refused (weights_only=True), and the refusal never
    repeats torch's advice to retry with weights_only=False or to allow-list the class."""
    path = tmp_path / "evil.pt"
    torch.save({"format": FORMAT, "model": {}, "model_info": {"x": _Opaque()}}, path)
    with pytest.raises(
        ValueError,
        match=r"evil.pt: not a readable segmin checkpoint \(it holds pickled Python "
        r"objects \(test_models._Opaque\); segmin loads only tensors",
    ) as info:
        read_checkpoint(path)
    _never_advises_unsafe_loading(str(info.value))
    with pytest.raises(ValueError, match="evil.pt: not a readable PyTorch state dict") as info:
        build_model(str(path))  # backbone_weights=<path>
    _never_advises_unsafe_loading(str(info.value))
    raw_pickle = tmp_path / "raw.pt"
    raw_pickle.write_bytes(pickle.dumps({"x": _Opaque()}))
    with pytest.raises(ValueError, match="raw.pt: not a readable segmin checkpoint") as info:
        read_checkpoint(raw_pickle)
    _never_advises_unsafe_loading(str(info.value))
    cached = torch_home / "hub" / "checkpoints" / WEIGHTS_FILE  # torchvision's own torch.load
    cached.parent.mkdir(parents=True)
    cached.write_bytes(path.read_bytes())
    with pytest.raises(WeightsUnavailableError, match="pickled Python objects") as info:
        build_model("imagenet")
    _never_advises_unsafe_loading(str(info.value))
    from segmin.app.cli import main

    assert main(["export", "--checkpoint", str(path), "--out", str(tmp_path / "m.onnx")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "evil.pt" in err
    _never_advises_unsafe_loading(err)


class _Opaque:
    pass
