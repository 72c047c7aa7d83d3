"""AgriSeg loader: layouts, pairing by frame id, bad input, splits, families, augmentation alignment."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from segmin.data.agriseg_loader import (
    AgriSegDataset,
    DatasetError,
    find_frames,
    load_frame,
    load_split,
    make_splits,
    read_depth,
    read_mask,
    resolve_domains,
    save_split,
    scan,
)
from segmin.data.augment import IMAGENET_MEAN, IMAGENET_STD, AugmentConfig, denormalize, eval_transform, train_transform

SIZE = (40, 48)  # h, w


def _image(n: int, h: int = SIZE[0], w: int = SIZE[1]) -> np.ndarray:
    """RGB image whose red channel encodes the frame id, so a mispairing is visible."""
    img = np.zeros((h, w, 3), np.uint8)
    img[..., 0] = n * 10
    img[..., 1] = 100
    return img


def _mask(n: int, h: int = SIZE[0], w: int = SIZE[1]) -> np.ndarray:
    """Mask with n crop columns on the left: the id is readable from the mask too."""
    m = np.zeros((h, w), np.uint8)
    m[:, :n] = 255
    return m


def _write(path: Path, array: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = array[..., ::-1] if array.ndim == 3 else array  # RGB -> BGR for OpenCV
    assert cv2.imwrite(str(path), np.ascontiguousarray(data))
    return path


def make_formatted(root: Path, domain: str, ids=(1, 2, 10), subset_k: int = 1, depth: bool = False) -> Path:
    sub = root / domain / f"{domain}_{subset_k}"
    for n in ids:
        _write(sub / "images" / f"Image{n}" / f"Image{n:04d}.png", _image(n))
        _write(sub / "masks" / f"Image{n}" / f"Segmentation{n:04d}.png", _mask(n))
        if depth:
            _write(sub / "depths" / f"Image{n}" / f"Depth{n:04d}.png", np.full(SIZE, 1000 * n, np.uint16))
    return sub


def make_distributed(root: Path, crop: str, subset: str, ids=(1, 2, 10)) -> Path:
    sub = root / f"Synthetic_Dataset_{crop}" / subset
    for n in ids:
        _write(sub / f"Image{n}" / f"Image{n:04d}.png", _image(n))
        _write(sub / f"Image{n}" / f"Segmentation{n:04d}.png", _mask(n))
        _write(sub / f"Image{n}" / f"Depth{n:04d}.png", np.full(SIZE, 2500, np.uint16))
    return sub


def _check_paired(frame) -> None:
    image, mask = load_frame(frame)
    assert image[0, 0, 0] == frame.frame_id * 10, f"{frame.image_path} is not frame {frame.frame_id}"
    assert mask[0].sum() == frame.frame_id, f"{frame.mask_path} is not frame {frame.frame_id}"


# ----------------------------------------------------------------------------- layouts and pairing


def test_formatted_layout_pairs_by_frame_id_in_numeric_order(tmp_path):
    make_formatted(tmp_path, "vineyard", ids=(1, 2, 10), depth=True)
    frames = find_frames(tmp_path)
    assert [f.frame_id for f in frames] == [1, 2, 10]
    assert {(f.domain, f.subset) for f in frames} == {("vineyard", "vineyard_1")}
    for frame in frames:
        _check_paired(frame)
        assert frame.depth_path is not None and frame.depth_path.parent.name == f"Image{frame.frame_id}"
    assert read_depth(frames[2].depth_path)[0, 0] == pytest.approx(10.0)
    assert scan(tmp_path).layouts == {str(tmp_path / "vineyard" / "vineyard_1"): "formatted"}


def test_distributed_layout_is_detected_and_named_like_formatted(tmp_path):
    make_distributed(tmp_path, "Vineyard_pergolato", "part_a", ids=(1, 2, 10))
    make_distributed(tmp_path, "Pear", "part_b", ids=(3, 20))
    frames = find_frames(tmp_path)
    assert {f.domain for f in frames} == {"vineyard_pergola", "pear"}
    pear = [f for f in frames if f.domain == "pear"]
    assert [f.frame_id for f in pear] == [3, 20] and pear[0].subset == "part_b"
    for frame in frames:
        _check_paired(frame)
        assert frame.depth_path is not None
        assert read_depth(frame.depth_path)[0, 0] == pytest.approx(2.5)
    assert set(scan(tmp_path).layouts.values()) == {"distributed"}


def test_flat_real_set_pairs_by_stem(tmp_path):
    real = tmp_path / "vineyard_real"
    for n in (5, 7, 12):
        _write(real / "images" / f"frame_{n:03d}.jpg", _image(n))
        _write(real / "masks" / f"frame_{n:03d}.png", _mask(n))
    frames = find_frames(tmp_path)
    assert [f.frame_id for f in frames] == [5, 7, 12]
    assert frames[0].domain == "vineyard_real"
    assert frames[0].image_path.suffix == ".jpg"
    for frame in frames:
        image, mask = load_frame(frame)  # JPEG: colours are approximate, the mask is exact
        assert abs(int(image[0, 0, 0]) - frame.frame_id * 10) <= 3
        assert mask[0].sum() == frame.frame_id


def test_mixed_layouts_under_one_root(tmp_path):
    make_formatted(tmp_path / "formatted", "tree_1", ids=(1, 2))
    make_distributed(tmp_path / "download", "Big_Trees", "s1", ids=(4,))
    frames = find_frames(tmp_path)
    assert sorted({f.domain for f in frames}) == ["tree", "tree_1"]
    assert len(frames) == 3


def test_missing_frame_is_an_error_naming_it_or_skipped_with_a_log(tmp_path, caplog):
    sub = make_formatted(tmp_path, "pear", ids=(1, 2, 10))
    missing = sub / "masks" / "Image2" / "Segmentation0002.png"
    missing.unlink()
    missing.parent.rmdir()
    with pytest.raises(DatasetError, match=r"Image2/Image0002\.png.*no mask"):
        find_frames(tmp_path)
    with caplog.at_level(logging.WARNING, logger="segmin.data.domains"):
        frames = find_frames(tmp_path, skip_unpaired=True)
    assert [f.frame_id for f in frames] == [1, 10]
    assert any(r.name == "segmin.data.domains" and "Image0002.png" in r.getMessage() for r in caplog.records)
    for frame in frames:  # frame 10 must not be paired with the mask of a neighbour
        _check_paired(frame)


def test_extra_mask_without_image_is_reported(tmp_path):
    sub = make_formatted(tmp_path, "pear", ids=(1, 2))
    _write(sub / "masks" / "Image7" / "Segmentation0007.png", _mask(7))
    with pytest.raises(DatasetError, match=r"Segmentation0007\.png.*no image"):
        find_frames(tmp_path)


def test_rgb_mask_any_nonzero_is_crop(tmp_path):
    mask = np.zeros((8, 8, 3), np.uint8)
    mask[2, 3] = (0, 0, 1)
    mask[5, 5] = (200, 0, 0)
    path = _write(tmp_path / "m.png", mask)
    binary = read_mask(path)
    assert binary.shape == (8, 8) and binary.dtype == np.uint8
    assert binary.sum() == 2 and binary[2, 3] == 1 and binary[5, 5] == 1


# ----------------------------------------------------------------------------- bad input


def test_missing_root_names_it(tmp_path):
    with pytest.raises(DatasetError, match="nowhere"):
        find_frames(tmp_path / "nowhere")


def test_empty_domain_and_unknown_domain(tmp_path):
    make_formatted(tmp_path, "pear", ids=(1,))
    empty = tmp_path / "vineyard" / "vineyard_1"
    (empty / "images").mkdir(parents=True)
    (empty / "masks").mkdir()
    with pytest.raises(DatasetError, match="vineyard_1: empty"):
        find_frames(tmp_path)
    (empty / "images").rmdir(), (empty / "masks").rmdir()
    with pytest.raises(DatasetError, match="'lettuce'.*available: pear"):
        find_frames(tmp_path, ["lettuce"])


def test_empty_root_is_an_error(tmp_path):
    with pytest.raises(DatasetError, match="no dataset found"):
        find_frames(tmp_path)


def test_truncated_and_garbage_images_are_errors_naming_the_file(tmp_path):
    sub = make_formatted(tmp_path, "pear", ids=(1, 2, 3))
    truncated = sub / "images" / "Image2" / "Image0002.png"
    truncated.write_bytes(truncated.read_bytes()[:-30])
    garbage = sub / "masks" / "Image3" / "Segmentation0003.png"
    garbage.write_bytes(b"\x89PNG\r\n\x1a\n this is not an image" + b"IEND\xaeB`\x82")
    ds = AgriSegDataset(tmp_path, split="all", image_size=32)
    assert ds[0][0].shape == (3, 32, 32)
    with pytest.raises(DatasetError, match=r"Image0002\.png: truncated"):
        ds[1]
    with pytest.raises(DatasetError, match=r"Segmentation0003\.png: unreadable"):
        ds[2]


def test_truncated_jpeg_is_an_error(tmp_path):
    real = tmp_path / "real"
    path = _write(real / "images" / "a_1.jpg", _image(1))
    _write(real / "masks" / "a_1.png", _mask(1))
    path.write_bytes(path.read_bytes()[:-200])
    with pytest.raises(DatasetError, match=r"a_1\.jpg: truncated JPEG"):
        load_frame(find_frames(tmp_path)[0])


def test_size_mismatch_names_both_files(tmp_path):
    sub = make_formatted(tmp_path, "pear", ids=(1,))
    _write(sub / "masks" / "Image1" / "Segmentation0001.png", np.zeros((20, 20), np.uint8))
    with pytest.raises(DatasetError, match=r"Segmentation0001\.png: mask size 20x20 .*Image0001\.png size 48x40"):
        load_frame(find_frames(tmp_path)[0])


def test_two_files_in_one_frame_folder_is_a_problem(tmp_path):
    sub = make_formatted(tmp_path, "pear", ids=(1, 2))
    _write(sub / "images" / "Image1" / "Image0001_copy.png", _image(1))
    with pytest.raises(DatasetError, match=r"images/Image1: 2 files"):
        find_frames(tmp_path)


def test_inspect_cli_lists_counts_and_problems(tmp_path, capsys):
    from segmin.app.cli import main

    make_formatted(tmp_path, "vineyard", ids=(1, 2, 10))
    sub = make_formatted(tmp_path, "pear", ids=(1, 2), subset_k=3)
    assert main(["data", "inspect", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "vineyard_1" in out and "pear_3" in out and "no problems found" in out
    (sub / "masks" / "Image2" / "Segmentation0002.png").unlink()
    bad = sub / "images" / "Image1" / "Image0001.png"
    bad.write_bytes(bad.read_bytes()[:50])
    assert main(["data", "inspect", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert (
        "3 problem(s)" in out
        and "masks/Image2: no" in out
        and "Image0002.png" in out
        and "Image0001.png: truncated" in out
    )


# ----------------------------------------------------------------------------- splits and families


def _many(root: Path, domain: str, n: int) -> None:
    make_formatted(root, domain, ids=tuple(range(1, n + 1)))


def test_splits_are_seeded_per_domain_and_reproducible(tmp_path):
    _many(tmp_path, "vineyard", 20)
    _many(tmp_path, "pear", 10)
    frames = find_frames(tmp_path)
    a, b = make_splits(frames, 0.1, seed=3), make_splits(list(reversed(frames)), 0.1, seed=3)
    assert [f.key for f in a["val"]] == [f.key for f in b["val"]]
    assert sum(f.domain == "vineyard" for f in a["val"]) == 2 and sum(f.domain == "pear" for f in a["val"]) == 1
    assert len(a["train"]) + len(a["val"]) == 30 and not {f.key for f in a["train"]} & {f.key for f in a["val"]}
    other = make_splits(frames, 0.1, seed=4)
    assert [f.key for f in other["val"]] != [f.key for f in a["val"]]
    # adding a domain leaves the split of the others unchanged
    only_vineyard = make_splits([f for f in frames if f.domain == "vineyard"], 0.1, seed=3)
    assert [f.key for f in only_vineyard["val"]] == [f.key for f in a["val"] if f.domain == "vineyard"]


def test_split_file_round_trip_and_dataset_use(tmp_path):
    data = tmp_path / "data"
    _many(data, "vineyard", 12)
    ds = AgriSegDataset(data, split="val", val_fraction=0.25, seed=7, image_size=32)
    ds.save_split(tmp_path / "split.json")
    again = AgriSegDataset(
        data, split="val", val_fraction=0.5, seed=99, image_size=32, split_file=tmp_path / "split.json"
    )
    assert [f.key for f in again.frames] == [f.key for f in ds.frames] and len(ds) == 3
    frames = find_frames(data)
    save_split(tmp_path / "bad.json", {"train": [], "val": frames[:1]})
    (data / "vineyard" / "vineyard_1" / "masks" / "Image1" / "Segmentation0001.png").unlink()
    with pytest.raises(DatasetError, match="not in the dataset"):
        load_split(tmp_path / "bad.json", find_frames(data, skip_unpaired=True))


def test_families_globs_and_prefixes():
    available = [
        "pear",
        "tree_1",
        "tree_2",
        "vineyard",
        "vineyard_pergola",
        "lettuce",
        "synth_vineyard_a",
        "synth_vineyard_b",
        "synth_pear_a",
        "synth_tree_a",
        "synth_pergola_a",
    ]
    assert resolve_domains(["trees"], available) == ["tree_1", "tree_2", "pear"]
    assert resolve_domains("vineyards", available) == ["vineyard", "vineyard_pergola"]
    assert resolve_domains(["synth_vineyards"], available) == [
        "synth_vineyard_a",
        "synth_vineyard_b",
        "synth_pergola_a",
    ]
    assert resolve_domains(["synth_trees"], available) == ["synth_tree_a", "synth_pear_a"]
    assert resolve_domains(["synth_vineyard"], available) == ["synth_vineyard_a", "synth_vineyard_b"]  # prefix
    assert resolve_domains(["synth_*_a", "lettuce"], available) == [
        "synth_pear_a",
        "synth_pergola_a",
        "synth_tree_a",
        "synth_vineyard_a",
        "lettuce",
    ]
    assert resolve_domains(None, ["b", "a"]) == ["a", "b"]
    with pytest.raises(DatasetError, match="synth_trees"):
        resolve_domains(["synth_trees"], ["vineyard"])


# ----------------------------------------------------------------------------- dataset and augmentation


def test_dataset_tensors_are_normalised_and_resized_nearest(tmp_path):
    make_formatted(tmp_path, "pear", ids=(10,))
    ds = AgriSegDataset(tmp_path, split="all", image_size=(20, 24))
    image, mask = ds[0]
    assert image.dtype == torch.float32 and image.shape == (3, 20, 24)
    assert mask.dtype == torch.float32 and mask.shape == (1, 20, 24)
    assert set(mask.unique().tolist()) == {0.0, 1.0}  # nearest: still binary
    assert mask[0, 0].sum() == 5  # 10 of 48 columns -> 5 of 24
    expected_green = (100 / 255 - IMAGENET_MEAN[1]) / IMAGENET_STD[1]
    assert image[1].mean().item() == pytest.approx(expected_green, abs=1e-4)


def test_epoch_index_seeding_is_deterministic(tmp_path):
    make_formatted(tmp_path, "pear", ids=(1, 2, 3))
    ds = AgriSegDataset(tmp_path, split="all", image_size=32, transform=train_transform(32))
    a, b, c = ds[(0, 1)], ds[(0, 1)], ds[(1, 1)]
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert not torch.equal(a[0], c[0])


def _geometric_sample(size: int = 96) -> tuple[np.ndarray, np.ndarray]:
    """White asymmetric shapes on black: the mask is exactly where the image is bright."""
    mask = np.zeros((size, size), np.uint8)
    cv2.fillPoly(mask, [np.array([[5, 5], [60, 12], [12, 80]], np.int32)], 1)
    cv2.rectangle(mask, (70, 40), (88, 90), 1, -1)
    image = np.repeat(mask[..., None] * 255, 3, axis=2).astype(np.uint8)
    return image, mask


@pytest.mark.parametrize("config", [AugmentConfig(), AugmentConfig(gray_p=1.0, hflip_p=1.0, crop_scale=(0.25, 0.3))])
def test_augmentations_keep_image_and_mask_aligned(config):
    image, mask = _geometric_sample()
    transform = train_transform(48, config)
    baseline = eval_transform(48)(image, mask)[1]
    changed = 0
    for seed in range(12):
        x, y = transform(image, mask, seed)
        rgb = denormalize(x.numpy()).astype(float).mean(axis=2)
        assert rgb.max() - rgb.min() > 40, "colour jitter should not erase the two levels"
        level = (rgb - rgb.min()) / (rgb.max() - rgb.min())
        truth = y[0].numpy() > 0.5
        assert set(np.unique(y.numpy())) <= {0.0, 1.0}

        def disagreement(m: np.ndarray, level: np.ndarray = level) -> float:
            """Clearly bright pixels off the mask or clearly dark ones on it (edges are blurred)."""
            return float((((level > 0.75) & ~m) | ((level < 0.25) & m)).mean())

        assert disagreement(truth) < 0.02, f"seed {seed}: image and mask disagree on {disagreement(truth):.1%}"
        assert disagreement(truth[:, ::-1]) > 0.1  # the check does see a misaligned mask
        changed += not torch.equal(y, baseline)
    assert changed >= 10, "the geometric augmentation should move the mask for most seeds"


def test_flip_moves_image_and_mask_together():
    image, mask = _geometric_sample()
    flip_only = AugmentConfig(crop_scale=(1.0, 1.0), hflip_p=1.0, gray_p=0.0, brightness=0.0, contrast=0.0)
    x, y = train_transform(96, flip_only)(image, mask, 0)
    assert np.array_equal(y[0].numpy().astype(np.uint8), mask[:, ::-1])
    assert np.array_equal(denormalize(x.numpy())[..., 0] > 128, mask[:, ::-1] > 0)


def test_augment_config_validation():
    with pytest.raises(ValueError, match="crop_scale"):
        AugmentConfig(crop_scale=(0.0, 1.0))
    with pytest.raises(ValueError, match="gray_p"):
        AugmentConfig(gray_p=1.5)


def test_root_may_be_a_single_subset_folder(tmp_path):
    sub = make_distributed(tmp_path, "Pear", "part_a", ids=(1, 10))
    frames = find_frames(sub)
    assert [(f.domain, f.subset, f.frame_id) for f in frames] == [("pear", "part_a", 1), ("pear", "part_a", 10)]
    formatted = make_formatted(tmp_path / "fmt", "vineyard", ids=(2, 3))
    assert {(f.domain, f.subset) for f in find_frames(formatted)} == {("vineyard", "vineyard_1")}


def test_scanning_and_readers_import_without_torch():
    """The robot runtime has no torch: everything but the Dataset must import without it."""
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['torch'] = None\n"
        "from segmin.data.agriseg_loader import find_frames, read_image, read_mask, scan, make_splits\n"
        "import segmin.data.layouts, segmin.data.readers, segmin.data.splits, segmin.data.domains\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_inspect_decodes_depth_files_and_quick_only_pairs_names(tmp_path, capsys):
    """Random bytes or a wrong-size depth file passed `data inspect`."""
    from segmin.app.cli import main

    sub = make_formatted(tmp_path, "vineyard", ids=(1, 2, 3), depth=True)
    assert main(["data", "inspect", str(tmp_path)]) == 0
    capsys.readouterr()
    depths = sorted((sub / "depths").rglob("*.png"))
    depths[0].write_bytes(np.random.default_rng(0).bytes(300))
    _write(depths[1], np.zeros((5, 7), np.uint16))
    assert main(["data", "inspect", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "2 problem(s)" in out and f"{depths[0]}: truncated PNG" in out
    assert f"{depths[1]}: depth size 7x5 does not match" in out
    assert main(["data", "inspect", "--quick", str(tmp_path)]) == 0
    assert "files not decoded: --quick" in capsys.readouterr().out


def test_inspect_reports_a_half_written_rendered_dataset(tmp_path, capsys):
    """A killed render (meta.json lists every planned frame) reported "no problems"."""
    import json

    from segmin.app.cli import main

    sub = make_formatted(tmp_path, "synth_vineyard", ids=(0, 1))
    meta = {"domain": "synth_vineyard", "subset": sub.name, "frames": {str(n): {} for n in range(5)}}
    (sub / "meta.json").write_text(json.dumps(meta))
    assert main(["data", "inspect", "--quick", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "meta.json: lists 5 frames, 3 of them are not on disk (e.g. Image2)" in out
