"""Characters from the trained 2022 style models: reload a model with its data, pick styles, blend
them, and drive them along paths (Mason, Starke & Komura 2022, section 4.4).

1. :func:`load_model` reloads a model trained by :func:`jaxstyle.mason2022.pipeline.train_model`
   (``jaxstyle lpn`` writes one into ``RUN/lpn``): its config and weights from the checkpoint folder
   (``config.json``), its training and new styles' clips from ``data.json`` (the LPN rows, their
   normalisers, the style clips and the skeleton are rebuilt from them, from the cache when there
   is one);
2. :func:`characters`: training styles (their runtime style: for FiLM the mean FiLM vector of the
   style's training clips, as :func:`jaxstyle.mason2022.train.evaluate` and the paper's runtime
   use; otherwise the style's one-hot row or adapter), new styles fine-tuned by the FiLM sweep
   (``finetuned_generators.npz`` at the rate of ``chosen_rates.json``: the FiLM vector of the new
   style's training clips under its fine-tuned generator), and a 2- or 3-way blend of the first
   characters (:func:`jaxstyle.output.drive.blend_character`, section 4.4's interpolation);
3. synthesis: :func:`jaxstyle.output.synthesis.synthesize` with the model as a
   :class:`jaxstyle.control.lpn_controller.StyleNetModel` (:meth:`Loaded.character_model`; one
   batched rollout; GIF, BVH files, the quality table), the same synthesis as the 2018 model's.

Every Table 2 model drives characters: the LPN and MANN backbones, and the PFNN backbones (PFNN
One-hot, PFNN Resad, PFNN FiLM), which the controller evaluates at a carried global phase
(:mod:`jaxstyle.control.lpn_controller`). ``jaxstyle synthesize --model lpn-film`` (or
``pfnn-film`` ...) and ``jaxstyle demo --model lpn-film`` are this module.
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from pathlib import Path
from typing import NamedTuple, Sequence

import jax
import numpy as np

from jaxstyle.control.lpn_controller import StyleNetModel
from jaxstyle.data import datasets
from jaxstyle.data.clips import ClipSpec
from jaxstyle.data.folders import PipelineError, located_path
from jaxstyle.mason2022 import finetune, pipeline, styledata
from jaxstyle.mason2022 import train as train_lpn
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import style_models
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.output import drive
from jaxstyle.output.check import FAILED_MARK, failed_check, refusal
from jaxstyle.output.drive import Character
from jaxstyle.train.defaults import BODY_SMOOTH, CHOOSE_EPOCHS, FOOT_SMOOTH, PHASE_FLOOR

MODELS = {"lpn-film": "LPN FiLM", "lpn-onehot": "LPN One-hot", "lpn-resad": "LPN Resad", "mann-film": "MANN FiLM",
          "pfnn-film": "PFNN FiLM", "pfnn-onehot": "PFNN One-hot", "pfnn-resad": "PFNN Resad"}
"""The ``--model`` names of the 2022 models (Table 2's names as values)."""


def model_key(name: str) -> str:
    """The ``--model`` key of a Table 2 model name (``"LPN FiLM"`` -> ``"lpn-film"``)."""
    return {v: k for k, v in MODELS.items()}[name]


class Loaded(NamedTuple):
    """A reloaded model: the :class:`jaxstyle.mason2022.pipeline.Model`, its :class:`LPNData`
    (training styles, new styles or ``None``, a skeleton clip), the folder, the epoch whose weights
    it holds and, when it was trained further (an epoch chosen by :func:`choose_epoch`), the epochs
    trained."""

    model: pipeline.Model
    data: pipeline.LPNData
    directory: Path
    epochs: int
    phase_floor: float = PHASE_FLOOR
    foot_smooth: float | None = FOOT_SMOOTH
    amplitude_floor: float = 0.0
    body_smooth: float | None = BODY_SMOOTH
    trained_epochs: int | None = None

    def epoch_text(self) -> str:
        """``'30 epochs'``, or ``'epoch 28 of 30'`` for a model taken from an earlier epoch."""
        if self.trained_epochs is None or self.trained_epochs == self.epochs:
            return f"{self.epochs} epochs"
        return f"epoch {self.epochs} of {self.trained_epochs}"

    def character_model(self, *, blend_bias: float = 1.5) -> StyleNetModel:
        """The model as a :class:`jaxstyle.control.model.CharacterModel`
        (:class:`jaxstyle.control.lpn_controller.StyleNetModel`: a character's conditioning is its
        runtime style), normalised with its training data's statistics, its local phases floored
        at ``phase_floor`` times each style's capture rate
        (:func:`jaxstyle.control.lpn_phases.floored_phases`; 0: the paper's runtime), its feet's
        ``foot_smooth`` (:meth:`jaxstyle.control.lpn_controller.StyleNetModel.create`; default
        :data:`jaxstyle.train.defaults.FOOT_SMOOTH`; 0.5 or ``None``: the paper's runtime), its local
        phases' amplitudes floored at ``amplitude_floor`` times each style's captured median (0: the
        paper's runtime), the other bones' ``body_smooth`` (default
        :data:`jaxstyle.train.defaults.BODY_SMOOTH`; 0.5 or ``None``: the paper's runtime)."""
        m = self.model
        return StyleNetModel.create(m.params, m.config, self.data.base.normalisers(), self.data.skeleton,
                                    blend_bias=blend_bias, phase_floor=self.phase_floor, foot_smooth=self.foot_smooth,
                                    amplitude_floor=self.amplitude_floor, body_smooth=self.body_smooth)


def _dataclass(cls, values: dict):
    """``cls(**values)`` keeping only ``cls``'s fields (configs written by other versions)."""
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in values.items() if k in names})


