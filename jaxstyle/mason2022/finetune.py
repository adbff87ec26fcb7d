"""New styles for a trained 2022 model (Mason, Starke & Komura 2022 section 5): its FiLM generator
alone fine-tuned on a new style's clips for every (new style, dropout rate) pair in one compiled
``vmap`` x ``vmap`` of :func:`jaxstyle.train.scan.train_scan`, as the 2018 few-shot sweep
(:func:`finetune_film_sweep`; tested with the model as it was by :func:`generator_sweep`), every
pair validated and driven closed-loop with the model's
:class:`jaxstyle.control.lpn_controller.StyleNetModel` (:func:`closed_loop_check`; the measures,
pass rule and rate choice are the 2018 sweep's, :mod:`jaxstyle.output.check`), the user's own clips
as new styles (:func:`user_clip_data`, :func:`finetune_clips`), and the files written
(:func:`write_finetune`, :func:`load_generator`).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.data import datasets
from jaxstyle.data.folders import PipelineError, user_clip_specs
from jaxstyle.mason2022 import styledata
from jaxstyle.mason2022 import train as train_lpn
from jaxstyle.mason2022.loss import Batch, LossWeights, batch_loss
from jaxstyle.mason2022.pipeline import LPNData, Model
from jaxstyle.mason2022.styledata import StaticBones, StyleData, bones_of, device_arrays
from jaxstyle.nn import film_generator as film
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.output.check import Judging, StyleStart, check_pairs, choose_rates, failed_criteria
from jaxstyle.train import scan
from jaxstyle.train.checkpoint import json_text
from jaxstyle.train.defaults import BODY_SMOOTH, FILM_DEFAULT_RATES, FOOT_SMOOTH, ROLLOUT_FIELDS, RolloutCheck

"""Dropout rates of the FiLM fine-tuning sweep."""


# --- the sweep: the FiLM generator fine-tuned for every (new style, dropout rate) ----------------


@dataclasses.dataclass(frozen=True)
class FiLMFinetuneConfig:
    """Fine-tuning of the FiLM generator on new styles, every style x dropout rate in one program."""

    epochs: int = 10
    batch_size: int = 32
    learning_rate: float = 1e-4
    rates: tuple[float, ...] = FILM_DEFAULT_RATES
    bone_loss_weight: float = 1.0
    max_steps: int | None = None
    seed: int = 0


def finetune_batches(data: StyleData, config: FiLMFinetuneConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(S, T, B)`` rows, ``(S, T)`` clips and ``(S, T)`` masks for every style of ``data``: the
    few-shot sweep's per-style batches (:func:`jaxstyle.train.scan.sweep_batches`), capped at
    ``max_steps``, with one random training clip of the style per step."""
    batches, mask = scan.sweep_batches(data.train_rows, config.epochs, config.batch_size, config.seed)
    if config.max_steps is not None:
        batches, mask = batches[:, :config.max_steps], mask[:, :config.max_steps]
    clips = np.stack([np.random.default_rng([config.seed, s, 11]).choice(c, size=batches.shape[1])
                      for s, c in enumerate(data.train_clips)]).astype(np.int32)
    return batches, clips, mask


@dataclasses.dataclass(frozen=True)
class GeneratorLoss:
    """The loss of one (style, rate) cell of :func:`finetune_film_sweep` for
    :func:`jaxstyle.train.scan.grid_sweep`: the trainable tree is the FiLM generator, ``frozen``
    ``{"params": the network without "style", "arrays": (x, y, gate, clips)}``, the step input
    ``(rows, clip)``, ``hparams`` ``{"weight"}`` (the bone-length loss weight)."""

    config: StyleModelConfig
    bones: StaticBones

    def __call__(self, generator, frozen, inputs, key, rate, hparams):
        idx, clip = inputs
        params = {**frozen["params"], "style": {"generator": generator}}
        return batch_loss(params, self.config, frozen["arrays"], Batch(idx, 0, clip), key,
                          LossWeights(rate, hparams["weight"]), bones_of(self.bones))[0]


class FilmSweep(NamedTuple):
    """The fine-tuned FiLM ``generators`` (leading axes ``(S, R)``: new style, dropout rate) and the
    per-step training ``losses`` ``(S, R, T)`` of :func:`finetune_film_sweep`."""

    generators: dict
    losses: np.ndarray


