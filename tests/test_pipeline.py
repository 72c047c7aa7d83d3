"""`segmin pipeline` end to end with the micro profile: artefacts, skipping, resuming, --from."""

from __future__ import annotations

import hashlib
import itertools
import json
import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import pytest

from segmin.app.cli import main
from segmin.app.pipeline.cache import StageCache
from segmin.app.pipeline.config import load_pipeline_config
from segmin.app.pipeline.runner import PipelineRunner
from segmin.common.config import ConfigError, to_dict

FIELDS = ("straight_vineyard", "curved_vineyard", "pergola_vineyard", "pear_field", "high_trees")
STAGE_KEYS = (
    "render",
    "train/trees",
    "train/vineyards",
    "export/trees",
    "export/vineyards",
    "real-eval/trees",
    "real-eval/vineyards",
    "nav-eval/trees",
    "nav-eval/vineyards",
    "nav-eval/oracle",
    "report",
)


def micro_config():
    return load_pipeline_config("micro", ["export.exporter=legacy"])


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("micro")
    code = main(["pipeline", "--config", "micro", "--out", str(out), "export.exporter=legacy"])
    assert code == 0
    return out


def runner_for(run_dir: Path, messages: list[str], **kwargs) -> PipelineRunner:
    return PipelineRunner(micro_config(), run_dir, log=messages.append, **kwargs)