def train_config(saved: dict) -> train_lpn.LPNTrainConfig:
    """The :class:`jaxstyle.mason2022.train.LPNTrainConfig` written to a run folder's ``config.json``."""
    model = dict(saved["model"])
    model["generator"] = _dataclass(film.FiLMConfig, model["generator"])
    cfg = dict(saved, model=_dataclass(StyleModelConfig, model))
    return _dataclass(train_lpn.LPNTrainConfig, cfg)


def _saved_run(directory: Path) -> tuple[train_lpn.LPNTrainConfig, tuple[str, ...], str]:
    """The training config, styles and compute dtype of a run folder's ``config.json``."""
    saved = json.loads((directory / "config.json").read_text())
    return train_config(saved["train"]), tuple(saved["styles"]), saved.get("compute_dtype", "float32")


def load_model(directory: str | os.PathLike, *, cache: str | os.PathLike | None = None,
               progress: bool = False) -> Loaded:
    """The style model trained into ``directory`` by :func:`jaxstyle.mason2022.pipeline.train_model`,
    with its data rebuilt from the clips listed in ``data.json`` (LPN rows cached in ``cache``): the
    last epoch's weights, or the epoch :func:`choose_epoch` recorded (``Loaded.epochs`` is the epoch
    loaded). A folder without a finished checkpoint, or whose clips changed, is refused in one line."""
    directory = Path(directory)
    for name in ("config.json", "data.json"):
        if not (directory / name).is_file():
            raise PipelineError(f"no trained 2022 model in {directory} (no {name}): train one with "
                                "`jaxstyle lpn --data PATH --run RUN` (or `jaxstyle demo --model lpn-film`)")
    config, styles, dtype = _saved_run(directory)
    meta = json.loads((directory / "data.json").read_text())

    def build(specs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # short clips are skipped with a warning, as in training
            return datasets.build_lpn_dataset([ClipSpec(**{**s, "path": located_path(s["path"], directory)})
                                               for s in specs], cache_dir=cache, skip_short=True,
                                              progress=progress)

    base = build(meta["base"])
    if tuple(base.styles) != styles:
        raise PipelineError(f"{directory}: the clips of data.json give styles {', '.join(base.styles)}, "
                            f"the model was trained on {', '.join(styles)}")
    new = build(meta["new"]) if meta.get("new") else None
    data = pipeline.LPNData(base, new, datasets.load_clip(base.specs[0]))
    if config.model.backbone == "pfnn" and len(base.global_phase) != len(base.inputs):
        raise PipelineError(f"{directory}: {meta.get('name', 'the model')} has the PFNN backbone and its rows no "
                            "global phase (a cache older than them): remove the cache folder and load it again")
    try:
        state = train_lpn.load(directory, config, styles, compute_dtype=dtype)
    except FileNotFoundError:
        raise PipelineError(f"{directory} has no checkpoint yet: finish training it first") from None
    trained = int(state.epoch)
    state = pipeline.chosen_state(directory, state, config, styles, dtype)
    style_data = styledata.style_data(base, data.skeleton, backbone=config.model.backbone)
    model = pipeline.Model(meta.get("name", pipeline.MODEL), config.model, state.params, style_data)
    return Loaded(model, data, directory, int(state.epoch), trained_epochs=trained)


def _generators(model: pipeline.Model, path: Path) -> dict:
    """The fine-tuned generators of :func:`jaxstyle.mason2022.finetune.write_finetune` (leading axes
    (new style, rate)) in the tree structure of ``model``'s generator."""
    like = model.params["style"]["generator"]
    with np.load(path) as z:
        leaves = [z[jax.tree_util.keystr(p)] for p, _ in jax.tree_util.tree_leaves_with_path(like)]
    return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(like), leaves)


