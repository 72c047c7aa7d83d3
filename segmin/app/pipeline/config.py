"""Pipeline profiles (`configs/pipeline/<profile>.yaml`): what each stage renders, trains and drives.

The paper trains one model per crop family and tests it on that family's fields: the trees
model drives the high-tree and pear rows, the vineyards model the three vineyards. A profile
lists, per family, the training worlds, the held-out validation worlds, the training config and the
test fields. Validation is either `validation` (worlds no training stage uses, each rendered
from a seed of its own: what a model choice may look at) or `val_worlds` (the training worlds
grown again from another seed: the quick profiles). A family may add fine-tuning stages
(`finetune`), each starting from the checkpoint the stage before it kept, so that a recipe
of several trainings is one run; `start_from` lets a run begin that chain at one of its stages
with a model made before (a shipped model or a checkpoint), so a next stage can be tried without
training the stages before it again. Training and nav configs are shipped names or YAML paths
(relative to the working folder).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from segmin.app.pipeline.gate import GateRule
from segmin.common.config import load_config, to_dict
from segmin.common.executor import Executor
from segmin.common.shipped import resolve_config
from segmin.nav_eval.runtime.methods import METHODS

STAGES: tuple[str, ...] = ("render", "train", "export", "real-eval", "nav-eval", "report", "release")

# Which checkpoint of a training is the model: the weight average of the last epochs (`swa`,
# nothing is chosen by a figure), or the epoch with the best validation IoU (`best`).
Keep = Literal["swa", "best"]
FIRST_STAGE = "base"  # the name of a family's first training stage


@dataclass
class ValidationWorld:
    """A held-out world a family validates on: a world no training stage uses, rendered from a
    seed of its own, so a choice made on its figures cannot fit the training frames (nor the
    real photos, which no stage reads)."""

    world: str
    seed: int
    frames: int = 120

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed!r}")
        if isinstance(self.frames, bool) or self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames!r}")


@dataclass
class StartFrom:
    """A model that stands in for a family's chain up to and including `stage`: the stages before
    it are not trained in this run, the named stage's model is this one, scored on the held-out
    frames like a trained stage (so a gated candidate after it is judged against it), and the
    stages after it fine-tune from it. The run renders no frame for the stages before it, and for
    it only the calibration frames (`stages.rendered_chain`).

    `model`: a shipped model name or a segmin fp32 ONNX file (its BatchNorm statistics measured
    again on `calibration_frames` of that stage's training frames, as `segmin models to-torch`
    does), or a PyTorch state dict (.pt) used as it is.
    """

    model: str
    stage: str = FIRST_STAGE
    calibration_frames: int = 64

    def __post_init__(self) -> None:
        if not str(self.model).strip():
            raise ValueError("model: name a shipped model, an .onnx or a .pt file")
        if isinstance(self.calibration_frames, bool) or self.calibration_frames < 1:
            raise ValueError(f"calibration_frames must be >= 1, got {self.calibration_frames!r}")


@dataclass
class FineTunePlan:
    """A training stage after the family's first: it starts from the checkpoint the stage before it
    kept (PyTorch, in the same run: no export and conversion between), on that stage's worlds plus
    `add_worlds`, with the family's training config and overrides, then its own."""

    name: str
    add_worlds: list[str] = field(default_factory=list)
    frames_per_world: int | None = None  # null: the previous stage's
    train_overrides: list[str] = field(default_factory=list)
    keep: Keep | None = None  # the model-choice rule, checked against the training config
    # A candidate stage (the family's last only): its model replaces the stage before it only if
    # it passes this rule on the held-out frames (segmin.app.pipeline.gate); null: it always does.
    gate: GateRule | None = None

    def __post_init__(self) -> None:
        if not self.name.replace("_", "").isalnum() or self.name == FIRST_STAGE:
            raise ValueError(f"name {self.name!r}: a word (letters, digits, _) other than {FIRST_STAGE!r}")
        if self.frames_per_world is not None and (isinstance(self.frames_per_world, bool) or self.frames_per_world < 1):
            raise ValueError(f"frames_per_world must be >= 1 or null, got {self.frames_per_world!r}")
        if any(item.split("=", 1)[0].strip() == "backbone_weights" for item in self.train_overrides):
            raise ValueError("train_overrides: backbone_weights is the previous stage's checkpoint; do not set it")