def finetune_film_sweep(params: dict, config: StyleModelConfig, data: StyleData,
                        finetune: FiLMFinetuneConfig = FiLMFinetuneConfig(), *, chunk_steps: int | None = None,
                        progress: bool = False, shard: bool = False) -> FilmSweep:
    """Fine-tune the FiLM generator on every style of ``data`` (new styles, normalised with the
    base statistics) at every rate of ``finetune.rates``, the synthesis network and gating frozen
    (broadcast to all pairs; gradients for the generator only). Returns generators stacked
    ``(S, R, ...)`` and per-step losses ``(S, R, T)`` (NaN on padded steps). Keys depend only on
    the seed, the style's index and the rate's index, as in the 2018 sweep; both sweeps are
    :func:`jaxstyle.train.scan.grid_sweep` with their own loss.

    ``chunk_steps`` runs the steps in chunks (one compiled program, called once per chunk, the
    last chunk padded with masked steps) so ``progress=True`` can move a bar; same result.
    ``shard=True`` spreads the style axis over all devices; same result."""
    if config.modulation != "film":
        raise ValueError(f"fine-tuning the FiLM generator needs a FiLM model, got {config.modulation!r}")
    batches, clips, mask = finetune_batches(data, finetune)
    num_styles, num_rates, steps = batches.shape[0], len(finetune.rates), batches.shape[1]
    keys = jnp.stack([jnp.stack([jax.random.split(scan.pair_key(finetune.seed, s, r), steps)
                                 for r in range(num_rates)]) for s in range(num_styles)])
    frozen = {"params": {k: v for k, v in params.items() if k != "style"}, "arrays": device_arrays(data)}
    gens = jax.tree.map(lambda v: jnp.broadcast_to(v, (num_styles, num_rates) + v.shape),
                        params["style"]["generator"])
    gens, per_step = scan.grid_sweep(
        GeneratorLoss(config, StaticBones(data.bones)), gens, frozen, scan.Steps((batches, clips), mask, keys),
        jnp.asarray(finetune.rates, jnp.float32), optimizer=finetune.learning_rate,
        hparams={"weight": jnp.float32(finetune.bone_loss_weight)},
        run=scan.GridRun(chunk_steps, shard, progress, f"FiLM fine-tuning {num_styles} styles x {num_rates} rates"))
    return FilmSweep(gens, np.asarray(per_step))


def tuned_film_vector(generators: dict, style: int, rate: int, clips_CxTxF: np.ndarray) -> np.ndarray:
    """A new style's FiLM vector under its fine-tuned generator ``(style, rate)`` of a sweep's
    ``generators`` (leading axes (new style, rate)): the mean over its ``clips`` (section 4.4)."""
    return film.clip_films(jax.tree.map(lambda v: v[style, rate], generators), clips_CxTxF).mean(axis=0)


def with_generator(params: dict, generators: dict, style: int, rate: int) -> dict:
    """``params`` with the fine-tuned generator of one (style, rate) pair of the sweep."""
    return {**params, "style": {"generator": jax.tree.map(lambda v: v[style, rate], generators)}}


@dataclasses.dataclass(frozen=True)
class FinetuneResult:
    """A FiLM fine-tuning sweep: ``generators`` with leading axes ``(style, rate)``; ``before``
    (per split: ``{"mse", "bll"}`` of shape ``(S,)``) and ``after`` (``(S, R)``) on the new styles'
    validation and test rows; the ``chosen`` rate index per style; the new styles' ``data``; when the
    rates were chosen by walking every pair (:func:`jaxstyle.mason2022.synthesis.choose_stepping_rates`),
    each pair's ``lifted_step_ratio`` ``(S, R)``."""

    styles: tuple[str, ...]
    rates: tuple[float, ...]
    generators: dict
    steps: int
    seconds: float
    before: dict[str, dict[str, np.ndarray]]
    after: dict[str, dict[str, np.ndarray]]
    chosen: np.ndarray
    data: StyleData
    lifted_step_ratio: np.ndarray | None = None

    def chosen_rate(self, style: str) -> float:
        return self.rates[int(self.chosen[self.styles.index(style)])]

    def params(self, model: Model, style: str, rate_index: int | None = None) -> dict:
        """The model with one new style's fine-tuned generator, at its chosen rate unless ``rate_index``."""
        s = self.styles.index(style)
        return with_generator(model.params, self.generators, s,
                              int(self.chosen[s]) if rate_index is None else rate_index)


SPLITS = ("validation", "test")