def characters(loaded: Loaded, *, styles: Sequence[str] = (), new_styles: Sequence[str] = (),
               finetune_dir: str | os.PathLike | None = None, blend: Sequence[float] | None = None,
               allow_failed: bool = False) -> list[Character]:
    """:class:`~jaxstyle.output.drive.Character` s: training ``styles``, ``new_styles``
    fine-tuned by the FiLM sweep (``finetune_dir``: default the model's folder) at their chosen rate,
    and with ``blend`` (2 or 3 barycentric weights) a blend of the first 2 or 3 of them. A new style
    whose closed-loop check failed at every rate (:func:`jaxstyle.output.check.failed_check`) is
    refused with one line, unless ``allow_failed``: then its title carries
    :data:`jaxstyle.output.check.FAILED_MARK`."""
    model, data = loaded.model, loaded.data
    film_model = model.config.modulation == "film"
    out = []
    if styles:
        vectors = train_lpn.film_vectors(model.params, model.data) if film_model else None
        for name in styles:
            if name not in model.data.styles:
                raise PipelineError(f"unknown style {name!r}; the model has {', '.join(model.data.styles)}")
            s = model.data.styles.index(name)
            runtime = vectors[s] if film_model else style_models.style_runtime(model.params, model.config, s)
            out.append(Character(name, name, runtime, data.base, name))
    if new_styles:
        folder = Path(finetune_dir or loaded.directory)
        files = [folder / "chosen_rates.json", folder / "finetuned_generators.npz"]
        if not film_model:
            raise PipelineError(f"{model.name}: only a FiLM model learns new styles (its generator is fine-tuned)")
        if data.new is None or not all(f.is_file() for f in files):
            raise PipelineError(f"no fine-tuned new styles in {folder}: run `jaxstyle lpn` with --finetune-steps > 0")
        chosen = json.loads(files[0].read_text())
        new = styledata.style_data(data.new, data.skeleton, base=data.base, backbone=model.config.backbone)
        gens = _generators(model, files[1])
        for name in new_styles:
            if name not in chosen or name not in new.styles:
                raise PipelineError(f"unknown new style {name!r}; {folder} has {', '.join(chosen) or 'none'}")
            failed = failed_check(chosen[name], name)
            if failed and not allow_failed:
                raise PipelineError(refusal("new style", failed))
            s = new.styles.index(name)
            runtime = finetune.tuned_film_vector(gens, s, int(chosen[name]["rate_index"]),
                                                 new.clips[new.train_clips[s]])
            mark = FAILED_MARK if failed else ""
            out.append(Character(f"{name} (fine-tuned, rate {chosen[name]['rate']:g}){mark}", name, runtime,
                                 data.new, name))
    if blend is not None:
        k = len(blend)
        if len(out) < k:
            raise PipelineError(f"a blend of {k} styles needs {k} styles to blend, got {len(out)}")
        try:
            out.append(drive.blend_character(loaded.character_model(), out[:k], blend))
        except ValueError as e:
            raise PipelineError(f"blend weights {list(blend)}: {e}") from None
    if not out:
        raise PipelineError("no styles to drive")
    return out