@dataclass(frozen=True)
class TrainStep:
    """One training stage of a family's chain, as the runner runs it (derived, not configured)."""

    key: str  # the stage key: train/<family> alone, train/<family>/<name> in a chain
    name: str
    worlds: tuple[str, ...]
    frames_per_world: int
    render_split: str  # the render folder of its training frames
    overrides: tuple[str, ...]  # after the family's train_overrides
    keep: Keep | None
    gate: GateRule | None = None  # a candidate stage's shipping rule (segmin.app.pipeline.gate)
    given: StartFrom | None = None  # not trained here: this model stands in for it (FamilyPlan.start_from)


@dataclass
class FamilyPlan:
    """One crop family: its worlds, its training config (and fine-tuning stages), the fields its model drives."""

    train_worlds: list[str]
    # Legacy validation: the training worlds again from another seed (render.val_seed_offset).
    val_worlds: list[str] = field(default_factory=list)
    fields: list[str] = field(default_factory=list)
    train_config: str = "quick"  # a shipped training config or a YAML path
    train_overrides: list[str] = field(default_factory=list)
    # Frames rendered per training world for this family (default: render.frames_per_world), so
    # a family with more worlds can keep the same number of frames, and the same training time.
    frames_per_world: int | None = None
    # Held-out validation worlds with their own seeds and frame counts (instead of val_worlds).
    validation: list[ValidationWorld] = field(default_factory=list)
    keep: Keep | None = None  # the first stage's model-choice rule (null: whatever the training config does)
    finetune: list[FineTunePlan] = field(default_factory=list)
    start_from: StartFrom | None = None  # begin the chain at a stage with a model made before
    # How many times the shipped real photos (a test set) were scored for models of this family's
    # recipe before this run, while it was being made: the record its model card carries beside
    # this run's one look (docs/results/history/models.md lists each). Changes no stage's output.
    photo_looks_before: int = 0

    def __post_init__(self) -> None:
        for name in ("train_worlds", "fields"):
            if not getattr(self, name):
                raise ValueError(f"{name}: list at least one world")
        if bool(self.val_worlds) == bool(self.validation):
            raise ValueError("give the held-out worlds in validation (or val_worlds), exactly one of the two")
        if self.frames_per_world is not None and (isinstance(self.frames_per_world, bool) or self.frames_per_world < 1):
            raise ValueError(f"frames_per_world must be >= 1 or null, got {self.frames_per_world!r}")
        if any(stage.gate is not None for stage in self.finetune[:-1]):
            raise ValueError(
                "finetune: only the last stage may have a gate (a later stage would start from a model that may not ship)"
            )
        names = [stage.name for stage in self.finetune]
        if len(set(names)) != len(names):
            raise ValueError(f"finetune: stage names must differ, got {names}")
        pairs = [(v.world, v.seed) for v in self.validation]
        if len(set(pairs)) != len(pairs):
            raise ValueError(f"validation: a world and seed listed twice in {pairs}")
        if isinstance(self.photo_looks_before, bool) or self.photo_looks_before < 0:
            raise ValueError(f"photo_looks_before must be >= 0, got {self.photo_looks_before!r}")
        startable = [FIRST_STAGE, *names][:-1]  # a stage with one after it to train
        if self.start_from is not None and self.start_from.stage not in startable:
            raise ValueError(
                f"start_from.stage {self.start_from.stage!r}: name a stage with one after it to train, "
                f"one of {startable} (a family without finetune stages has none)"
            )

    def run_chain(self, family: str, default_frames: int) -> list[TrainStep]:
        """The stages this run has: the whole chain, or with `start_from` the chain from its stage
        on, that stage given (not trained)."""
        steps = self.training_chain(family, default_frames)
        if self.start_from is None:
            return steps
        index = [step.name for step in steps].index(self.start_from.stage)
        return [dataclasses.replace(steps[index], given=self.start_from), *steps[index + 1 :]]

    def training_chain(self, family: str, default_frames: int) -> list[TrainStep]:
        """The family's training stages in order: the first on `train_worlds`, then each fine-tuning
        stage on the worlds before it plus its own. A family without fine-tuning keeps the stage key
        and render folder it always had (train/<family>, render/train)."""
        chained = bool(self.finetune)
        frames = self.frames_per_world or default_frames
        worlds = tuple(self.train_worlds)
        steps = [
            TrainStep(
                key=f"train/{family}/{FIRST_STAGE}" if chained else f"train/{family}",
                name=FIRST_STAGE,
                worlds=worlds,
                frames_per_world=frames,
                render_split="train",
                overrides=(),
                keep=self.keep,
            )
        ]
        for stage in self.finetune:
            worlds = (*worlds, *(w for w in stage.add_worlds if w not in worlds))
            frames = stage.frames_per_world or frames
            steps.append(
                TrainStep(
                    key=f"train/{family}/{stage.name}",
                    name=stage.name,
                    worlds=worlds,
                    frames_per_world=frames,
                    render_split=f"train-{family}-{stage.name}",
                    overrides=tuple(stage.train_overrides),
                    keep=stage.keep,
                    gate=stage.gate,
                )
            )
        return steps