def generator_sweep(model: Model, data: LPNData, *, rates: Sequence[float] = FILM_DEFAULT_RATES, steps: int = 150,
                   epochs: int = 100, chunk_steps: int = 10, progress: bool = True) -> FinetuneResult:
    """Fine-tune ``model``'s FiLM generator on every new style of ``data`` at every dropout rate,
    at most ``steps`` steps each (over at most ``epochs`` epochs), in one compiled sweep
    (:func:`finetune_film_sweep`); test every pair and the model as it was on
    the new styles' validation and test rows, and choose a rate per style
    (:func:`jaxstyle.output.check.choose_rates` on validation alone)."""
    if model.config.modulation != "film":
        raise PipelineError(f"{model.name}: only a FiLM model's generator can be fine-tuned on new styles")
    if data.new is None:
        raise PipelineError("no new styles to fine-tune on")
    if steps < 1 or not rates or any(not 0 <= r < 1 for r in rates):
        raise PipelineError(f"need steps >= 1 and dropout rates in [0, 1), got {steps} and {list(rates)}")
    new = styledata.style_data(data.new, data.skeleton, base=data.base, backbone=model.config.backbone)
    config = FiLMFinetuneConfig(rates=tuple(float(r) for r in rates), max_steps=steps, epochs=epochs)
    t0 = time.perf_counter()
    gens, per_step = finetune_film_sweep(model.params, model.config, new, config, chunk_steps=chunk_steps,
                                                   progress=progress)
    seconds = time.perf_counter() - t0
    shape = (len(new.styles), len(config.rates))
    before = {split: train_lpn.evaluate(model.params, model.config, new, split) for split in SPLITS}
    after = {split: {"mse": np.full(shape, np.nan), "bll": np.full(shape, np.nan)} for split in SPLITS}
    for s in range(shape[0]):
        for r in range(shape[1]):
            tuned = with_generator(model.params, gens, s, r)
            for split in SPLITS:
                losses = train_lpn.evaluate(tuned, model.config, new, split, styles=[s])
                for k in ("mse", "bll"):
                    after[split][k][s, r] = losses[k][0]
    chosen, _ = choose_rates(after["validation"]["mse"] + after["validation"]["bll"])
    return FinetuneResult(tuple(new.styles), config.rates, gens, int(per_step.shape[2]), seconds, before, after,
                          chosen, new)



def user_clip_data(data: LPNData, clips: Sequence[str | os.PathLike], *, mirror: bool = True,
                   seconds: tuple[float, float] | None = None, joint_map=None,
                   cache: str | os.PathLike | None = None, progress: bool = False) -> LPNData:
    """``data`` with its new styles replaced by the user's BVH ``clips`` (one new style per file,
    named by its stem, mirrored unless ``mirror`` is false, ``seconds`` = (start, end) of each;
    :func:`jaxstyle.data.folders.user_clip_specs`), as ``jaxstyle sweep --clip`` does for the 2018
    adapters. A clip of another skeleton, or too short to give a style clip (240 frames) inside
    its training rows and some validation rows, is refused in one line naming the file."""
    specs = user_clip_specs(clips, mirror, seconds, joint_map)
    names, base_file = tuple(data.skeleton.names), data.base.specs[0].path
    for spec in specs:
        if spec.mirror:
            continue
        motion = datasets.load_clip(spec)
        if tuple(motion.names) != names:
            detail = (f"{motion.num_joints} joints" if motion.num_joints != len(names) else
                      "joint {} is {!r} where the model's is {!r}".format(
                          *next((i, a, b) for i, (a, b) in enumerate(zip(motion.names, names, strict=True))
                                if a != b)))
            raise PipelineError(f"clip {spec.path}: its skeleton has {detail}; the model was trained on "
                                f"{len(names)} joints ({base_file}): give a clip of the model's skeleton")
        need = datasets.min_frames(motion.fps)
        if motion.num_frames < need:
            raise PipelineError(f"clip {spec.path}: {motion.num_frames} frames ({motion.num_frames / motion.fps:.1f} s)"
                                f" are shorter than the trajectory window ({need} frames, {need / motion.fps:.1f} s)")
    new = datasets.build_lpn_dataset(specs, cache_dir=cache, progress=progress)
    for spec in specs:
        if spec.mirror:
            continue
        frames = int(np.sum(new.clip == new.specs.index(spec)))
        if len(new.clips_of_style(spec.style, "train")) == 0 or len(new.rows_of_style(spec.style, "validation")) == 0:
            raise PipelineError(f"clip {spec.path}: {frames} rows give no {new.clips.shape[1]}-frame style clip inside "
                                "its training rows (80% of the clip) or no validation rows: give a longer clip "
                                f"(about {_min_clip_seconds(new.clips.shape[1]):.0f} s or more)")
    return LPNData(data.base, new, data.skeleton)