def measure_quality(loaded: Loaded, styles: Sequence[str], new_styles: Sequence[str] = (), *,
                    allow_failed: bool = False, **kwargs):
    """The quality benchmark's rows of a loaded model's characters (:func:`characters`: its
    training ``styles`` as ``base``, the fine-tuned ``new_styles`` as ``few-shot``; ``allow_failed``
    as there), driven and measured by :func:`jaxstyle.output.quality.run` (``kwargs``: its
    ``path_names``, ``seconds`` ...). ``jaxstyle demo --model lpn-film``, ``experiments/quality.py``
    and :func:`style_check` use it."""
    from jaxstyle.output import quality

    chars = characters(loaded, styles=styles, new_styles=new_styles, allow_failed=allow_failed)
    subjects = [quality.subject(c, "base" if i < len(styles) else "few-shot", loaded.model.name)
                for i, c in enumerate(chars)]
    return quality.run(loaded.character_model(), subjects, loaded.data.skeleton, **kwargs)


STYLE_CHECK_SECONDS = 8.0
"""How long :func:`style_check` walks each character (the quality benchmark's length)."""


def style_check(loaded: Loaded, styles: Sequence[str], new_styles: Sequence[str] = (), *,
                seconds: float | None = None) -> list[dict]:
    """Every training style (and fine-tuned new style, its check's failure marked, not refused) of a
    freshly trained model walked ``seconds`` along the straight path at its own speed with the
    default runtime (``seconds``: default :data:`STYLE_CHECK_SECONDS`), measured as the quality benchmark
    measures (:func:`measure_quality`): its rows
    (one per character, then its capture's). ``jaxstyle lpn`` prints them
    (:func:`jaxstyle.mason2022.report.style_check_table`) so that a run says which of its styles
    step and which hold one pose or glide (``not_stepping``,
    :func:`jaxstyle.output.quality.stepping_figures`); the test loss cannot tell them apart."""
    return measure_quality(loaded, styles, new_styles, allow_failed=True, path_names=("straight",),
                           seconds=STYLE_CHECK_SECONDS if seconds is None else seconds).rows


def rate_check(loaded: Loaded, result: finetune.FinetuneResult, *, seconds: float | None = None) -> np.ndarray:
    """``(S, R)``: the lifted-step ratio (``lifted_step_ratio``: lifted steps per second over the
    capture's, where the path asks the character to move; NaN where it diverged) of every (new
    style, rate) pair of a FiLM fine-tuning sweep (``result``, held in memory: nothing is read from
    the folder), each walked as :func:`style_check` walks a style (``seconds`` along the straight
    path at its own speed, default runtime), all in one batched rollout."""
    from jaxstyle.output import quality

    new, chars, where = result.data, [], {}
    for s, name in enumerate(result.styles):
        clips = new.clips[new.train_clips[s]]
        for r, rate in enumerate(result.rates):
            title = f"{name} (fine-tuned, rate {rate:g})"
            where[title] = (s, r)
            vector = finetune.tuned_film_vector(result.generators, s, r, clips)
            chars.append(Character(title, f"{name}_rate_{r}", vector, loaded.data.new, name))
    subjects = [quality.subject(c, "few-shot", loaded.model.name) for c in chars]
    rows = quality.run(loaded.character_model(), subjects, loaded.data.skeleton, path_names=("straight",),
                       seconds=STYLE_CHECK_SECONDS if seconds is None else seconds).rows
    out = np.full((len(result.styles), len(result.rates)), np.nan)
    for row in rows:
        if row["path"] != "capture" and row["style"] in where:
            out[where[row["style"]]] = row.get("lifted_step_ratio", np.nan)
    return out


