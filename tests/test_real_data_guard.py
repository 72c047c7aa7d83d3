"""The real photos are a test set: no shipped config trains or validates on them, and the guard can fail.

Every shipped training config and pipeline profile is loaded and its data sources are checked
explicitly here (not only through the loaders' own validation), then the checker itself is shown
to refuse bad configs, so a broken guard cannot pass silently.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from segmin.app.pipeline.config import PipelineConfig, check_training_sources, load_pipeline_config
from segmin.app.pipeline.stages import train_config_for
from segmin.common.config import ConfigError
from segmin.common.shipped import shipped_dir, shipped_names
from segmin.data.real_sets import (
    check_frames_not_real,
    check_not_real_data,
    points_to_real_data,
    real_data_root,
    shipped_real_data,
)
from segmin.train.config import load_train_config

REAL = shipped_real_data()


def train_sources(config) -> tuple[dict[str, object], dict[str, object]]:
    """(paths, names) a training config reads frames from."""
    data = config.data
    return (
        {"data.root": data.root, "data.val_root": data.val_root, "data.split_file": data.split_file},
        {"data.domains": data.domains, "data.val_domains": data.val_domains},
    )


@pytest.mark.parametrize("name", shipped_names("train"))
def test_no_shipped_training_config_reads_real_photos(name: str) -> None:
    raw = yaml.safe_load((shipped_dir("train") / f"{name}.yaml").read_text())
    paths, names = train_sources(load_train_config(name))
    check_not_real_data(f"configs/train/{name}.yaml", paths=paths, names=names)
    for key in ("root", "val_root", "domains", "val_domains"):  # the raw YAML too, before any resolution
        assert not points_to_real_data((raw.get("data") or {}).get(key), [REAL]), (name, key)


@pytest.mark.parametrize("profile", shipped_names("pipeline"))
def test_no_shipped_pipeline_profile_trains_on_real_photos(profile: str, tmp_path: Path) -> None:
    config = load_pipeline_config(profile)
    check_training_sources(config)
    real = config.real_eval.resolved_data()
    assert config.real_eval.data is None and real.resolve() == REAL.resolve()  # scored on the test set, never elsewhere
    for family, plan in config.families.items():
        held_out = plan.val_worlds + [v.world for v in plan.validation]
        for step in config.training_chain(family):  # every training stage, fine-tuning ones too
            domains = {"train": [f"synth_{w}" for w in step.worlds], "val": [f"synth_val_{w}" for w in held_out]}
            train_config = train_config_for(config, family, plan, tmp_path / "render", domains, "none", step)
            paths, names = train_sources(train_config)
            check_not_real_data(f"{profile}/{family}/{step.name}", paths=paths, names=names, extra=[real])
            for world in (*step.worlds, *held_out):
                assert not points_to_real_data(world, [real], is_path=False)


# ----------------------------------------------------------------------------- the guard can fail


@pytest.mark.parametrize(
    "override",
    [
        "data.root=data/real/vineyard_rows",
        f"data.val_root={REAL}",
        f"data.root={real_data_root().parent}",  # a parent folder: the loader would scan the photos
        "data.domains=[vineyard_rows]",
    ],
)
def test_a_training_config_on_real_photos_is_refused(override: str) -> None:
    with pytest.raises(ConfigError, match="real test photos"):
        load_train_config("quick", [override])


def test_the_checker_names_the_field() -> None:
    with pytest.raises(ConfigError, match=r"bad\.yaml: data\.val_root=.*real test photos"):
        check_not_real_data(
            "bad.yaml", paths={"data.root": "data/synth_frames/train", "data.val_root": "../x/data/real/vineyard_rows"}
        )
    check_not_real_data("fine.yaml", paths={"data.root": "data/synth_frames/train"}, names={"d": ["vineyards"]})
    assert not points_to_real_data("data", is_path=False)  # a domain called "data" is not a folder


@pytest.mark.parametrize(
    "overrides",
    [
        ["families.vineyards.train_overrides=[data.root=data/real/vineyard_rows]"],
        ["families.trees.train_worlds=[vineyard_rows]"],
        ["families.trees.val_worlds=[data/real/vineyard_rows/world.yaml]"],
        ["families.vineyards.finetune=[{name: a, add_worlds: [vineyard_rows]}]"],
        ["families.vineyards.finetune=[{name: a, train_overrides: [data.val_root=data/real/vineyard_rows]}]"],
    ],
)
def test_a_pipeline_profile_on_real_photos_is_refused(overrides: list[str]) -> None:
    with pytest.raises(ConfigError, match="real test photos"):
        load_pipeline_config("micro", overrides)


def test_a_custom_real_set_is_guarded_too(tmp_path: Path) -> None:
    photos = tmp_path / "my_real"
    with pytest.raises(ConfigError, match=r"data\.val_root=.*real test photos"):
        load_pipeline_config(
            "micro", [f"real_eval.data={photos}", f"families.trees.train_overrides=[data.val_root={photos}]"]
        )
    # The guard also runs on the assembled config (a render folder inside the real set).
    config: PipelineConfig = load_pipeline_config("micro", [f"real_eval.data={photos}"])
    plan = config.families["trees"]
    with pytest.raises(ConfigError, match="real test photos"):
        train_config_for(config, "trees", plan, photos / "render", {"train": ["a"], "val": ["b"]}, "none")


# ----------------------------------------------------------------------------- the frames training selects


def test_the_frames_training_selects_are_checked_whatever_the_config_says_now(tmp_path: Path) -> None:
    """DataConfig checks its fields when it is built; a field assigned afterwards is caught where
    the frames are selected, by the frames themselves."""
    from test_train import tiny_config, write_blob_dataset

    from segmin.train.loaders import select_frames

    config = tiny_config(write_blob_dataset(tmp_path / "synth", frames=6))
    train, val = select_frames(config)  # the normal path: rendered frames train and validate
    assert len(train) + len(val) == 6
    config.data.val_root, config.data.val_domains = REAL, ["vineyard_rows"]
    with pytest.raises(ConfigError, match=r"validation frame .*vineyard_row_0\.png is one of the real test photos"):
        select_frames(config)
    config.data.val_root, config.data.val_domains = None, None
    config.data.root, config.data.domains = REAL, None
    with pytest.raises(ConfigError, match=r"training frame .*vineyard_rows.* is one of the real test photos"):
        select_frames(config)


def test_real_photos_are_recognised_through_a_link(tmp_path: Path) -> None:
    from segmin.data.frames import Frame

    link = tmp_path / "innocent_looking"
    link.symlink_to(REAL)
    photo = Frame("d", "s", 0, link / "images" / "vineyard_row_0.png", link / "masks" / "vineyard_row_0.png")
    rendered = Frame("d", "s", 1, tmp_path / "Image1.png", tmp_path / "Segmentation1.png")
    check_frames_not_real({"training": [rendered]})
    with pytest.raises(ConfigError, match="validation frame .*innocent_looking/images/vineyard_row_0.png"):
        check_frames_not_real({"training": [rendered], "validation": [photo]})