def _min_clip_seconds(clip_frames: int, fps: float = 60.0) -> float:
    """A rough length that gives a style clip in the training block: the trajectory window, the
    clip over the 80% training share, one clip stride for its alignment."""
    return (datasets.min_frames(fps) + clip_frames / 0.8 + clip_frames / 2) / fps




def closed_loop_check(model: Model, result: "FinetuneResult", data: LPNData,
                      check: RolloutCheck | None = None) -> dict[str, np.ndarray]:
    """Drive every (new style, rate) of a fine-tuning sweep and, per new style, the model before
    fine-tuning (:func:`jaxstyle.output.check.check_pairs`, one batched rollout); returns ``(S, R)``
    arrays named by :data:`jaxstyle.train.defaults.ROLLOUT_FIELDS` and per style ``(S,)`` references
    ``real_contact_fraction``, ``speed_m_s``, ``base_skating_m_s``, ``base_bone_error`` (see
    :class:`jaxstyle.train.defaults.RolloutCheck`; the measures and the pass rule are the 2018 sweep's,
    :mod:`jaxstyle.output.check`). Each style starts at the first frame of its first training clip
    (:meth:`jaxstyle.control.lpn_controller.StyleNetModel.initial_state`: that frame's pose, local
    and global phases); the capture's feet are measured on that clip's BVH. The characters run the
    default runtime, local phases floored (:data:`jaxstyle.train.defaults.PHASE_FLOOR`) and the
    feet's blend :data:`jaxstyle.train.defaults.FOOT_SMOOTH` and the other bones'
    :data:`jaxstyle.train.defaults.BODY_SMOOTH`, as synthesis does."""
    check = check or RolloutCheck()
    from jaxstyle.control import lpn_controller
    from jaxstyle.labels.contacts import FootJoints, estimate_units_per_meter, floor_heights
    from jaxstyle.motion.kinematics import UP_AXIS, global_positions
    from jaxstyle.output import metrics

    new, skeleton, raw = result.data, data.skeleton, data.new
    upm, fps = estimate_units_per_meter(skeleton), float(skeleton.fps)
    num_rates = len(result.rates)
    feet = list(FootJoints.find(skeleton).ankles) + list(FootJoints.find(skeleton).toes)
    gen0 = model.params["style"]["generator"]
    character = lpn_controller.StyleNetModel.create(model.params, model.config, data.base.normalisers(), skeleton,
                                                    foot_smooth=FOOT_SMOOTH, body_smooth=BODY_SMOOTH)
    starts, styles = [], []
    for s in range(len(result.styles)):
        rows = new.train_rows[s]
        first_clip = int(raw.clip[rows].min())
        real = global_positions(datasets.load_clip(raw.specs[first_clip]))
        floor = floor_heights(real[:, feet, UP_AXIS])
        contact = metrics.positions_foot_stats(real, skeleton, fps, floor, units_per_meter=upm,
                                               tolerance_m=check.tolerance_m).contact_fraction
        clip_rows = rows[raw.clip[rows] == first_clip]
        start = clip_rows[np.argmin(raw.frame[clip_rows])]
        speed = character.own_speed(raw, rows, upm, fps) * upm  # file units / s
        starts.append(StyleStart(character.initial_state(raw, start), speed, floor, contact))
        clips = new.clips[new.train_clips[s]]
        styles.append([tuned_film_vector(result.generators, s, r, clips) for r in range(num_rates)]
                      + [film.clip_films(gen0, clips).mean(axis=0)])
    out, base = check_pairs(character, styles, starts, Judging(skeleton, fps, upm, check))
    ref = {"real_contact_fraction": np.array([s.contact_fraction for s in starts]),
           "speed_m_s": np.array([s.speed for s in starts]) / upm}
    return {**out, **ref, **base}


class FinetunedClips(NamedTuple):
    """:func:`finetune_clips`' sweep ``result``, the closed-loop ``checked`` figures of every pair
    (:func:`closed_loop_check`, with ``chosen_passed`` per style) and the ``files`` written."""

    result: FinetuneResult
    checked: dict[str, np.ndarray]
    files: dict[str, Path]