def stepping_rates(validation_loss_SxR: np.ndarray, lifted_ratio_SxR: np.ndarray) -> np.ndarray:
    """Per new style the index of the rate :func:`choose_stepping_rates` takes: the lowest
    validation loss among the rates whose walk lifts its feet within 25% of the capture's rate;
    when none does, among those that step (a ratio of at least
    :data:`jaxstyle.output.quality.STEP_RATIO`); when none steps, among all rates
    (:func:`jaxstyle.output.check.choose_rates`, which keeps the first rate when no loss is finite)."""
    from jaxstyle.output.check import choose_rates
    from jaxstyle.output.quality import STEP_RATIO

    ratio = np.asarray(lifted_ratio_SxR, dtype=float)
    within = np.abs(ratio - 1.0) <= 0.25
    stepping = ratio >= STEP_RATIO
    allowed = np.where(within.any(axis=1, keepdims=True), within,
                       np.where(stepping.any(axis=1, keepdims=True), stepping, True))
    return choose_rates(validation_loss_SxR, allowed)[0]


def choose_stepping_rates(loaded: Loaded, result: finetune.FinetuneResult, *,
                          seconds: float | None = None) -> finetune.FinetuneResult:
    """``result`` (a FiLM fine-tuning sweep of :func:`jaxstyle.mason2022.finetune.generator_sweep`
    on ``loaded``'s model) with each new style's rate chosen by :func:`stepping_rates` from the walk
    of every pair (:func:`rate_check`, recorded as ``lifted_step_ratio``) and the validation loss
    (MSE + bone-length loss), rather than by the validation loss alone.

    Not in the paper, which does not say how a new style's fine-tuning is stopped or regularised.
    Why: on two 30-epoch models the validation loss always took the lowest dropout swept, and in 5
    of their 6 (model, new style) pairs another rate's walk came closer to the capture's stepping
    rate; fine-tuning longer without dropout (600 steps, lower test MSE still) left every new style
    frozen (docs/mason2022.md, "New styles that step")."""
    ratios = rate_check(loaded, result, seconds=seconds)
    validation = result.after["validation"]
    chosen = stepping_rates(validation["mse"] + validation["bll"], ratios)
    return dataclasses.replace(result, chosen=chosen, lifted_step_ratio=ratios)


class EpochChoice(NamedTuple):
    """What :func:`choose_epoch` did: the ``epoch`` chosen of a run trained ``trained_epochs``
    epochs, the ``model`` with that epoch's weights, and per epoch compared its ``ratios``
    (``{epoch: {style: lifted_step_ratio}}`` of :func:`style_check`)."""

    epoch: int
    trained_epochs: int
    model: pipeline.Model
    ratios: dict[int, dict[str, float]]


def epoch_score(ratios: dict[str, float]) -> tuple[int, int]:
    """How :func:`choose_epoch` ranks an epoch by its training styles' lifted-step ratios on the
    check: the number of styles within 25% of their captures' lifted steps per second (the
    benchmark's steps target), then minus the number not stepping
    (:data:`jaxstyle.output.quality.STEP_RATIO`); a style without a figure counts as neither."""
    from jaxstyle.output.quality import STEP_RATIO

    r = np.array([v for v in ratios.values() if np.isfinite(v)], dtype=np.float64)
    return int(np.sum(np.abs(r - 1.0) <= 0.25)), -int(np.sum(r < STEP_RATIO))