@dataclass
class RenderPlan:
    """How many frames per world, at what size, with how many processes."""

    frames_per_world: int = 300
    val_frames_per_world: int = 60
    val_seed_offset: int = 1000
    size: int = 224
    workers: int = 2
    contact_sheet_frames: int = 1

    def __post_init__(self) -> None:
        for name in ("frames_per_world", "val_frames_per_world", "size", "workers"):
            if getattr(self, name) < 1:
                raise ValueError(f"render.{name} must be >= 1, got {getattr(self, name)}")
        if self.val_seed_offset == 0:
            raise ValueError("render.val_seed_offset must not be 0 (validation worlds would be the training worlds)")


@dataclass
class ExportPlan:
    """Export options (see `segmin export --help`)."""

    exporter: Literal["dynamo", "legacy"] = "dynamo"
    verify_frames: int = 32
    fp16: bool = False
    int8: bool = False
    latency_frames: int = 50
    # Files written for each family: "onnx" (always: the later stages run it) and "tflite" (a
    # LiteRT file, `litert/<family>/<family>.tflite` in the run folder, with an INT8 one when `int8`).
    formats: list[Literal["onnx", "tflite"]] = field(default_factory=lambda: ["onnx"])

    def __post_init__(self) -> None:  # checked at load: the export stage runs after render and training
        for name in ("verify_frames", "latency_frames"):
            if isinstance(getattr(self, name), bool) or getattr(self, name) < 1:
                raise ValueError(f"export.{name} must be >= 1, got {getattr(self, name)!r}")
        if "onnx" not in self.formats:
            raise ValueError(
                f"export.formats {self.formats}: must include onnx (the evaluation stages run the ONNX model)"
            )
        if len(set(self.formats)) != len(self.formats):
            raise ValueError(f"export.formats {self.formats}: a format is listed twice")

    def onnx_settings(self) -> dict[str, Any]:
        """What the ONNX export depends on (the export stage's hash): every setting but `formats`,
        which only decides whether the LiteRT stage runs, so adding tflite re-exports nothing."""
        settings: dict[str, Any] = to_dict(self)
        del settings["formats"]
        return settings