def finetune_clips(model: Model, data: LPNData, directory: str | os.PathLike, *,
                   rates: Sequence[float] = FILM_DEFAULT_RATES, steps: int = 150, epochs: int = 100,
                   check: RolloutCheck | None = None, progress: bool = True
                   ) -> FinetunedClips:
    """New styles from the user's clips (``data.new``, :func:`user_clip_data`) the 2022 way: the
    FiLM generator alone fine-tuned for every (clip style, rate) in one compiled sweep
    (:func:`generator_sweep`), every pair validated and driven closed-loop
    (:func:`closed_loop_check`), a rate chosen per style (:func:`jaxstyle.output.check.choose_rates`), and written to
    ``directory``: :func:`write_finetune`'s files (every generator, ``chosen_rates.json`` with the
    check), ``generators/<style>.npz`` (the chosen generator alone, :func:`load_generator` reads it)
    and ``clips.json`` (the clips, the rates, the base clips: enough to rebuild the new styles' rows)."""
    result = generator_sweep(model, data, rates=rates, steps=steps, epochs=epochs, progress=progress)
    check = check or RolloutCheck()
    checked = closed_loop_check(model, result, data, check)
    val = result.after["validation"]["mse"] + result.after["validation"]["bll"]
    chosen, passed = choose_rates(val, checked["passed"])
    result = dataclasses.replace(result, chosen=chosen)
    directory = Path(directory)
    paths = write_finetune(result, directory)
    saved = json.loads(paths["chosen"].read_text())
    for s, style in enumerate(result.styles):
        saved[style]["check_passed"] = bool(passed[s])
        saved[style]["check"] = {k: _number(checked[k][s, chosen[s]]) for k in ROLLOUT_FIELDS}
        if not passed[s]:  # every rate failed: what the chosen one failed, for the refusal
            saved[style]["failed"] = failed_criteria(
                {k: float(checked[k][s, chosen[s]]) for k in ROLLOUT_FIELDS if k != "passed"},
                float(checked["real_contact_fraction"][s]), float(checked["base_skating_m_s"][s]),
                float(checked["speed_m_s"][s]), check)
    paths["chosen"].write_text(json_text(saved))
    (directory / "generators").mkdir(parents=True, exist_ok=True)
    for style in result.styles:
        path = directory / "generators" / f"{style}.npz"
        gen = result.params(model, style)["style"]["generator"]
        np.savez(path, **{jax.tree_util.keystr(k): np.asarray(v) for k, v in jax.tree_util.tree_leaves_with_path(gen)})
        paths[f"generator {style}"] = path
    paths["clips"] = directory / "clips.json"
    paths["clips"].write_text(json_text({"model": model.name, "rates": list(result.rates), "steps": result.steps,
                                         "new": [dataclasses.asdict(s) for s in data.new.specs],
                                         "base": [dataclasses.asdict(s) for s in data.base.specs]}))
    return FinetunedClips(result, {**checked, "chosen_passed": passed}, paths)


def load_generator(path: str | os.PathLike, like: dict) -> dict:
    """A generator written by :func:`finetune_clips` (``generators/<style>.npz``) in the tree
    structure of ``like`` (the model's generator), e.g. to drive the new style later."""
    with np.load(path) as z:
        leaves = [z[jax.tree_util.keystr(k)] for k, _ in jax.tree_util.tree_leaves_with_path(like)]
    return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(like), leaves)


def write_finetune(result: FinetuneResult, directory: str | os.PathLike) -> dict[str, Path]:
    """Write ``finetuned_generators.npz`` (every generator, leading axes (new style, rate)) and
    ``chosen_rates.json`` (per new style its chosen rate and losses, and each rate's walk's
    ``lifted_step_ratio`` when the rates were chosen by walking) into ``directory``."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = {"generators": directory / "finetuned_generators.npz", "chosen": directory / "chosen_rates.json"}
    leaves = jax.tree_util.tree_leaves_with_path(result.generators)
    np.savez(paths["generators"], **{jax.tree_util.keystr(path): np.asarray(v) for path, v in leaves})
    chosen = {}
    for s, style in enumerate(result.styles):
        c = int(result.chosen[s])
        chosen[style] = {"rate": result.rates[c], "rate_index": c,
                         **{f"{split}_{k}": _number(result.after[split][k][s, c]) for split in SPLITS
                            for k in ("mse", "bll")}}
        if result.lifted_step_ratio is not None:
            chosen[style]["lifted_step_ratio"] = {f"{r:g}": _number(result.lifted_step_ratio[s, i])
                                                  for i, r in enumerate(result.rates)}
    paths["chosen"].write_text(json_text(chosen))
    return paths


def _number(value) -> float | None:
    return float(value) if np.isfinite(value) else None