def choose_epoch(model: pipeline.Model, data: pipeline.LPNData, directory: str | os.PathLike, *,
                 epochs: int = CHOOSE_EPOCHS, seconds: float | None = None, reuse: bool = True) -> EpochChoice:
    """The model of a finished :func:`jaxstyle.mason2022.pipeline.train_model` run in ``directory``
    taken from the epoch, of its last ``epochs`` kept, whose training styles step best in the closed
    loop: each epoch's weights drive every training style along the closing check's straight line
    (:func:`style_check`, ``seconds``) and are ranked by :func:`epoch_score`; a tie goes to the later
    epoch. The choice is recorded in the folder (:data:`jaxstyle.mason2022.pipeline.CHOSEN_EPOCH_FILE`),
    so that :func:`load_model`, ``jaxstyle synthesize`` and a rerun of ``jaxstyle lpn`` load that
    epoch; the new styles are then fine-tuned on it. With ``reuse``, a choice already recorded for
    this training is returned as it was made (its ratios read back), without driving again.

    Not in the paper (which takes the last epoch): validation-based checkpoint selection, with a
    closed-loop validation because the test loss does not say which epochs step. Why: at the
    paper's size the closed loop changes from one epoch to the next as much as between seeds; on
    three 30-epoch runs the epoch this ranks first among the last three was the one with the most
    training-style rows of the quality benchmark stepping within 25% and the fewest not stepping
    (docs/mason2022.md, "Choosing the epoch"). The check's straight line is
    one of the quality benchmark's six paths, so the benchmark's straight rows are not independent
    of the choice; the docs give the figures without them too. With a single epoch kept (or
    ``epochs=1``) ``model`` comes back as it is, with empty ``ratios``, and nothing is recorded.
    Refused (ValueError) under several JAX processes, as :func:`jaxstyle.mason2022.train.averaged_params`."""
    if jax.process_count() > 1:
        raise ValueError("choosing the epoch reads earlier epochs' checkpoints back, which a process of several does "
                         "not restore: train with one process, or keep the last epoch")
    directory = Path(directory)
    config, styles, dtype = _saved_run(directory)
    kept = train_lpn.saved_epochs(directory, config, styles, compute_dtype=dtype)
    if not kept:
        raise PipelineError(f"{directory} has no checkpoint yet: finish training it first")
    if epochs < 1:
        raise ValueError(f"epochs must be >= 1, got {epochs}")
    trained = kept[-1]
    if len(kept[-epochs:]) < 2:  # nothing to choose from: the last epoch, nothing driven or recorded
        return EpochChoice(trained, trained, model, {})
    def weights(epoch):
        return train_lpn.load(directory, config, styles, compute_dtype=dtype, epoch=epoch).params

    record = pipeline.chosen_record(directory, trained) if reuse else None
    if record is not None:  # chosen for this training already
        ratios = {int(e): {s: np.nan if v is None else float(v) for s, v in r.items()}
                  for e, r in record.get("lifted_step_ratio", {}).items()}
        return EpochChoice(record["epoch"], trained, model._replace(params=weights(record["epoch"])), ratios)
    ratios, best = {}, None
    for epoch in kept[-epochs:]:  # one epoch's weights in memory beside the best so far
        candidate = Loaded(model._replace(params=weights(epoch)), data, directory, epoch)
        rows = style_check(candidate, list(model.data.styles), seconds=seconds)
        ratios[epoch] = {r["style"]: float(r.get("lifted_step_ratio", np.nan)) for r in rows if r["path"] != "capture"}
        if best is None or (*epoch_score(ratios[epoch]), epoch) >= (*epoch_score(ratios[best.epochs]), best.epochs):
            best = candidate
    pipeline.write_chosen_record(directory, {
        "epoch": best.epochs, "trained_epochs": trained, "rule": "most training styles with lifted steps within 25% "
        "of the capture's on the closing check, then fewest not stepping, then the later epoch",
        "lifted_step_ratio": {str(e): {s: round(v, 4) for s, v in r.items()} for e, r in ratios.items()}})
    return EpochChoice(best.epochs, trained, best.model, ratios)