def test_every_report_artefact_is_written(run_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    report = (run_dir / "report.md").read_text()
    for field in FIELDS:
        assert f"| {field} | segmind |" in report
        for folder in (
            "nav-eval/oracle",
            "nav-eval/trees" if field in ("pear_field", "high_trees") else "nav-eval/vineyards",
        ):
            assert (run_dir / folder / f"{field}_trajectories.png").stat().st_size > 1000
            assert (run_dir / folder / f"{field}_histograms.png").stat().st_size > 1000
    for artefact in (
        "render/contact_sheet.png",
        "report/training_curves.png",
        "export/trees/trees.onnx",
        "export/vineyards/vineyards.onnx",
        "train/trees/best.pt",
        "train/vineyards/metrics.csv",
        *[
            f"real-eval/{family}/{name}"
            for family in ("trees", "vineyards")
            for name in ("results.csv", "results.json", "contact_sheet.png")
        ],
    ):
        assert (run_dir / artefact).stat().st_size > 0, artefact
    for section in (
        "## 1. Data",
        "## 2. Training",
        "## 3. Export",
        "## 4. Real photos",
        "## 5. Closed loop",
        "oracle segmenter",
        "Comparison with the paper",
        "## 6. Figures",
    ):
        assert section in report
    # The real-photo figures beside the synthetic ones, per family, and the cross-crop caveat.
    real = report[report.index("## 4. Real photos") : report.index("## 5. Closed loop")]
    assert "| family | synthetic val IoU | real mean IoU |" in real and "cross-crop" in real and "CC BY 4.0" in real
    for family in ("trees", "vineyards"):
        assert f"| {family} | " in real and f"real-eval/{family}/contact_sheet.png" in real
        results = json.loads((run_dir / "real-eval" / family / "results.json").read_text())
        assert len(results["rows"]) == 8 and results["kind"] == "onnx"
        # where each mask would steer, beside IoU: one table row per family with the set's figures
        steering = results["summary"]
        assert 0 <= steering["target_error_median_px"] <= steering["target_error_worst_px"] <= 224
        assert f"| {family} | {steering['target_error_median_px']:.1f} | " in real
    # micro's vineyards family averages its weights (swa.pt) and exports that; the trees family best.pt
    training = report[report.index("## 2. Training") : report.index("## 3. Export")]
    assert "| exported | its val IoU |" in training
    for family, kept in (("trees", "best"), ("vineyards", "swa")):
        outputs = StageCache(run_dir).record(f"train/{family}").outputs
        assert outputs["kept"] == kept and outputs["checkpoint"] == str(run_dir / "train" / family / f"{kept}.pt")
        assert f" | {kept} | {outputs['kept_val_iou']:.3f} |" in training
    html = (run_dir / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 2 + 2 + 2 * len(FIELDS)
    assert 'src="render/' not in html  # every figure embedded, the page stands alone
    rows = json.loads((run_dir / "nav-eval" / "oracle" / "results.json").read_text())["rows"]
    assert sorted(r["field"] for r in rows) == sorted(FIELDS)
    # micro's nav.oracle_methods ([segmin]) replaces nav.methods ([segmind]) for the oracle only.
    assert {r["method"] for r in rows} == {"segmin"}
    model_rows = json.loads((run_dir / "nav-eval" / "trees" / "results.json").read_text())["rows"]
    assert {r["method"] for r in model_rows} == {"segmind"}


def test_a_run_releases_its_models_with_cards_from_its_records(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`segmin models release` on a real (micro) run: every card figure comes from the run's records."""
    import yaml

    from segmin.app.cli import main as segmin_main
    from segmin.nav_eval.runtime.segmenter import OnnxSegmenter

    monkeypatch.setenv("SEGMIN_MODELS_DIR", str(tmp_path / "registry"))
    assert yaml.safe_load((run_dir / "pipeline.yaml").read_text())["profile"] == "micro"
    assert segmin_main(["models", "release", "--run", str(run_dir)]) == 0
    for family in ("vineyards", "trees"):
        card = json.loads(OnnxSegmenter(family, threads=1).metadata["model_card_json"])
        train = StageCache(run_dir).record(f"train/{family}").outputs
        assert card["recipe"]["profile"] == "micro" and card["training"]["machine"] == train["machine"]
        assert card["architecture"] == train["architecture"] == "lraspp_mobilenet_v3_large"
        assert card["synthetic_val_iou"] == train["kept_val_iou"] and card["data"]["train_frames"] > 0
        assert card["real_photos"]["images"] == 8 and card["closed_loop"] and card["latency"]["threads"] == 2


def test_the_report_shows_the_shipped_models_beside_the_run_s_and_a_release_reruns_it(
    run_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With models shipped under the run's family names, sections 4 and 5 add their card figures
    (not for the run's own released models); a release changes the report stage's inputs, so the
    next run rewrites the report."""
    from segmin.app.cli import main as segmin_main
    from segmin.app.pipeline.report import shipped_cards

    registry = tmp_path / "registry"
    monkeypatch.setenv("SEGMIN_MODELS_DIR", str(registry))
    assert shipped_cards(run_dir, ["vineyards", "trees"]) == {}
    assert segmin_main(["models", "release", "--run", str(run_dir), "--families", "trees"]) == 0
    assert shipped_cards(run_dir, ["trees"]) == {}  # the run's own model is not set beside itself
    card_file = registry / "trees.card.json"  # as if another run's model had been released
    card_file.write_text(json.dumps({**json.loads(card_file.read_text()), "onnx_sha256": "0" * 64}))
    assert set(shipped_cards(run_dir, ["vineyards", "trees", "apples"])) == {"trees"}
    record = run_dir / "report" / "stage.json"
    before = json.loads(record.read_text())["input_hash"]
    try:
        runner = runner_for(run_dir, [])
        runner.run()
        assert runner.ran == ["report"] and json.loads(record.read_text())["input_hash"] != before
        report = (run_dir / "report.md").read_text()
    finally:  # the install's own registry again: the report goes back to what the other tests expect
        monkeypatch.undo()
        runner = runner_for(run_dir, [])
        runner.run()
    assert runner.ran == ["report"] and json.loads(record.read_text())["input_hash"] == before
    card = json.loads(card_file.read_text())
    real = report[report.index("## 4. Real photos") : report.index("## 5. Closed loop")]
    assert card["real_photos"]["shipped_photos"] is True
    assert f"| trees: shipped model | {card['synthetic_val_iou']:.3f} | {card['real_photos']['mean_iou']:.3f} |" in real
    assert "vineyards: shipped model" not in real
    loop = report[report.index("## 5. Closed loop") : report.index("### Comparison with the paper")]
    first = card["closed_loop"][0]
    assert f"| trees | {first['field']} | {first['method']} | {first['successes']}/{first['runs']} |" in loop


def test_a_second_run_skips_every_stage(run_dir: Path) -> None:
    messages: list[str] = []
    runner = runner_for(run_dir, messages)
    report = runner.run()
    assert runner.ran == []
    assert sorted(runner.skipped) == sorted(STAGE_KEYS)
    assert report == run_dir / "report.md"


def test_an_interrupted_stage_resumes_and_later_stages_stay_cached(run_dir: Path) -> None:
    cache = StageCache(run_dir)
    frames = sorted((run_dir / "render" / "train").rglob("images/*/*.png"))
    lost = frames[:2]
    for image in lost:
        image.unlink()
    for stage in ("render", "train/trees"):  # as if the process had been killed mid-stage
        cache.started(stage, cache.record(stage).input_hash)
    messages: list[str] = []
    runner = runner_for(run_dir, messages)
    runner.run()
    assert all(image.is_file() for image in lost)
    assert "render: resuming an interrupted run" in messages
    assert "train/trees: resuming an interrupted run" in messages
    assert sorted(runner.ran) == ["render", "train/trees"]  # same inputs: nothing downstream reruns
    assert cache.record("render").finished and cache.record("train/trees").finished


def test_a_truncated_model_reruns_its_export_and_what_read_it(run_dir: Path) -> None:
    """stage.json said "finished", so an empty trees.onnx used to be skipped by every stage (and
    exit 0). The export reruns from scratch, the trees stages after it rerun when the new files
    differ from what they read, and nothing of the vineyards family runs."""
    model = run_dir / "export" / "trees" / "trees.onnx"
    size = model.stat().st_size
    model.write_bytes(b"")
    messages: list[str] = []
    runner = runner_for(run_dir, messages)
    runner.run()
    assert runner.ran[0] == "export/trees"
    assert (
        f"export/trees: finished before, but export/trees/trees.onnx is 0 bytes, {size} when its stage finished: "
        "running it again from scratch" in messages
    )
    assert not [key for key in runner.ran if "vineyards" in key or key in ("render", "nav-eval/oracle")]
    assert model.stat().st_size == size
    cache = StageCache(run_dir)
    for key in ("export/trees", "real-eval/trees", "nav-eval/trees", "report"):
        record = cache.record(key)
        assert record.finished and cache.stale(record) is None, key
    again = runner_for(run_dir, [])
    again.run()
    assert again.ran == []


def test_the_oracle_s_methods_rerun_the_oracle_stage_only(run_dir: Path) -> None:
    """Each nav-eval stage hashes its own methods: other oracle methods do not redo the models'
    loops, and going back reruns the oracle alone again (which leaves the shared run as it was)."""
    other = load_pipeline_config("micro", ["export.exporter=legacy", "nav.oracle_methods=[segmind]"])
    runner = PipelineRunner(other, run_dir, log=lambda message: None)
    runner.run()
    assert runner.ran == ["nav-eval/oracle", "report"]
    rows = json.loads((run_dir / "nav-eval" / "oracle" / "results.json").read_text())["rows"]
    assert {r["method"] for r in rows} == {"segmind"}
    back = runner_for(run_dir, [])
    back.run()
    assert back.ran == ["nav-eval/oracle", "report"]


def test_from_reruns_that_stage_and_later_ones(run_dir: Path) -> None:
    messages: list[str] = []
    runner = runner_for(run_dir, messages, from_stage="report")
    runner.run()
    assert runner.ran == ["report"]
    with pytest.raises(ValueError, match="unknown stage 'bake'"):
        runner_for(run_dir, [], from_stage="bake")


def _writer(contents: dict[str, bytes], name: str):
    """A stage's work: write contents[name] to out.bin in its folder; outputs say whether it was fresh."""

    def work(folder: Path, fresh: bool) -> dict[str, bool]:
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "out.bin").write_bytes(contents[name])
        return {"fresh": fresh}

    return work


def test_a_stage_is_done_only_while_its_files_and_what_it_read_are_as_recorded(tmp_path: Path) -> None:
    contents = {"model": b"model", "results": b"rows"}
    messages: list[str] = []

    def run() -> PipelineRunner:
        messages.clear()
        runner = PipelineRunner(micro_config(), tmp_path, log=messages.append)
        runner._stage("export", "export/a", "h1", _writer(contents, "model"))
        runner._stage("nav-eval", "nav-eval/a", "h2", _writer(contents, "results"), reads=("export/a",))
        return runner

    run()
    record = StageCache(tmp_path).record("nav-eval/a")
    assert record.files == {"nav-eval/a/out.bin": [4, hashlib.sha256(b"rows").hexdigest()]}
    assert run().skipped == ["export/a", "nav-eval/a"]

    # Deleted, and rebuilt the same: what the later stage read is unchanged, it stays done.
    (tmp_path / "export" / "a" / "out.bin").unlink()
    runner = run()
    assert runner.ran == ["export/a"] and runner.skipped == ["nav-eval/a"]
    assert "export/a: finished before, but export/a/out.bin is missing: running it again from scratch" in messages
    assert StageCache(tmp_path).record("export/a").outputs == {"fresh": True}  # no resume over a damaged folder

    # Truncated, and rebuilt otherwise: the stage that read the old file runs again.
    (tmp_path / "export" / "a" / "out.bin").write_bytes(b"")
    contents["model"] = b"model v2"
    runner = run()
    assert runner.ran == ["export/a", "nav-eval/a"]
    assert "export/a: finished before, but export/a/out.bin is 0 bytes, 5 when its stage finished" in messages[0]
    assert messages[2].startswith("nav-eval/a: finished before, but export/a changed since it ran")

    # Same size, other content.
    (tmp_path / "nav-eval" / "a" / "out.bin").write_bytes(b"ROWS")
    runner = run()
    assert runner.ran == ["nav-eval/a"]
    assert "nav-eval/a/out.bin changed since its stage finished (same size, other content)" in messages[1]
    assert (tmp_path / "nav-eval" / "a" / "out.bin").read_bytes() == b"rows"

    # A record without a file list (an older segmin) proves nothing about the files.
    legacy = json.loads((tmp_path / "nav-eval" / "a" / "stage.json").read_text())
    del legacy["files"], legacy["reads"]
    (tmp_path / "nav-eval" / "a" / "stage.json").write_text(json.dumps(legacy))
    runner = run()
    assert runner.ran == ["nav-eval/a"] and "lists no output files (written by an older segmin)" in messages[1]


def test_profiles_are_validated() -> None:
    with pytest.raises(ConfigError, match="unknown key"):
        load_pipeline_config("micro", ["render.frame_per_world=3"])
    with pytest.raises(ConfigError, match="val_seed_offset"):
        load_pipeline_config("micro", ["render.val_seed_offset=0"])
    for profile in ("quick", "paper", "micro"):
        assert load_pipeline_config(profile).families.keys() == {"trees", "vineyards"}
    assert load_pipeline_config("paper_cpu").families.keys() == {"vineyards"}
    with pytest.raises(ConfigError, match="unknown key"):
        load_pipeline_config("micro", ["real_eval.dat=x"])


def test_the_demo_drives_segcorridor_beside_the_papers_methods() -> None:
    """A new user's report shows the navigator that beats the paper, with the paper's three."""
    from segmin.nav_eval.runtime.methods import METHODS

    nav = load_pipeline_config("quick").nav
    assert nav.methods_for("trees") == nav.methods_for("vineyards") == list(METHODS)
    assert "segcorridor" in METHODS


def test_the_comparison_with_the_paper_sets_segcorridor_beside_segmind() -> None:
    """Per field, the paper's SegMinD MAE is the bar for our SegMinD and SegCorridor, SegMinD first;
    the paper's other methods are left to the table, a field without a finished run says so."""
    from segmin.app.pipeline.report import _comparison
    from segmin.nav_eval.evaluation.records import RunResult

    def run(field: str, method: str, mae: float, success: bool = True) -> RunResult:
        return RunResult(field, method, 0, 0, "trees", success, "goal" if success else "collision", mae=mae)

    results = [
        run("pear_field", "segcorridor", 0.020),
        run("pear_field", "segmin", 0.010),
        run("pear_field", "segmind", 0.050),
        run("high_trees", "segmind", float("nan"), success=False),
        run("high_trees", "segcorridor", 0.100),
    ]
    assert _comparison(results) == [
        "- pear_field: MAE against the paper's SegMinD 0.031 m: SegMinD 0.050 m, higher (worse), "
        "1/1 runs succeeded; SegCorridor 0.020 m, lower (better), 1/1 runs succeeded.",
        "- high_trees: MAE against the paper's SegMinD 0.174 m: SegMinD: 0/1 runs succeeded; "
        "SegCorridor 0.100 m, lower (better), 1/1 runs succeeded.",
    ]
    assert _comparison([run("pear_field", "segmin", 0.010)]) == ["(no SegMinD or SegCorridor runs)"]


@pytest.mark.parametrize(
    "profile", sorted(p.stem for p in (Path(__file__).parents[1] / "configs" / "pipeline").glob("*.yaml"))
)
def test_every_shipped_profile_builds_its_training_configs(profile: str, tmp_path: Path) -> None:
    """A family's train_overrides are applied only when its training starts: a typo there would
    surface hours into a run, so each shipped profile's training configs are built here."""
    from segmin.app.pipeline.stages import check_keep, train_config_for

    config = load_pipeline_config(profile)
    for family, plan in config.families.items():
        for step in config.training_chain(family):  # every stage of a chain
            domains = {"train": ["synth_a"], "val": ["synth_val_a"]}
            train = train_config_for(config, family, plan, tmp_path, domains, "none", step)
            assert train.family == family
            check_keep(step, train, f"{profile} {step.key}")
            if "micro" not in profile:  # the full-size profiles train on the canopy-region label
                assert train.data.label_closing == 4, (profile, family)


def test_train_seed_reaches_every_family_and_null_keeps_the_configs_own(tmp_path: Path) -> None:
    """The seed spread reruns a profile with train_seed=N; unset, the training configs (and so the
    training stages' input hashes of runs made before the key existed) stay as they were."""
    from segmin.app.pipeline.stages import train_config_for

    domains = {"train": ["synth_a"], "val": ["synth_val_a"]}
    plain = load_pipeline_config("release")
    seeded = load_pipeline_config("release", ["train_seed=2"])
    for family, plan in plain.families.items():
        own = train_config_for(plain, family, plan, tmp_path, domains, "none")
        spread = train_config_for(seeded, family, seeded.families[family], tmp_path, domains, "none")
        assert (own.seed, spread.seed) == (0, 2), family
        assert to_dict(replace(spread, seed=own.seed)) == to_dict(own)  # nothing else moves
    with pytest.raises(ConfigError, match="train_seed"):
        load_pipeline_config("micro", ["train_seed=-1"])


def test_real_eval_can_be_turned_off_and_a_missing_set_fails_first(tmp_path: Path) -> None:
    config = load_pipeline_config("micro", ["real_eval.enabled=false"])
    assert not config.real_eval.enabled
    messages: list[str] = []
    missing = load_pipeline_config("micro", [f"real_eval.data={tmp_path / 'nowhere'}"])
    with pytest.raises(FileNotFoundError, match="real_eval.data folder not found"):
        PipelineRunner(missing, tmp_path / "run", log=messages.append).run()
    assert not (tmp_path / "run").exists()  # refused before any stage ran, and no empty --out left


@pytest.mark.parametrize(
    "override, message",
    [
        ("export.exporter=foo", "export.exporter"),
        ("nav.methods=[segmax]", "nav.methods"),
        ("nav.oracle_methods=[segmax]", "nav.oracle_methods: unknown"),
        ("nav.oracle_methods=[]", "nav.oracle_methods: name at least one method"),
        ("export.verify_frames=0", "export.verify_frames must be >= 1"),
        ("export.latency_frames=0", "export.latency_frames must be >= 1"),
        ("executor=dask", "executor: 'dask' is not one of"),
        ("ray_address=auto", "an address is for the ray executor"),
    ],
)
def test_settings_that_would_fail_late_fail_when_the_profile_loads(override, message) -> None:
    """These failed only when their stage ran, after render and training."""
    with pytest.raises(ConfigError, match=message):
        load_pipeline_config("micro", [override])


@pytest.mark.parametrize(
    "override, message",
    [
        ("nav.overrides=[run.lenght_m=3]", "lenght_m"),
        ("families.trees.train_overrides=[epochz=1]", "families.trees: .*epochz"),
        ("families.trees.fields=[no_such_field]", "no_such_field"),
        # The navigator sections' values, not only their keys: the nav-eval stage runs last.
        ("nav.overrides=[corridor.min_points=1000]", r"corridor.min_points \(1000\)"),
    ],
)
def test_nested_configs_are_checked_before_the_first_stage(tmp_path, override, message) -> None:
    runner = PipelineRunner(load_pipeline_config("micro", [override]), tmp_path / "run", log=lambda m: None)
    with pytest.raises(ValueError, match=message):
        runner.run()
    assert not (tmp_path / "run").exists()  # nothing ran, and the refused run left no empty --out


def test_a_family_can_render_its_own_number_of_frames_per_world(tmp_path: Path) -> None:
    """`families.<f>.frames_per_world` lets a family with more worlds keep its frame budget; it
    replaces render.frames_per_world for that family's training worlds only, and is part of the
    render stage's inputs (a cached render with other counts is not reused)."""
    from segmin.app.pipeline import stages
    from segmin.app.pipeline.cache import hash_inputs

    config = load_pipeline_config("micro", ["families.trees.frames_per_world=3"])
    with pytest.raises(ConfigError, match="frames_per_world"):
        load_pipeline_config("micro", ["families.trees.frames_per_world=0"])
    outputs = stages.render_stage(config, tmp_path, overwrite=False, log=lambda message: None)

    def frames(split: str, domain: str) -> int:
        return len(list((tmp_path / split / domain).rglob("images/*/*.png")))

    trees, vineyards = outputs["domains"]["trees"], outputs["domains"]["vineyards"]
    assert [frames("train", d) for d in trees["train"]] == [3]
    assert [frames("train", d) for d in vineyards["train"]] == [config.render.frames_per_world]
    assert [frames("val", d) for d in trees["val"]] == [config.render.val_frames_per_world]
    assert hash_inputs("render", *stages.render_inputs(config)) != hash_inputs(
        "render", *stages.render_inputs(micro_config())
    )


def test_families_train_side_by_side_with_a_thread_each(run_dir: Path) -> None:
    """micro (like quick) trains both families at once: one process, one thread and one log each."""
    import yaml

    for family in ("trees", "vineyards"):
        config = yaml.safe_load((run_dir / "train" / family / "config.yaml").read_text())
        assert config["threads"] == 1
        assert "epoch 1/1" in (run_dir / "train" / family / "train.log").read_text()
    assert "ran side by side" in (run_dir / "report.md").read_text()


@pytest.mark.parametrize("parallel", [True, False])
def test_a_failing_family_keeps_the_family_that_trained(run_dir: Path, tmp_path: Path, parallel: bool) -> None:
    """One family's error is raised and the family that trained stays recorded as done (a rerun
    skips it), side by side and one after the other."""
    from segmin.data.agriseg_loader import DatasetError
    from segmin.train.config import load_train_config

    config = load_pipeline_config("micro", ["export.exporter=legacy", f"parallel_training={parallel}"])
    runner = PipelineRunner(config, tmp_path, log=lambda message: None)
    good = load_train_config(run_dir / "train" / "trees" / "config.yaml")
    bad = load_train_config(run_dir / "train" / "trees" / "config.yaml", ["data.domains=[synth_no_such_world]"])
    with pytest.raises(DatasetError, match="synth_no_such_world"):
        runner._train_families({"good": (good, "hash-good"), "bad": (bad, "hash-bad")})
    assert runner.cache.record("train/good").finished
    assert (tmp_path / "train" / "good" / "best.pt").is_file()
    assert not runner.cache.record("train/bad").finished


def test_ctrl_c_stops_the_trainings_side_by_side_and_each_saves_its_place(
    tmp_path: Path, sigint_delivered: None
) -> None:
    """The trainings run in process groups of their own: a Ctrl-C to the pipeline reaches them
    through it, once; each finishes its step, saves last.pt and stops, and the stages stay
    unfinished (a rerun resumes them). No training process outlives the pipeline."""
    import signal
    import subprocess
    import sys
    import time

    import yaml

    profile = yaml.safe_load((Path(__file__).parents[1] / "configs" / "pipeline" / "micro.yaml").read_text())
    for plan in profile["families"].values():  # long enough to be interrupted
        plan["train_overrides"] = [o for o in plan["train_overrides"] if not o.startswith(("epochs", "max_steps"))]
        plan["train_overrides"] += ["epochs=50"]
    profile["render"]["frames_per_world"] = 24
    (tmp_path / "long.yaml").write_text(yaml.safe_dump(profile))
    out = tmp_path / "run"
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "segmin.app.cli",
            "pipeline",
            "--config",
            str(tmp_path / "long.yaml"),
            "--out",
            str(out),
            "export.exporter=legacy",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    metrics = [out / "train" / family / "metrics.csv" for family in ("trees", "vineyards")]
    deadline = time.monotonic() + 240
    while not all(len(read_rows(m)) >= 1 for m in metrics):
        assert process.poll() is None and time.monotonic() < deadline, "training did not start"
        time.sleep(0.5)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr.decode()
    for family in ("trees", "vineyards"):
        folder = out / "train" / family
        assert (folder / "last.pt").is_file()
        assert "interrupted: saved" in (folder / "train.log").read_text()
        assert not StageCache(out).record(f"train/{family}").finished
        assert len(read_rows(folder / "metrics.csv")) < 50


def read_rows(path: Path) -> list[str]:
    """The data rows of a metrics.csv (none while it does not exist)."""
    return path.read_text().splitlines()[1:] if path.is_file() else []


# ------------------------------------------------------------------ the release recipe in one run

RELEASE_CHAIN = ("train/vineyards/base", "train/vineyards/tree_edges", "train/vineyards/by_trees")


@dataclass
class ReleaseRun:
    """The micro release profile, killed in its second vineyards stage and run again."""

    out: Path
    first: str  # what the killed run printed
    second: str  # what the run that resumed it printed
    code: int


@pytest.fixture(scope="module")
def release_run(tmp_path_factory: pytest.TempPathFactory) -> ReleaseRun:
    """`segmin pipeline --config release_micro`, interrupted (as by Ctrl-C) after the first of
    the tree_edges stage's two epochs, then the same command again."""
    import contextlib
    import io

    import segmin.train.run as train_run

    out = tmp_path_factory.mktemp("release_micro") / "run"
    argv = ["pipeline", "--config", "release_micro", "--out", str(out)]
    epoch = train_run.train_epoch

    def killed_in_the_second_epoch(run, state) -> None:
        if run.out_dir.name == "tree_edges" and state.epoch == 1:
            raise KeyboardInterrupt
        epoch(run, state)

    @contextlib.contextmanager
    def printed_and_logged(buffer: io.StringIO) -> Iterator[None]:
        """What the command prints and what segmin logs (training's progress lines), as a user sees both."""
        logger, handler = logging.getLogger("segmin"), logging.StreamHandler(buffer)
        level = logger.level
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        try:
            with contextlib.redirect_stdout(buffer):
                yield
        finally:
            logger.removeHandler(handler)
            logger.setLevel(level)

    first, second = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as patch, printed_and_logged(first):
        patch.setattr(train_run, "train_epoch", killed_in_the_second_epoch)
        assert main(argv) == 130
    with printed_and_logged(second):
        code = main(argv)
    return ReleaseRun(out, first.getvalue(), second.getvalue(), code)


def test_the_release_profile_chains_its_stages_by_checkpoint(release_run: ReleaseRun) -> None:
    """Each vineyards fine-tuning stage starts from the checkpoint the stage before it kept (in
    the run, no ONNX between), on its own render folder with the worlds before it and its own."""
    import torch
    import yaml

    from segmin.models.lraspp import build_model

    assert release_run.code == 0
    cache = StageCache(release_run.out)
    starts = []
    for before, key in itertools.pairwise(RELEASE_CHAIN):
        config = yaml.safe_load((release_run.out / key / "config.yaml").read_text())
        assert config["backbone_weights"] == cache.record(before).outputs["checkpoint"], key
        assert set(cache.record(key).reads) == {"render", before}
        starts.append(Path(config["backbone_weights"]).name)
    assert starts == ["best.pt", "swa.pt"]  # base keeps best, tree_edges the weight average (keep:)
    domains = cache.record("render").outputs["training_sets"]["vineyards"]
    assert [len(domains[s]["domains"]) for s in ("base", "tree_edges", "by_trees")] == [1, 2, 2]
    assert domains["by_trees"]["root"] == "train-vineyards-by_trees"

    def weights(key: str) -> torch.Tensor:
        state = torch.load(cache.record(key).outputs["checkpoint"], weights_only=True)["model"]
        return next(v for k, v in state.items() if k.endswith("weight") and v.dim() == 4)

    # A few steps at lr 1e-4 move the weights by about 1e-3 at most; a network of its own differs by far more.
    fresh = next(v for k, v in build_model("none").state_dict().items() if k.endswith("weight") and v.dim() == 4)
    assert (weights(RELEASE_CHAIN[1]) - weights(RELEASE_CHAIN[0])).abs().max() < 1e-2
    assert (fresh - weights(RELEASE_CHAIN[0])).abs().max() > 1e-1


def test_a_killed_release_run_resumes_at_its_stage_and_epoch(release_run: ReleaseRun) -> None:
    assert "train/vineyards/base: done" in release_run.first
    assert "train/vineyards/tree_edges: done" not in release_run.first
    for key in ("render", "train/vineyards/base"):
        assert f"{key}: up to date, skipped" in release_run.second
    assert "train/vineyards/tree_edges: resuming an interrupted run" in release_run.second
    folder = release_run.out / "train" / "vineyards" / "tree_edges"
    assert f"resuming {folder / 'last.pt'}: epoch 2," in release_run.second  # from its last.pt, not epoch 1
    rows = read_rows(folder / "metrics.csv")
    assert [row.split(",")[0] for row in rows] == ["1", "2"]  # every epoch once
    assert "train/vineyards/by_trees: done" in release_run.second


def test_every_stage_is_scored_on_its_held_out_frames_as_the_photos_are(release_run: ReleaseRun) -> None:
    """IoU against the canopy region and the steering figures of each stage's kept model on the
    held-out validation frames: what a change of recipe is judged on (report section 2)."""
    cache = StageCache(release_run.out)
    report = (release_run.out / "report.md").read_text()
    assert "Held-out validation frames" in report
    for key in RELEASE_CHAIN:
        held = cache.record(key).outputs["held_out"]
        results = json.loads((release_run.out / key / "held-out" / "results.json").read_text())
        assert held["images"] == len(results["rows"]) == 2  # release_micro: 2 frames of one held-out world
        assert results["truth_closing"] == 0 and "target_error_px" in results["definitions"]
        assert held["target_error_median_px"] == results["summary"]["target_error_median_px"]
        assert f"| {held['target_error_median_px']:.1f} |" in report


def test_the_release_run_ends_in_the_released_files_with_their_cards(release_run: ReleaseRun) -> None:
    from segmin.nav_eval.runtime.segmenter import OnnxSegmenter
    from segmin.nav_eval.runtime.shipped_models import models_dir

    folder = release_run.out / "release"
    for suffix in (".onnx", ".md", ".card.json", ".real.jpg"):
        assert (folder / f"vineyards{suffix}").stat().st_size > 0, suffix
    card = json.loads(OnnxSegmenter(str(folder / "vineyards.onnx"), threads=1).metadata["model_card_json"])
    assert card == json.loads((folder / "vineyards.card.json").read_text())
    assert card["command"] == f"segmin pipeline --config release_micro --out {release_run.out}"
    assert card["recipe"]["profile"] == "release_micro"
    # release_micro's candidate (by_trees) has a gate no model passes: the stage before it ships.
    assert card["candidate_gate"]["stage"] == "by_trees" and not card["candidate_gate"]["passed"]
    assert [s["stage"] for s in card["stages"]] == list(RELEASE_CHAIN[:2])
    assert [s["start"] for s in card["stages"]] == ["none", "train/vineyards/base/best.pt"]
    assert [s["seed"] for s in card["stages"]] == [0, 0]
    assert [(w["world"], w["seed"], w["frames"]) for w in card["stages"][1]["worlds"]] == [
        ("train_vineyard_a", 2101, 3),
        ("train_vineyard_d_tree_edges", 2122, 3),
    ]
    assert card["data"]["train_frames"] == 6 and card["data"]["val_frames"] == 2
    assert [(w["world"], w["seed"]) for w in card["data"]["validation"]] == [("heldout_vineyard_row_end_hedge", 5201)]
    report = (release_run.out / "report.md").read_text()
    assert (
        "- **vineyards/by_trees** (fine-tuning stage, from the stage before's checkpoint): 4 training frames" in report
    )
    for label in ("vineyards/base", "vineyards/tree_edges", "vineyards/by_trees"):
        assert f"| {label} | " in report  # one training row a stage
    assert "the candidate stage `by_trees` fails its gate (" in report and "a uniform frame painted" in report
    assert "exported: `tree_edges`" in report
    markdown = (folder / "vineyards.md").read_text()
    assert "## Training stages" in markdown and "from train/vineyards/base/best.pt" in markdown
    assert "candidate stage `by_trees`: failed its gate" in markdown
    assert "a test set looked at once for this model, after it was chosen" in markdown
    # Into the run's folder only: the package's registry keeps its own models.
    shipped = models_dir() / "vineyards.card.json"
    assert not shipped.is_file() or json.loads(shipped.read_text())["recipe"]["profile"] != "release_micro"


@pytest.mark.parametrize(
    "override, message",
    [
        (
            "families.vineyards.validation=[{world: train_vineyard_d_tree_edges, seed: 1}]",
            "training world of vineyards",
        ),
        ("families.vineyards.validation=[{world: straight_vineyard, seed: 1}]", "test field of vineyards"),
        (
            "families.vineyards.validation=[{world: high_trees, seed: 1}]",
            "high_trees is a test field of the test fields",
        ),
        ("families.vineyards.validation=[{world: slope_vineyard_s4, seed: 1}]", "test field of the sloped test rows"),
        ("families.vineyards.val_worlds=[train_vineyard_a]", "exactly one of the two"),
        ("families.vineyards.validation=[]", "exactly one of the two"),
        ("families.vineyards.validation=[{world: tune_pear, seed: 1}, {world: tune_pear, seed: 1}]", "listed twice"),
        ("families.vineyards.validation=[{world: tune_pear, seed: 1, frames: 0}]", "frames must be >= 1"),
        ("families.vineyards.finetune=[{name: a, train_overrides: [backbone_weights=x.pt]}]", "previous stage"),
        ("families.vineyards.finetune=[{name: base}]", "other than 'base'"),
        ("families.vineyards.finetune=[{name: a}, {name: a}]", "must differ"),
        ("families.vineyards.start_from={model: vineyards, stage: by_trees}", "name a stage with one after it"),
        ("families.vineyards.start_from={model: ' '}", "model: name a shipped model"),
        ("families.vineyards.start_from={model: vineyards, calibration_frames: 0}", "calibration_frames must be >= 1"),
        (
            "families={apples: {train_worlds: [train_trees_a], val_worlds: [train_trees_a], fields: [pear_field]}}",
            "release: no family",
        ),
    ],
)
def test_release_profiles_are_validated(override: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_pipeline_config("release_micro", [override])


def test_a_world_s_old_name_is_that_world_when_validation_is_checked() -> None:
    overrides = [
        "families.vineyards.train_worlds=[train_vineyard_under_nets]",
        "families.vineyards.validation=[{world: train_vineyard_a_levers, seed: 1}]",  # its old name
    ]
    with pytest.raises(ConfigError, match="train_vineyard_a_levers is a training world of vineyards"):
        load_pipeline_config("release_micro", overrides)


def test_a_stage_whose_keep_rule_its_training_contradicts_is_refused_before_the_first_stage(tmp_path: Path) -> None:
    config = load_pipeline_config("release_micro", ["families.vineyards.keep=swa"])
    runner = PipelineRunner(config, tmp_path / "run", log=lambda message: None)
    with pytest.raises(ValueError, match="families.vineyards: stage base: keep is 'swa', so its training must set"):
        runner.run()
    assert not (tmp_path / "run").exists()


def test_the_release_profile_is_the_shipped_recipe_and_the_next_stage() -> None:
    """release.yaml is the recipe of the shipped models, trees in one stage, vineyards in three
    (7 worlds x 860 frames, 50 epochs; + tree edges, 8 x 750, 12 epochs at 1e-4; + young vines by
    trees, 10 x 600, 16 epochs at 3e-4), then each family's hard-cases stage (3 epochs at 3e-4),
    each keeping its weight average, validated on held-out worlds."""
    from segmin.app.pipeline.stages import train_config_for

    config = load_pipeline_config("release")
    assert config.release
    chain = config.training_chain("vineyards")
    assert [(len(s.worlds), s.frames_per_world) for s in chain] == [(7, 860), (8, 750), (10, 600), (12, 500)]
    assert [s.keep for s in chain] == ["swa", "swa", "swa", "swa"]
    assert [s.key for s in config.training_chain("trees")] == ["train/trees/base", "train/trees/hard_cases"]
    assert [(len(s.worlds), s.frames_per_world) for s in config.training_chain("trees")] == [(9, 670), (10, 600)]
    domains = {"train": ["synth_a"], "val": ["synth_val_a"]}
    plan = config.families["vineyards"]
    trained = [train_config_for(config, "vineyards", plan, Path("r"), domains, "none", s, "init.pt") for s in chain]
    assert [(t.epochs, t.lr, t.swa_start_epoch) for t in trained] == [
        (50, 3e-4, 38),
        (12, 1e-4, 7),
        (16, 3e-4, 9),
        (3, 3e-4, 2),
    ]
    assert {t.backbone_weights for t in trained} == {"init.pt"} and {t.data.label_closing for t in trained} == {4}
    for family, plan in config.families.items():
        held_out = {v.world for v in plan.validation}
        assert held_out and not held_out & {w for s in config.training_chain(family) for w in s.worlds}


def test_a_run_starts_its_chain_at_a_stage_with_a_model_made_before(
    exported: tuple[Path, dict], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """start_from: an exported model (ONNX, 64 px) stands in for the micro release's tree_edges;
    base and tree_edges are not trained, by_trees fine-tunes from it, its gate judges it against it."""
    import cv2
    import yaml

    from segmin.nav_eval.seg_eval.predictor import load_predictor

    onnx = exported[0]
    out = tmp_path / "run"
    start = f"families.vineyards.start_from={{model: {onnx}, stage: tree_edges, calibration_frames: 4}}"
    looks = "families.vineyards.photo_looks_before=3"
    assert main(["pipeline", "--config", "release_micro", "--out", str(out), start, looks]) == 0
    assert "largest probability difference to the ONNX model" in capsys.readouterr().out
    cache = StageCache(out)
    assert cache.record("train/vineyards/base") is None and not (out / "train" / "vineyards" / "base").exists()
    # Rendered: no frame of the stage before the given one, the given one's calibration frames alone.
    rendered = cache.record("render").outputs["worlds"]["vineyards"]
    assert {w["stage"] for w in rendered} == {"tree_edges", "by_trees", "validation"}
    given_frames = [w["frames"] for w in rendered if w["stage"] == "tree_edges"]
    assert given_frames == [math.ceil(4 / len(given_frames))] * len(given_frames)
    given = cache.record("train/vineyards/tree_edges").outputs
    assert given["kept"] == "given" and given["epochs"] == 0 and given["backbone_weights"] == str(onnx)
    assert not (out / "train" / "vineyards" / "tree_edges" / "metrics.csv").exists()  # nothing trained
    # The given checkpoint computes what the ONNX model computes (BatchNorm measured again).
    frame = next(p for p in sorted((out / "render" / "val").rglob("*.png")) if "images" in p.parts)
    image = cv2.cvtColor(cv2.imread(str(frame)), cv2.COLOR_BGR2RGB)
    probs = [load_predictor(p, threads=1).predict(image)[0] for p in (Path(given["checkpoint"]), onnx)]
    assert abs(probs[0] - probs[1]).max() < 1e-3
    config = yaml.safe_load((out / "train" / "vineyards" / "by_trees" / "config.yaml").read_text())
    assert config["backbone_weights"] == given["checkpoint"]
    card = json.loads((out / "release" / "vineyards.card.json").read_text())
    assert card["candidate_gate"]["stage"] == "by_trees" and not card["candidate_gate"]["passed"]
    assert [(s["stage"], s["start"], s["kept"]) for s in card["stages"]] == [
        ("train/vineyards/tree_edges", str(onnx), "given")
    ]
    assert card["stages"][0]["start_sha256"] == hashlib.sha256(onnx.read_bytes()).hexdigest()
    assert card["real_photos"]["looks"] == {"before": 3, "this_model": 1}
    markdown = (out / "release" / "vineyards.md").read_text()
    assert "a test set looked at 3 times while this model's recipe was made and once for this model" in markdown
    report = (out / "report.md").read_text()
    assert "| vineyards/tree_edges | 0 |" in report and "| vineyards/base |" not in report


def test_a_given_state_dict_must_fit_the_stage_s_network_whole(tmp_path: Path) -> None:
    import torch

    from segmin.app.pipeline.config import StartFrom
    from segmin.app.pipeline.given_stage import given_stage
    from segmin.models.lraspp import build_model
    from segmin.train.config import load_train_config

    train_config = load_train_config("quick", ["image_size=64", "data.val_domains=[]"])
    whole = build_model("none", architecture=train_config.architecture).state_dict()
    fits, partial = tmp_path / "fits.pt", tmp_path / "partial.pt"
    torch.save(whole, fits)
    torch.save(dict(list(whole.items())[:10]), partial)
    outputs = given_stage(StartFrom(model=str(fits)), train_config, tmp_path, tmp_path / "stage", log=print)
    assert outputs["kept"] == "given" and outputs["held_out"] is None  # no held-out frames configured
    with pytest.raises(ValueError, match=r"start_from.model .*partial.pt: does not fit the stage's"):
        given_stage(StartFrom(model=str(partial)), train_config, tmp_path, tmp_path / "stage2", log=print)
    with pytest.raises(FileNotFoundError, match=r"start_from.model .*missing.pt: no such file"):
        given_stage(StartFrom(model=str(tmp_path / "missing.pt")), train_config, tmp_path, tmp_path / "s3", log=print)