@dataclass
class RealEvalPlan:
    """Score every family's ONNX on real labelled photos (a test set: never trained or validated on).

    `data`: any folder the AgriSeg loader reads; null = the shipped real vineyard rows
    (data/real/vineyard_rows, 8 photos, CC BY 4.0). Relative paths are from the working folder.
    """

    enabled: bool = True
    data: Path | None = None

    def resolved_data(self) -> Path:
        from segmin.data.real_sets import shipped_real_data

        return Path(self.data) if self.data is not None else shipped_real_data()


def _check_methods(key: str, methods: list[str]) -> None:
    """A non-empty list of known navigation methods, or one error naming `key`."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        problem = f"unknown {unknown}" if unknown else "name at least one method"
        raise ValueError(f"{key}: {problem}; choose from {list(METHODS)}")


@dataclass
class NavPlan:
    """Closed-loop evaluation: nav config, methods, runs; the oracle runs beside the model."""

    config: str = "default"  # a shipped nav config or a YAML path
    overrides: list[str] = field(default_factory=list)
    methods: list[str] = field(default_factory=lambda: list(METHODS))
    runs: int = 1
    workers: int = 2
    oracle: bool = True
    # The oracle's methods; null: the same as `methods`. The oracle separates control from
    # perception, and SegMinD alone answers that for the headline method at a third of the cost
    # (the quick profile's time budget).
    oracle_methods: list[str] | None = None
    seed: int = 0
    video: bool = False

    def __post_init__(self) -> None:
        if self.runs < 1 or self.workers < 1:
            raise ValueError("nav.runs and nav.workers must be >= 1")
        _check_methods("nav.methods", self.methods)
        if self.oracle_methods is not None:
            _check_methods("nav.oracle_methods", self.oracle_methods)

    def methods_for(self, model: str) -> list[str]:
        """The methods driven with `model` ('oracle' or an exported model)."""
        if model == "oracle" and self.oracle_methods is not None:
            return list(self.oracle_methods)
        return list(self.methods)


@dataclass
class PipelineConfig:
    """A whole profile."""

    profile: str
    families: dict[str, FamilyPlan]
    render: RenderPlan = field(default_factory=RenderPlan)
    export: ExportPlan = field(default_factory=ExportPlan)
    real_eval: RealEvalPlan = field(default_factory=RealEvalPlan)
    nav: NavPlan = field(default_factory=NavPlan)
    # "auto": ImageNet when its file is cached (said so in the log), else from scratch;
    # or "imagenet" / "none" / a state-dict path, passed to every family's training.
    backbone_weights: str = "auto"
    # Train the families side by side, one process and one thread each (on 2 cores: 0.62 against
    # 0.75 s a step of one 2-thread training after the other); false: one after the other.
    parallel_training: bool = False
    # The training seed of every family (null: each training config's own). The seed spread of a
    # recipe is the same profile run again with train_seed=1, 2 into other run folders.
    train_seed: int | None = None
    # Where the render and nav-eval stages' workers run: "local" processes or "ray" actors, on the
    # cluster at `ray_address` (null: RAY_ADDRESS, else a Ray instance started for the stage).
    # Not a stage input: the outputs are the same on either.
    executor: str = "local"
    ray_address: str | None = None
    # End with the release stage: what `segmin models release` ships (models, cards, contact
    # sheets) written into <run>/release/, never into the package.
    release: bool = False

    def __post_init__(self) -> None:
        if not self.families:
            raise ValueError("families: name at least one crop family")
        self.fan_out()  # a bad executor or address is refused at load
        if self.train_seed is not None and (isinstance(self.train_seed, bool) or self.train_seed < 0):
            raise ValueError(f"train_seed must be >= 0 or null, got {self.train_seed!r}")
        check_training_sources(self)
        check_held_out(self)
        if self.release:
            from segmin.nav_eval.runtime.shipped_models import SHIPPED_NAMES

            if not set(self.families) & set(SHIPPED_NAMES):
                raise ValueError(f"release: no family is named as a shipped model ({', '.join(SHIPPED_NAMES)})")

    def training_chain(self, family: str) -> list[TrainStep]:
        """`family`'s training stages in order, the whole recipe (what the family renders and
        what its model has been trained on); the last one's model is exported."""
        return self.families[family].training_chain(family, self.render.frames_per_world)

    def run_chain(self, family: str) -> list[TrainStep]:
        """`family`'s stages in this run: `training_chain`, from `start_from`'s stage on."""
        return self.families[family].run_chain(family, self.render.frames_per_world)

    def fan_out(self) -> Executor:
        """The render and nav-eval stages' executor."""
        return Executor(self.executor, self.ray_address, address_source="ray_address")


