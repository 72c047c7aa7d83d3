"""Run the stages in order, skipping what is up to date and resuming what was interrupted.

Stage keys and folders: `render`, `train/<family>` (a family with fine-tuning stages:
`train/<family>/base`, then `train/<family>/<name>` for each), `export/<family>`,
`real-eval/<family>`, `nav-eval/<family>`, `nav-eval/oracle`, `report`, and with `release: true`
`release`. A stage's input hash chains the hashes of the stages it reads, so changing a training
config reruns that family's training (and its later fine-tuning stages), export and evaluation,
and nothing else. `--from STAGE` reruns that stage and every later one from scratch.

A family's training stages run in order, each fine-tuning stage from the checkpoint the stage
before it kept; with `parallel_training` the families' n-th stages run side by side. An
interrupted chain resumes where it stopped: its finished stages are skipped, the interrupted one
continues from its last.pt (the epoch it had reached), the later ones run.

A finished stage is skipped only while its recorded output files are as it left them and the
stages it read still hold what it read (`StageCache.stale`): a deleted or truncated output
reruns its stage from scratch, and a stage after it whose input files then differ reruns too.
The log says why.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from segmin.app.pipeline import stages
from segmin.app.pipeline.cache import StageCache, Timer, file_manifest, hash_inputs
from segmin.app.pipeline.config import STAGES, PipelineConfig, TrainStep
from segmin.app.pipeline.gate import GateVerdict, judge
from segmin.app.pipeline.run_files import COMMAND_FILE, RECIPE_FILE
from segmin.app.pipeline.side_by_side import train_side_by_side
from segmin.common.atomic import write_text
from segmin.common.config import to_dict
from segmin.common.outputs import check_output_dir, make_dirs


class PipelineRunner:
    """One pipeline run in one folder."""

    def __init__(
        self,
        config: PipelineConfig,
        run_dir: str | Path,
        *,
        from_stage: str | None = None,
        log: Callable[[str], None] | None = None,
        command: str | None = None,
    ) -> None:
        if from_stage is not None and from_stage not in STAGES:
            raise ValueError(f"--from: unknown stage {from_stage!r}; stages are {', '.join(STAGES)}")
        self.config = config
        self.run_dir = Path(run_dir)
        self.cache = StageCache(self.run_dir)
        self.forced = set(STAGES[STAGES.index(from_stage) :]) if from_stage else set()
        self.log = log or _default_log
        self.command = command
        self.skipped: list[str] = []
        self.ran: list[str] = []

    def run(self) -> Path:
        """Run every stage; returns the path of report.md.

        render -> train -> export -> real-eval -> nav-eval -> report. `upstream` collects each
        stage's input hash as it is known; the report's own hash chains them all.
        """
        check_output_dir(self.run_dir, "--out")
        config = self.config
        self.preflight()
        backbone = stages.resolve_backbone(config, self.log)
        # Checked before anything runs: a missing photo folder should not wait for training to fail.
        real_fingerprint = (
            stages.dataset_fingerprint(config.real_eval.resolved_data()) if config.real_eval.enabled else None
        )
        make_dirs(self.run_dir, "--out")  # only now: a refused run leaves no empty folder
        # The resolved profile, overrides applied: the recipe a model card names and hashes.
        write_text(self.run_dir / RECIPE_FILE, yaml.safe_dump(to_dict(config), sort_keys=False))
        if self.command is not None:
            write_text(self.run_dir / COMMAND_FILE, self.command + "\n")
        upstream: dict[str, str] = {}
        render = self._render(upstream)
        nav_config = stages.nav_config(config)
        models = self._train_and_export(render, backbone, upstream)
        if config.real_eval.enabled:
            self._real_eval(models, real_fingerprint, upstream)
        self._nav_eval(models, nav_config, upstream)
        report = self._report(upstream)
        if config.release:
            self._release(upstream)
        return report

    def _render(self, upstream: dict[str, str]) -> dict[str, Any]:
        """The rendered training and validation worlds (the render stage's outputs)."""
        config = self.config
        upstream["render"] = hash_inputs("render", *stages.render_inputs(config))
        return self._stage(
            "render",
            "render",
            upstream["render"],
            lambda folder, fresh: stages.render_stage(config, folder, overwrite=fresh, log=self.log),
        )

    def _train_and_export(
        self, render: dict[str, Any], backbone: Any, upstream: dict[str, str]
    ) -> dict[str, tuple[str, str]]:
        """Train every family's chain of stages, then export each family's last (or, when the last
        is a candidate that fails its gate, the stage before it); {family: (onnx path, export hash)}."""
        config = self.config
        chains = {family: config.run_chain(family) for family in config.families}
        trained_all = self._train_chains(chains, render, backbone, upstream)
        models: dict[str, tuple[str, str]] = {}
        for family, chain in chains.items():
            kept, verdict = self._gate(family, chain, trained_all[family])
            final = chain[kept].key
            judged = (upstream[chain[-1].key], verdict.as_dict()) if verdict is not None else ()
            export_hash = hash_inputs("export", upstream[final], config.export.onnx_settings(), *judged)
            exported = self._stage(
                "export",
                f"export/{family}",
                export_hash,
                functools.partial(
                    self._export_stage,
                    checkpoint=trained_all[family][kept]["checkpoint"],
                    family=family,
                    keys=[s.key for s in chain[: kept + 1]],
                    gate=verdict.as_dict() if verdict is not None else None,
                ),
                reads=("render", final, *((chain[-1].key,) if verdict is not None else ())),
            )
            models[family] = (exported["onnx"], export_hash)
            upstream[f"export/{family}"] = export_hash
            if "tflite" in config.export.formats:
                self._stage(
                    "export",
                    f"litert/{family}",
                    hash_inputs("litert", export_hash),
                    functools.partial(
                        self._litert_stage, checkpoint=trained_all[family][kept]["checkpoint"], family=family
                    ),
                    reads=(final,),
                )
        return models

    def _gate(
        self, family: str, chain: list[TrainStep], trained: list[dict[str, Any]]
    ) -> tuple[int, GateVerdict | None]:
        """The index of the stage whose model the family exports, and the candidate's verdict (None
        without a gate): a gated last stage ships only if it passes on the held-out frames."""
        rule = chain[-1].gate
        if rule is None or len(chain) < 2:
            return len(chain) - 1, None
        verdict = judge(rule, chain[-1].name, trained[-1].get("held_out"), trained[-2].get("held_out"))
        if verdict.passed:
            self.log(f"gate: {family} {chain[-1].name} passes on its held-out frames: it ships")
            return len(chain) - 1, verdict
        self.log(
            f"gate: {family} {chain[-1].name} does not ship ({'; '.join(verdict.failures)}): {chain[-2].name} does"
        )
        return len(chain) - 2, verdict

    def _train_chains(
        self, chains: dict[str, list[TrainStep]], render: dict[str, Any], backbone: Any, upstream: dict[str, str]
    ) -> dict[str, list[dict[str, Any]]]:
        """Every family's training stages in order; each family's stage outputs, first to last.

        Round n trains the n-th stage of every family that has one (side by side with
        `parallel_training`). A fine-tuning stage starts from the previous stage's kept
        checkpoint, and its input hash chains that stage's: a retrained first stage reruns the rest.
        """
        config = self.config
        render_dir = self.cache.folder("render")
        last: dict[str, tuple[str, dict[str, Any]]] = {}  # family -> (stage key, outputs)
        trained: dict[str, list[dict[str, Any]]] = {family: [] for family in chains}
        for index in range(max(len(chain) for chain in chains.values())):
            jobs: dict[str, tuple[Any, str]] = {}
            keys: dict[str, str] = {}
            reads: dict[str, tuple[str, ...]] = {}
            for family, chain in chains.items():
                if index >= len(chain):
                    continue
                step, before = chain[index], last.get(family)
                domains = {"train": _training_domains(render, family, step), "val": render["domains"][family]["val"]}
                train_config = stages.train_config_for(
                    config,
                    family,
                    config.families[family],
                    render_dir,
                    domains,
                    backbone,
                    step,
                    init=before[1]["checkpoint"] if before else None,
                )
                if step.given is not None:  # not trained here: the model made before stands in for it
                    upstream[step.key], outputs = self._given(step, train_config, render_dir, upstream["render"])
                    last[family] = (step.key, outputs)
                    trained[family].append(outputs)
                    continue
                chained = (upstream[before[0]],) if before else ()
                jobs[family] = (train_config, hash_inputs("train", upstream["render"], *chained, to_dict(train_config)))
                keys[family] = step.key
                reads[family] = ("render", *((before[0],) if before else ()))
            for family, outputs in self._train_families(jobs, keys, reads).items():
                upstream[keys[family]] = jobs[family][1]
                last[family] = (keys[family], outputs)
                trained[family].append(outputs)
        return trained

    def _given(
        self, step: TrainStep, train_config: Any, render_dir: Path, render_hash: str
    ) -> tuple[str, dict[str, Any]]:
        """A stage `start_from` gives (its input hash, its outputs): the model's checkpoint and its
        held-out figures, redone when the model file, the frames or the stage's config change."""
        from segmin.app.pipeline.cache import file_digest
        from segmin.app.pipeline.given_stage import given_model_file, given_stage

        start = step.given
        assert start is not None
        source = given_model_file(start)
        key_hash = hash_inputs("given", render_hash, to_dict(start), file_digest(source), to_dict(train_config))
        outputs = self._stage(
            "train",
            step.key,
            key_hash,
            lambda folder, fresh: given_stage(start, train_config, render_dir / step.render_split, folder, self.log),
            reads=("render",),
        )
        return key_hash, outputs

    def _real_eval(self, models: dict[str, tuple[str, str]], fingerprint: Any, upstream: dict[str, str]) -> None:
        """Score every exported model on the labelled real photos."""
        config = self.config
        real_common = (to_dict(config.real_eval), fingerprint)
        for family in config.families:
            onnx_path, export_hash = models[family]
            key = f"real-eval/{family}"
            upstream[key] = hash_inputs("real-eval", export_hash, real_common)
            self._stage(
                "real-eval",
                key,
                upstream[key],
                functools.partial(self._real_eval_stage, model=onnx_path),
                reads=(f"export/{family}",),
            )

    # The stages' bodies, as the cache calls them: (folder, fresh) first, the rest bound by partial.

    def _train_stage(self, folder: Path, fresh: bool, *, train_config: Any) -> dict[str, Any]:
        return stages.train_stage(train_config, folder, resume=_resumable(folder, fresh), log=self.log)

    def _export_stage(
        self, folder: Path, fresh: bool, *, checkpoint: str, family: str, keys: list[str], gate: dict[str, Any] | None
    ) -> dict[str, Any]:
        val_frames = self.cache.folder("render") / "val"
        return {
            **stages.export_stage(self.config, Path(checkpoint), folder / f"{family}.onnx", val_frames, self.log),
            "train_stages": keys,  # the chain that made the model, for its card
            "gate": gate,  # a candidate stage's verdict (None without one), for the report and the card
        }

    def _litert_stage(self, folder: Path, fresh: bool, *, checkpoint: str, family: str) -> dict[str, Any]:
        return stages.litert_stage(self.config, Path(checkpoint), folder / f"{family}.tflite", self.log)

    def _real_eval_stage(self, folder: Path, fresh: bool, *, model: str) -> dict[str, Any]:
        return stages.real_eval_stage(self.config, Path(model), folder, self.log)

    def _nav_stage(self, folder: Path, fresh: bool, *, model: str, fields: list[str]) -> dict[str, Any]:
        return stages.nav_stage(self.config, model, fields, folder, self.log)

    def _nav_eval(self, models: dict[str, tuple[str, str]], nav_config: Any, upstream: dict[str, str]) -> None:
        """Drive each family's fields with its exported model, then every field with the oracle."""
        config = self.config
        for family, plan in config.families.items():
            onnx_path, export_hash = models[family]
            key = f"nav-eval/{family}"
            upstream[key] = hash_inputs(
                "nav", export_hash, _nav_inputs(config, onnx_path), to_dict(nav_config), plan.fields
            )
            self._stage(
                "nav-eval",
                key,
                upstream[key],
                functools.partial(self._nav_stage, model=onnx_path, fields=plan.fields),
                reads=(f"export/{family}",),
            )
        if config.nav.oracle:
            fields = [f for plan in config.families.values() for f in plan.fields]
            upstream["nav-eval/oracle"] = hash_inputs(
                "nav-oracle", _nav_inputs(config, "oracle"), to_dict(nav_config), fields
            )
            self._stage(
                "nav-eval",
                "nav-eval/oracle",
                upstream["nav-eval/oracle"],
                lambda folder, fresh: stages.nav_stage(config, "oracle", fields, folder, self.log),
            )

    def _report(self, upstream: dict[str, str]) -> Path:
        from segmin.app.pipeline.report import shipped_cards, write_pipeline_report

        # The shipped models' cards are shown beside the run's: a release changes the report.
        cards = shipped_cards(self.run_dir, list(self.config.families))
        report_hash = hash_inputs("report", upstream, to_dict(self.config), cards)
        report = self._stage(
            "report",
            "report",
            report_hash,
            lambda folder, fresh: write_pipeline_report(self.config, self.run_dir, self.cache, self.log, cards),
            reads=tuple(upstream),
        )
        return Path(report["markdown"])

    def _release(self, upstream: dict[str, str]) -> None:
        """What `segmin models release` ships, written into the run's release/ folder (never into
        the package): each shipped-name family's model with its card, card JSON and contact sheet."""
        from segmin.app.models_cli import release_run

        config = self.config
        families = released_families(config)
        inputs = {key: value for key, value in upstream.items() if key != "report"}
        self._stage(
            "release",
            "release",
            hash_inputs("release", inputs, to_dict(config), families),
            lambda folder, fresh: {
                "folder": str(folder),
                "released": list(release_run(self.run_dir, folder, families=families, force=True)),
            },
            reads=tuple(inputs),
        )

    def preflight(self) -> None:
        """Load every config the stages will load, before the first one runs.

        A typo in `nav.overrides`, a family's training config (any stage's) or its fields would
        otherwise surface only after rendering and training (hours in), as would a stage whose
        `keep` rule its training config contradicts. The configs loaded here are discarded: the
        stages load them again with the paths only the render stage knows.
        """
        from segmin.nav_eval.evaluation.evaluate import resolve_fields
        from segmin.train.config import load_train_config

        stages.nav_config(self.config)
        for family, plan in self.config.families.items():
            try:
                for step in self.config.run_chain(family):
                    train_config = load_train_config(
                        plan.train_config, [f"family={family}", *plan.train_overrides, *step.overrides]
                    )
                    stages.check_keep(step, train_config, f"stage {step.name}")
                resolve_fields(plan.fields)
            except ValueError as exc:
                raise type(exc)(f"families.{family}: {exc}") from exc

    def _stage(
        self,
        stage: str,
        key: str,
        input_hash: str,
        work: Callable[[Path, bool], dict[str, Any]],
        reads: tuple[str, ...] = (),
    ) -> dict[str, Any]:
        """Skip a finished stage with the same inputs; otherwise run it (resuming where possible).

        `work(folder, fresh)`: `fresh` is true when earlier work in the folder must not be reused
        (forced with --from, done with other inputs, or its outputs changed since). `reads`: the
        stages whose files it reads.
        """
        done, fresh = self._begin(stage, key, input_hash)
        if done is not None:
            return done
        timer = Timer()
        outputs = work(self.cache.folder(key), fresh)
        self._finish(stage, key, input_hash, timer, outputs, reads)
        return outputs

    def _begin(self, stage: str, key: str, input_hash: str) -> tuple[dict[str, Any] | None, bool]:
        """(outputs, False) for a stage that is up to date; else (None, fresh) with the stage marked started."""
        record = self.cache.record(key)
        forced = stage in self.forced
        stale = None
        if record is not None and record.finished and record.input_hash == input_hash and not forced:
            stale = self.cache.stale(record)
            if stale is None:
                self.log(f"{key}: up to date, skipped")
                self.skipped.append(key)
                return record.outputs or {}, False
            # Resuming would keep what is there: a truncated frame counts as rendered, a damaged
            # checkpoint would be trained on. The stage starts over.
            self.log(f"{key}: finished before, but {stale}: running it again from scratch")
        fresh = forced or stale is not None or (record is not None and record.input_hash != input_hash)
        if record is not None and not record.finished and not fresh:
            self.log(f"{key}: resuming an interrupted run")
        self.cache.started(key, input_hash)
        return None, fresh

    def _finish(
        self, stage: str, key: str, input_hash: str, timer: Timer, outputs: dict[str, Any], reads: tuple[str, ...]
    ) -> None:
        """Record the stage as finished, with its output files and what it read (see cache.py)."""
        files = file_manifest(self.run_dir, stages.output_paths(stage, self.cache.folder(key), outputs))
        self.cache.finished(key, input_hash, timer.seconds, outputs, files, self.cache.digests(reads))
        self.log(f"{key}: done in {timer.seconds:.1f} s")
        self.ran.append(key)

    def _train_families(
        self,
        jobs: dict[str, tuple[Any, str]],
        keys: dict[str, str] | None = None,
        reads: dict[str, tuple[str, ...]] | None = None,
    ) -> dict[str, dict[str, Any]]:
        """Train one stage of every family (config, input hash): one after the other, or side by
        side in processes of their own when the profile says `parallel_training` (see
        `train_side_by_side`). `keys`: each family's stage key (default train/<family>); `reads`:
        the stages each reads (default the render stage)."""
        keys = keys or {family: f"train/{family}" for family in jobs}
        reads = reads or dict.fromkeys(jobs, ("render",))
        results: dict[str, dict[str, Any]] = {}
        todo: dict[str, tuple[Any, Path, bool]] = {}
        for family, (train_config, train_hash) in jobs.items():
            key = keys[family]
            if not self.config.parallel_training:
                results[family] = self._stage(
                    "train",
                    key,
                    train_hash,
                    functools.partial(self._train_stage, train_config=train_config),
                    reads=reads[family],
                )
                continue
            done, fresh = self._begin("train", key, train_hash)
            if done is not None:
                results[family] = done
            else:
                folder = self.cache.folder(key)
                todo[family] = (train_config, folder, _resumable(folder, fresh))
        if todo:
            timer = Timer()
            outcomes = train_side_by_side(todo, self.log)
            failures = [error for error in outcomes.values() if isinstance(error, BaseException)]
            for family, outputs in outcomes.items():
                if not isinstance(outputs, BaseException):  # a finished family is kept when another failed
                    self._finish("train", keys[family], jobs[family][1], timer, outputs, reads[family])
                    results[family] = outputs
            if failures:
                raise failures[0]
        return results


def _training_domains(render: dict[str, Any], family: str, step: TrainStep) -> list[str]:
    """The rendered domains of a training stage (a render record from before fine-tuning stages
    existed holds only the first stage's, under `domains`)."""
    sets = render.get("training_sets", {}).get(family)
    return list(sets[step.name]["domains"]) if sets else list(render["domains"][family]["train"])


def released_families(config: PipelineConfig) -> list[str]:
    """The profile's families that `segmin models release` ships (those named as a shipped model)."""
    from segmin.nav_eval.runtime.shipped_models import SHIPPED_NAMES

    return [family for family in config.families if family in SHIPPED_NAMES]


def _resumable(folder: Path, fresh: bool) -> bool:
    """Continue the folder's training run: it was interrupted with the same inputs."""
    return not fresh and (folder / "last.pt").is_file()


def _default_log(message: str) -> None:
    print(f"[pipeline {time.strftime('%H:%M:%S')}] {message}", flush=True)


def _nav_inputs(config: PipelineConfig, model: str) -> dict:
    """What one nav-eval stage's runs depend on: the nav section with that stage's own methods in
    place of both method lists and the oracle switch, so that changing the oracle's methods
    (or turning it off) does not rerun the models' closed loops, and the reverse."""
    settings = {k: v for k, v in to_dict(config.nav).items() if k not in ("methods", "oracle", "oracle_methods")}
    return {**settings, "methods": config.nav.methods_for(model)}