def check_held_out(config: PipelineConfig) -> None:
    """A `validation` world is held out: no training stage of any family renders it, and it is
    none of the closed-loop test fields (a choice made on it would then fit the test)."""
    from segmin.data.synth.spec import RENAMED_WORLDS, TEST_FIELDS

    def same(world: str) -> str:  # an old name is the world it was renamed to
        return RENAMED_WORLDS.get(world, world)

    trained = {same(w): f for f in config.families for step in config.training_chain(f) for w in step.worlds}
    fields = {same(w): f for f, plan in config.families.items() for w in plan.fields}
    fields.update({w: "the test fields" for w in TEST_FIELDS if w not in fields})
    for family, plan in config.families.items():
        for entry in plan.validation:
            world = same(entry.world)
            if world in trained:
                raise ValueError(
                    f"families.{family}.validation: {entry.world} is a training world of {trained[world]}; "
                    "validation worlds must be held out"
                )
            if world in fields or world.startswith("slope_"):
                owner = fields.get(world, "the sloped test rows")
                raise ValueError(
                    f"families.{family}.validation: {entry.world} is a test field of {owner}; "
                    "validation worlds must be held out"
                )


def check_training_sources(config: PipelineConfig) -> None:
    """No family may train or validate on real test photos (data/real or `real_eval.data`).

    Catches what a profile can name: training/validation worlds, the training config path, and
    data paths or domains in `train_overrides`. The training config itself checks its own
    `data` section (train.config.DataConfig), and `stages.train_config_for` checks the final
    config against `real_eval.data` too.
    """
    from segmin.data.real_sets import check_not_real_data

    extra = [config.real_eval.data] if config.real_eval.data is not None else []
    for family, plan in config.families.items():
        own = [*plan.train_overrides, *(item for stage in plan.finetune for item in stage.train_overrides)]
        overrides = dict(item.split("=", 1) for item in own if "=" in item)
        data_overrides = {k: v.strip() for k, v in overrides.items() if k.strip().startswith("data.")}
        paths = {
            f"families.{family}.train_config": plan.train_config,
            **{
                f"families.{family}.train_overrides {k}": v
                for k, v in data_overrides.items()
                if k.strip() in ("data.root", "data.val_root", "data.split_file")
            },
        }
        names = {
            f"families.{family}.train_worlds": plan.train_worlds,
            f"families.{family}.val_worlds": plan.val_worlds,
            f"families.{family}.validation": [v.world for v in plan.validation],
            **{f"families.{family}.finetune.{s.name}.add_worlds": s.add_worlds for s in plan.finetune},
            **{
                f"families.{family}.train_overrides {k}": [d.strip(" '\"") for d in v.strip("[]").split(",")]
                for k, v in data_overrides.items()
                if k.strip() in ("data.domains", "data.val_domains")
            },
        }
        check_not_real_data(f"pipeline profile {config.profile!r}", paths=paths, names=names, extra=extra)


def load_pipeline_config(name_or_path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> PipelineConfig:
    """Load a profile with dotted key=value overrides (e.g. `render.frames_per_world=50`)."""
    return load_config(PipelineConfig, resolve_config("pipeline", name_or_path), overrides)
