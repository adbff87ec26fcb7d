"""The 2022 workflow: a style folder, a style model, its FiLM generator fine-tuned on new styles.

Mason, Starke & Komura 2022 end to end, in the shape of :mod:`jaxstyle.mason2018.pipeline`, on any
folder in the 100STYLE layout (:mod:`jaxstyle.data.folders`):

1. data: :func:`build_data` builds the LPN rows of the training styles and of the new styles (the
   latter normalised later with the training styles' statistics, as both papers do), every row
   with its local phases and its global phase; :func:`user_clip_data` makes the user's own BVH
   clips the new styles;
2. train: :func:`model_config` sizes any of Table 2's seven models for the data and
   :func:`train_model` trains it into a folder (or resumes, or reloads it); :func:`train_for`
   trains within a wall-clock :class:`Budget` (whole epochs, early stop once validation has
   flattened); :func:`model_losses`;
3. sweep: :func:`finetune_sweep` fine-tunes the FiLM generator alone for every (new style, dropout
   rate) pair in one compiled program, then tests every pair and the model before fine-tuning;
   :func:`finetune_clips` adds a closed-loop check of every pair with the 2022 controller
   (:func:`closed_loop_check`) and writes the chosen generators;
4. select: :func:`jaxstyle.output.check.choose_rates` (the 2018 sweep's rule) keeps per new style
   the rate of the lowest validation MSE + bone-length loss (a style without validation rows keeps
   the first rate), among the rates that passed the check when there is one;
5. report: Markdown lines (:func:`losses_table`, :func:`models_table`, :func:`budget_table`,
   :func:`ordering_lines`, :func:`finetune_summary`, :func:`finetune_table`, :func:`check_table`)
   and files (:func:`write_finetune`: the generators and chosen rates; :func:`curves_figure`:
   validation curves of several models; :func:`film_figure`: the paper's Figure 11 with PCA).

``jaxstyle lpn`` (:mod:`jaxstyle.cli.lpn`) and ``experiments/mason2022_styles.py`` are this pipeline.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
import warnings
from pathlib import Path
from typing import NamedTuple, Sequence

import jax
import numpy as np

from jaxstyle.data import datasets
from jaxstyle.data.folders import PipelineError, clip_specs, portable_path, user_clip_specs
from jaxstyle.mason2022 import train as train_lpn
from jaxstyle.motion import Motion
from jaxstyle.nn import film_generator as film
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.output import viz
from jaxstyle.output.check import choose_rates
from jaxstyle.train import defaults
from jaxstyle.train.checkpoint import json_text
from jaxstyle.train.defaults import FILM_DEFAULT_RATES

PAPER_NEW_STYLES = ("Elated", "Rushed")
"""The new (held-out) styles of ``experiments/mason2022_styles.py`` in the shared 100STYLE sample."""
FINETUNE_RATES = FILM_DEFAULT_RATES
"""Dropout rates of the FiLM fine-tuning sweep."""
MODEL = "LPN FiLM"
"""The paper's model, the one whose FiLM generator is fine-tuned on new styles."""


# --- data ---------------------------------------------------------------------------------------

class LPNData(NamedTuple):
    """The LPN rows of the training styles (``base``) and the ``new`` styles, and a clip of the skeleton."""

    base: datasets.Dataset
    new: datasets.Dataset | None
    skeleton: Motion


def build_data(root: str | os.PathLike, styles: Sequence[str], new_styles: Sequence[str] = (), *,
               gaits: Sequence[str] | None = None, max_seconds: float | None = None,
               cache: str | os.PathLike | None = None, progress: bool = False, joint_map=None) -> LPNData:
    """LPN rows (cached) of ``styles`` and ``new_styles`` of the style folder ``root``
    (:func:`jaxstyle.data.folders.clip_specs`: ``gaits``, ``max_seconds``, ``joint_map``); short
    clips skipped."""
    root = Path(root)
    def build(names):
        return datasets.build_lpn_dataset(clip_specs(root, names, gaits, max_seconds, joint_map), cache_dir=cache,
                                          skip_short=True, progress=progress)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # short clips are skipped with a warning
        base = build(styles)
        new = build(new_styles) if new_styles else None
    return LPNData(base, new, datasets.load_clip(base.specs[0]))


# --- train --------------------------------------------------------------------------------------

class Model(NamedTuple):
    """A trained style model: its Table 2 ``name``, ``config``, ``params`` and training ``data``."""

    name: str
    config: StyleModelConfig
    params: dict
    data: train_lpn.StyleData


def model_config(dataset: datasets.Dataset, name: str = MODEL, *, hidden: int = 512, generator_hidden: int = 2048,
                 filters: int = 256) -> StyleModelConfig:
    """Table 2's model ``name`` for the styles and layout of an LPN ``dataset``: ``hidden`` units
    (paper: 512), a FiLM generator of ``generator_hidden`` dense units (2048) and ``filters``
    convolution filters (256) reading the dataset's style clips.

    Every backbone predicts the dataset's whole output row (342 values on 100STYLE), where the
    paper's PFNN predicts 327 and its MANN 326 (:meth:`StyleModelConfig.paper`): with one output
    layout the test MSE of the seven models is over the same values and so comparable; the extra
    local-phase outputs of the PFNN and MANN rows are simply not fed back at runtime. The PFNN
    backbones' expert blend is the row's global phase (:func:`jaxstyle.mason2022.train.style_data`)."""
    paper = StyleModelConfig.paper(name, len(dataset.styles))
    if paper.backbone == "pfnn" and len(dataset.global_phase) != len(dataset.inputs):
        raise PipelineError(f"{name}: the PFNN backbone needs a global phase per row; this dataset (or its cache) "
                            "has none: build it again with jaxstyle.data.datasets.build_lpn_dataset")
    gen = film.FiLMConfig(clip_frames=dataset.clips.shape[1], clip_features=dataset.clips.shape[2], filters=filters,
                          hidden=generator_hidden, film_size=4 * hidden)
    return dataclasses.replace(paper, hidden_size=hidden, input_size=dataset.inputs.shape[1],
                               output_size=dataset.outputs.shape[1], generator=gen)


def train_model(data: LPNData, config: StyleModelConfig, directory: str | os.PathLike, *, name: str = MODEL,
                epochs: int = 6, progress: bool = True, devices: str | int | None = None,
                compute_dtype: str = "float32", **train_options) -> Model:
    """Train (or resume, or reload) a style model on the training styles into ``directory``
    (:func:`jaxstyle.mason2022.train.train`: style-balanced batches, the paper's optimiser;
    ``train_options``: other :class:`jaxstyle.mason2022.train.LPNTrainConfig` fields, e.g. the demo's
    ``learning_rate``; ``devices`` / ``compute_dtype``: data-parallel devices and bfloat16 products,
    as :func:`jaxstyle.mason2022.train.train`)."""
    style_data = train_lpn.style_data(data.base, data.skeleton, backbone=config.backbone)
    write_data_file(data, directory, name)
    state = train_lpn.train(style_data, train_lpn.LPNTrainConfig(model=config, epochs=epochs, **train_options),
                            directory, progress=progress, devices=devices, compute_dtype=compute_dtype)
    return Model(name, config, state["params"], style_data)


def write_data_file(data: LPNData, directory: str | os.PathLike, name: str = MODEL) -> Path:
    """``directory/data.json``: the model's ``name`` and the clips of its training and new styles,
    what :func:`jaxstyle.mason2022.synthesis.load_model` rebuilds the data (normalisers, style clips,
    skeleton) from."""
    path = Path(directory) / "data.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    def portable(specs):  # paths inside the run folder relative to this one (a run can be copied or moved)
        return [{**dataclasses.asdict(s), "path": portable_path(s.path, path.parent)} for s in specs]

    path.write_text(json_text({"name": name, "base": portable(data.base.specs),
                               "new": [] if data.new is None else portable(data.new.specs)}))
    return path


def model_losses(model: Model, split: str = "test") -> dict[str, np.ndarray]:
    """``{"mse", "bll"}`` per training style on ``split``'s rows (bone-length loss in metres)."""
    return train_lpn.evaluate(model.params, model.config, model.data, split)


# --- training within a time budget -------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Budget:
    """How :func:`train_for` spends a wall-clock budget: whole epochs while the next one (predicted
    to last as long as the last one) still fits in ``seconds``, at least one, at most
    ``max_epochs`` (the paper: 90), and stop early once validation has flattened: the best
    validation loss (MSE + bone-length loss) of the last ``flat_epochs`` epochs is less than
    ``flat_tolerance`` (relative) below the best of the epochs before them."""

    seconds: float
    max_epochs: int = 90
    flat_epochs: int = 3
    flat_tolerance: float = 0.01


def read_log(directory: str | os.PathLike) -> dict[str, np.ndarray]:
    """The columns of a training run's ``log.csv`` (:func:`jaxstyle.mason2022.train.train`) as float
    arrays, one value per epoch; empty when there is no log yet."""
    import csv

    path = Path(directory) / "log.csv"
    if not path.is_file():
        return {}
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) if r[k] not in ("", None) else np.nan for r in rows]) for k in rows[0]} \
        if rows else {}


def flattened(validation_loss: Sequence[float], epochs: int = 3, tolerance: float = 0.01) -> bool:
    """Whether the best of the last ``epochs`` losses is less than ``tolerance`` (relative) below
    the best loss before them (needs at least ``epochs + 1`` values)."""
    v = np.asarray(validation_loss, dtype=np.float64)
    if len(v) <= epochs:
        return False
    before, last = np.nanmin(v[:-epochs]), np.nanmin(v[-epochs:])
    return bool(last > (1.0 - tolerance) * before)


class BudgetRun(NamedTuple):
    """What :func:`train_for` did: the ``model``, ``epochs`` done (in all), ``seconds`` this call,
    and why it stopped (``"flattened"``, ``"budget"`` or ``"max epochs"``)."""

    model: Model
    epochs: int
    seconds: float
    stopped: str


def train_for(data: LPNData, config: StyleModelConfig, directory: str | os.PathLike, budget: Budget, *,
              name: str = MODEL, progress: bool = True, train_config: dict | None = None) -> BudgetRun:
    """Train a style model epoch by epoch (resuming ``directory``) within ``budget`` (:class:`Budget`).

    Each epoch is one call of :func:`jaxstyle.mason2022.train.train` with ``stop_after_epochs=1``
    (the compiled step is reused; the state comes back from the epoch's checkpoint), so the
    budget is checked between epochs and a later call with a larger budget continues the run.
    ``train_config``: further :class:`jaxstyle.mason2022.train.LPNTrainConfig` fields."""
    import contextlib
    import io

    style_data = train_lpn.style_data(data.base, data.skeleton, backbone=config.backbone)
    cfg = train_lpn.LPNTrainConfig(model=config, epochs=budget.max_epochs, **(train_config or {}))
    write_data_file(data, directory, name)  # to reload the model with its data
    t0 = time.perf_counter()
    state, stopped, last_epoch_s = None, "max epochs", 0.0
    while True:
        e0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):  # "resumed from step N" after every epoch
            state = train_lpn.train(style_data, cfg, directory, progress=progress, stop_after_epochs=1)
        last_epoch_s = time.perf_counter() - e0
        log = read_log(directory)
        epochs = int(state["epoch"])
        if epochs >= budget.max_epochs:
            stopped = "max epochs"
            break
        if log and flattened(log["val_mse"] + log["val_bll"], budget.flat_epochs, budget.flat_tolerance):
            stopped = "flattened"
            break
        if time.perf_counter() - t0 + last_epoch_s > budget.seconds:
            stopped = "budget"
            break
    return BudgetRun(Model(name, config, state["params"], style_data), int(state["epoch"]),
                     time.perf_counter() - t0, stopped)


def steps_per_epoch(data: train_lpn.StyleData, batch_size: int = 32) -> int:
    """Steps of one style-balanced epoch (:func:`jaxstyle.data.batching.balanced_batches`)."""
    from jaxstyle.data.batching import balanced_batches

    return len(balanced_batches(data.train_rows, batch_size, seed=0))


def budget_table(runs: dict[str, BudgetRun], logs: dict[str, dict[str, np.ndarray]]) -> list[str]:
    """Markdown lines: per model the epochs it got in its budget and why it stopped, its minutes,
    the last epoch's training MSE and validation MSE, its best validation MSE, and every model's
    validation MSE at the epoch all of them reached (a comparison at equal epochs)."""
    common = min((len(log["epoch"]) for log in logs.values() if log), default=0)
    lines = [f"| model | epochs | stopped | minutes | train MSE (last epoch) | val MSE (last) | best val MSE | "
             f"val MSE @ epoch {common} |", "|---|---|---|---|---|---|---|---|"]
    for name, run in runs.items():
        log = logs[name]
        lines.append(f"| {name} | {run.epochs} | {run.stopped} | {run.seconds / 60:.1f} | {log['train_mse'][-1]:.4f} | "
                     f"{log['val_mse'][-1]:.4f} | {np.nanmin(log['val_mse']):.4f} | "
                     f"{log['val_mse'][common - 1]:.4f} |")
    return lines


def ordering_lines(results: dict[str, dict[str, np.ndarray]]) -> list[str]:
    """Lines: the models ranked by mean test MSE + BLL, and whether the paper's two claims about
    Figure 10 hold: every FiLM model has a lower test error than every one-hot and adapter model,
    and PFNN Resad is below LPN Resad (the CP adapter's phase dependence)."""
    total = {n: float(np.mean(r["mse"]) + np.mean(r["bll"])) for n, r in results.items()}
    ranked = sorted(total, key=total.get)
    lines = ["ranked by test MSE + BLL (lowest first): " + ", ".join(f"{n} {total[n]:.4f}" for n in ranked)]
    film_models = [n for n in total if "FiLM" in n]
    other = [n for n in total if "FiLM" not in n]
    if film_models and other:
        worst_film, best_other = max(film_models, key=total.get), min(other, key=total.get)
        holds = total[worst_film] < total[best_other]
        verdict = "holds" if holds else "does not hold"
        lines.append(f"paper: every FiLM model below every one-hot / adapter model: {verdict}"
                     f" (worst FiLM {worst_film} {total[worst_film]:.4f}, best other {best_other} "
                     f"{total[best_other]:.4f})")
    if {"PFNN Resad", "LPN Resad"} <= set(total):
        holds = total["PFNN Resad"] < total["LPN Resad"]
        lines.append(f"paper: PFNN Resad below LPN Resad: {'holds' if holds else 'does not hold'} "
                     f"({total['PFNN Resad']:.4f} vs {total['LPN Resad']:.4f})")
    return lines


def curves_figure(logs: dict[str, dict[str, np.ndarray]], path: str | os.PathLike, *, title: str = "") -> Path:
    """One figure of validation curves of several runs (``{model: read_log(...)}``): validation MSE
    against epochs (left) and against cumulative training minutes (right), log scale."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    for i, (name, log) in enumerate(logs.items()):
        if not log:
            continue
        style = {"color": f"C{i}", "marker": "o", "markersize": 3, "label": name,
                 "linestyle": "-" if "FiLM" in name else "--"}
        a.plot(log["epoch"], log["val_mse"], **style)
        b.plot(np.cumsum(log["seconds"]) / 60.0, log["val_mse"], **style)
    a.set_xlabel("epoch")
    b.set_xlabel("training minutes (2-core CPU, validation included)")
    a.set_ylabel("validation MSE (normalised outputs)")
    for ax in (a, b):
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    a.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# --- sweep and select ---------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class FinetuneResult:
    """A FiLM fine-tuning sweep: ``generators`` with leading axes ``(style, rate)``; ``before``
    (per split: ``{"mse", "bll"}`` of shape ``(S,)``) and ``after`` (``(S, R)``) on the new styles'
    validation and test rows; the ``chosen`` rate index per style; the new styles' ``data``."""

    styles: tuple[str, ...]
    rates: tuple[float, ...]
    generators: dict
    steps: int
    seconds: float
    before: dict[str, dict[str, np.ndarray]]
    after: dict[str, dict[str, np.ndarray]]
    chosen: np.ndarray
    data: train_lpn.StyleData

    def chosen_rate(self, style: str) -> float:
        return self.rates[int(self.chosen[self.styles.index(style)])]

    def params(self, model: Model, style: str, rate_index: int | None = None) -> dict:
        """The model with one new style's fine-tuned generator, at its chosen rate unless ``rate_index``."""
        s = self.styles.index(style)
        return train_lpn.with_generator(model.params, self.generators, s,
                                        int(self.chosen[s]) if rate_index is None else rate_index)


SPLITS = ("validation", "test")


def finetune_sweep(model: Model, data: LPNData, *, rates: Sequence[float] = FINETUNE_RATES, steps: int = 150,
                   epochs: int = 100, chunk_steps: int = 10, progress: bool = True) -> FinetuneResult:
    """Fine-tune ``model``'s FiLM generator on every new style of ``data`` at every dropout rate,
    at most ``steps`` steps each (over at most ``epochs`` epochs), in one compiled sweep
    (:func:`jaxstyle.mason2022.train.finetune_film_sweep`); test every pair and the model as it was on
    the new styles' validation and test rows, and choose a rate per style
    (:func:`jaxstyle.output.check.choose_rates` on validation alone)."""
    if model.config.modulation != "film":
        raise PipelineError(f"{model.name}: only a FiLM model's generator can be fine-tuned on new styles")
    if data.new is None:
        raise PipelineError("no new styles to fine-tune on")
    if steps < 1 or not rates or any(not 0 <= r < 1 for r in rates):
        raise PipelineError(f"need steps >= 1 and dropout rates in [0, 1), got {steps} and {list(rates)}")
    new = train_lpn.style_data(data.new, data.skeleton, base=data.base, backbone=model.config.backbone)
    config = train_lpn.FiLMFinetuneConfig(rates=tuple(float(r) for r in rates), max_steps=steps, epochs=epochs)
    t0 = time.perf_counter()
    gens, per_step = train_lpn.finetune_film_sweep(model.params, model.config, new, config, chunk_steps=chunk_steps,
                                                   progress=progress)
    seconds = time.perf_counter() - t0
    shape = (len(new.styles), len(config.rates))
    before = {split: train_lpn.evaluate(model.params, model.config, new, split) for split in SPLITS}
    after = {split: {"mse": np.full(shape, np.nan), "bll": np.full(shape, np.nan)} for split in SPLITS}
    for s in range(shape[0]):
        for r in range(shape[1]):
            tuned = train_lpn.with_generator(model.params, gens, s, r)
            for split in SPLITS:
                losses = train_lpn.evaluate(tuned, model.config, new, split, styles=[s])
                for k in ("mse", "bll"):
                    after[split][k][s, r] = losses[k][0]
    chosen, _ = choose_rates(after["validation"]["mse"] + after["validation"]["bll"])
    return FinetuneResult(tuple(new.styles), config.rates, gens, int(per_step.shape[2]), seconds, before, after,
                          chosen, new)


# --- new styles from the user's own clips -------------------------------------------------------

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


ClosedLoopCheck = defaults.RolloutCheck  # the 2018 sweep's check thresholds, one definition for both papers
CHECK_FIELDS = defaults.ROLLOUT_FIELDS
DEFAULT_CHECK = ClosedLoopCheck()


def closed_loop_check(model: Model, result: "FinetuneResult", data: LPNData,
                      check: ClosedLoopCheck = DEFAULT_CHECK) -> dict[str, np.ndarray]:
    """Drive every (new style, rate) of a fine-tuning sweep and, per new style, the model before
    fine-tuning, in ONE batched rollout; returns ``(S, R)`` arrays named by :data:`CHECK_FIELDS`
    and per style ``(S,)`` references ``real_contact_fraction``, ``speed_m_s``,
    ``base_skating_m_s``, ``base_bone_error`` (see :class:`ClosedLoopCheck`; the measures and the
    pass rule are the 2018 sweep's, :mod:`jaxstyle.output.check`)."""
    from jaxstyle.control import loop, lpn_controller
    from jaxstyle.control.model import rollout_batch
    from jaxstyle.data.lpn_features import bone_points
    from jaxstyle.data.pfnn_features import FUTURE_SAMPLES
    from jaxstyle.labels.contacts import FootJoints, estimate_units_per_meter, floor_heights
    from jaxstyle.motion.kinematics import UP_AXIS, global_positions
    from jaxstyle.output import metrics
    from jaxstyle.output.check import passes_check, rollout_measures

    new, skeleton, raw = result.data, data.skeleton, data.new
    upm, num_joints = estimate_units_per_meter(skeleton), skeleton.num_joints
    num_bones, fps = len(bone_points(skeleton)[0]), float(skeleton.fps)
    num_styles, num_rates = len(result.styles), len(result.rates)
    frames = int(round(check.seconds * fps))
    feet = list(FootJoints.find(skeleton).ankles) + list(FootJoints.find(skeleton).toes)
    gen0 = model.params["style"]["generator"]
    character = lpn_controller.StyleNetModel.create(model.params, model.config, data.base.normalisers(), skeleton)
    states, controls, styles = [], [], []
    ref = {k: np.zeros(num_styles) for k in ("real_contact_fraction", "speed_m_s", "base_skating_m_s",
                                            "base_bone_error")}
    floors = []
    for s in range(num_styles):
        rows = new.train_rows[s]
        first_clip = int(raw.clip[rows].min())
        motion = datasets.load_clip(raw.specs[first_clip])
        real = global_positions(motion)
        floor = floor_heights(real[:, feet, UP_AXIS])
        floors.append(floor)
        ref["real_contact_fraction"][s] = metrics.positions_foot_stats(
            real, skeleton, fps, floor, units_per_meter=upm, tolerance_m=check.tolerance_m).contact_fraction
        y = raw.outputs[rows]
        # the first future trajectory sample (x at 0, z at FUTURE_SAMPLES) is the next frame's root
        speed = float(np.median(np.hypot(y[:, 0], y[:, FUTURE_SAMPLES]))) * fps
        ref["speed_m_s"][s] = speed / upm
        clip_rows = rows[raw.clip[rows] == first_clip]
        start = clip_rows[np.argmin(raw.frame[clip_rows])]
        state = lpn_controller.initial_state(raw.inputs[start], raw.phases[start], num_bones)
        control = loop.turning_path(frames, speed, np.deg2rad(check.turn_deg_per_s), fps)
        clips = new.clips[new.train_clips[s]]
        for r in range(num_rates + 1):  # the last: the model before fine-tuning
            gen = gen0 if r == num_rates else jax.tree.map(lambda v, s=s, r=r: v[s, r], result.generators)
            styles.append(film.clip_films(gen, clips).mean(axis=0))
            states.append(state)
            controls.append(control)

    def stack(items):
        return jax.tree.map(lambda *a: np.stack(a), *items)

    out = rollout_batch(character, np.stack(styles), stack(states), stack(controls))
    positions = np.asarray(out.positions)[:, :, :num_joints]
    origin = np.asarray(out.origin)
    finite_c = np.isfinite(positions).all(axis=(1, 2, 3)) & np.isfinite(np.asarray(out.outputs)).all(axis=(1, 2))
    measures = {k: np.full((num_styles, num_rates + 1), np.nan) for k in CHECK_FIELDS[:-1]}
    for c in range(len(styles)):
        s, r = divmod(c, num_rates + 1)
        row = rollout_measures(positions[c], origin[c], bool(finite_c[c]), skeleton, fps, floors[s], upm, check,
                               ref["speed_m_s"][s] * upm)
        for k, v in row.items():
            measures[k][s, r] = v
    ref["base_skating_m_s"] = measures["skating_m_s"][:, -1]
    ref["base_bone_error"] = measures["bone_error"][:, -1]
    out_sr = {k: v[:, :-1] for k, v in measures.items()}
    out_sr["passed"] = passes_check(out_sr, ref["real_contact_fraction"], ref["base_skating_m_s"], ref["speed_m_s"],
                                    check).astype(float)
    return {**out_sr, **ref}


def finetune_clips(model: Model, data: LPNData, directory: str | os.PathLike, *,
                   rates: Sequence[float] = FINETUNE_RATES, steps: int = 150, epochs: int = 100,
                   check: ClosedLoopCheck = DEFAULT_CHECK, progress: bool = True
                   ) -> tuple["FinetuneResult", dict[str, np.ndarray], dict[str, Path]]:
    """New styles from the user's clips (``data.new``, :func:`user_clip_data`) the 2022 way: the
    FiLM generator alone fine-tuned for every (clip style, rate) in one compiled sweep
    (:func:`finetune_sweep`), every pair validated and driven closed-loop
    (:func:`closed_loop_check`), a rate chosen per style (:func:`jaxstyle.output.check.choose_rates`), and written to
    ``directory``: :func:`write_finetune`'s files (every generator, ``chosen_rates.json`` with the
    check), ``generators/<style>.npz`` (the chosen generator alone, :func:`load_generator` reads it)
    and ``clips.json`` (the clips, the rates, the base clips: enough to rebuild the new styles' rows)."""
    result = finetune_sweep(model, data, rates=rates, steps=steps, epochs=epochs, progress=progress)
    checked = closed_loop_check(model, result, data, check)
    val = result.after["validation"]["mse"] + result.after["validation"]["bll"]
    chosen, passed = choose_rates(val, checked["passed"])
    result = dataclasses.replace(result, chosen=chosen)
    directory = Path(directory)
    paths = write_finetune(result, directory)
    saved = json.loads(paths["chosen"].read_text())
    for s, style in enumerate(result.styles):
        saved[style]["check_passed"] = bool(passed[s])
        saved[style]["check"] = {k: _number(checked[k][s, chosen[s]]) for k in CHECK_FIELDS}
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
    return result, {**checked, "chosen_passed": passed}, paths


def load_generator(path: str | os.PathLike, like: dict) -> dict:
    """A generator written by :func:`finetune_clips` (``generators/<style>.npz``) in the tree
    structure of ``like`` (the model's generator), e.g. to drive the new style later."""
    with np.load(path) as z:
        leaves = [z[jax.tree_util.keystr(k)] for k, _ in jax.tree_util.tree_leaves_with_path(like)]
    return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(like), leaves)


def check_table(result: "FinetuneResult", checked: dict[str, np.ndarray]) -> list[str]:
    """Markdown lines: per clip style and rate the validation loss (``(fails)`` where the
    closed-loop check fails), the chosen rate and its check's figures."""
    rates = result.rates
    val = result.after["validation"]["mse"] + result.after["validation"]["bll"]
    lines = ["| clip style | val rows | " + " | ".join(f"val @ {r:g}" for r in rates)
             + " | chosen | check | bone error | feet on floor (clip) | skating m/s (before) | progress |",
             "|---|---|" + "---|" * len(rates) + "---|---|---|---|---|---|"]
    for s, style in enumerate(result.styles):
        c = int(result.chosen[s])
        cells = [f"{val[s, r]:.4f}" + ("" if checked["passed"][s, r] else " (fails)") for r in range(len(rates))]
        lines.append(f"| {style} | {len(result.data.val_rows[s])} | " + " | ".join(cells)
                     + f" | {rates[c]:g} | {'passed' if checked['chosen_passed'][s] else 'FAILED'} | "
                       f"{100 * checked['bone_error'][s, c]:.1f}% | {checked['contact_fraction'][s, c]:.2f} "
                       f"({checked['real_contact_fraction'][s]:.2f}) | {checked['skating_m_s'][s, c]:.2f} "
                       f"({checked['base_skating_m_s'][s]:.2f}) | {checked['progress'][s, c]:.2f} |")
    return lines


# --- report -------------------------------------------------------------------------------------

def losses_table(styles: Sequence[str], losses: dict[str, np.ndarray]) -> list[str]:
    """Markdown lines: one model's test MSE and bone-length loss per style."""
    lines = ["| style | test MSE (normalised) | test bone-length loss (cm) |", "|---|---|---|"]
    return lines + [f"| {style} | {losses['mse'][s]:.4f} | {100 * losses['bll'][s]:.2f} |"
                    for s, style in enumerate(styles)]


def models_table(styles: Sequence[str], results: dict[str, dict[str, np.ndarray]]) -> list[str]:
    """Markdown lines: per model its mean test MSE and bone-length loss, and both per style."""
    lines = ["| model | test MSE (normalised) | test BLL (m) | " + " | ".join(styles) + " |",
             "|---|---|---|" + "---|" * len(styles)]
    for name, r in results.items():
        per = " | ".join(f"{m:.3f} / {b * 100:.2f} cm" for m, b in zip(r["mse"], r["bll"], strict=True))
        lines.append(f"| {name} | {np.mean(r['mse']):.4f} | {np.mean(r['bll']):.5f} | {per} |")
    return lines


def finetune_summary(result: FinetuneResult) -> str:
    """One line: what was fine-tuned, and how long it took."""
    return (f"fine-tuned the FiLM generator alone: {len(result.styles)} new styles x {len(result.rates)} rates, "
            f"{result.steps} steps each, one compiled sweep: {result.seconds:.0f} s")


def finetune_table(result: FinetuneResult, *, checked: bool = False) -> list[str]:
    """Markdown lines: per new style its test MSE before and after fine-tuning at each rate, the
    chosen rate and the test bone-length loss there; then the validation loss that chose it
    (``checked``: among the rates that passed the closed-loop check, :func:`finetune_clips`)."""
    rates, s_r = result.rates, range(len(result.rates))
    test, val = result.after["test"], result.after["validation"]
    lines = ["| new style | test MSE before | " + " | ".join(f"after @ {r:g}" for r in rates)
             + " | chosen rate | test BLL before / after (cm) |", "|---|---|" + "---|" * len(rates) + "---|---|"]
    for s, style in enumerate(result.styles):
        c = int(result.chosen[s])
        lines.append(f"| {style} | {result.before['test']['mse'][s]:.4f} | "
                     + " | ".join(f"{test['mse'][s, r]:.4f}" for r in s_r)
                     + f" | {rates[c]:g} | {100 * result.before['test']['bll'][s]:.2f} / "
                       f"{100 * test['bll'][s, c]:.2f} |")
    lines += ["", "| new style | validation MSE + BLL before | " + " | ".join(f"@ {r:g}" for r in rates) + " |",
              "|---|---|" + "---|" * len(rates)]
    for s, style in enumerate(result.styles):
        before = result.before["validation"]["mse"][s] + result.before["validation"]["bll"][s]
        cells = [f"{val['mse'][s, r] + val['bll'][s, r]:.4f}" + (" (chosen)" if r == result.chosen[s] else "")
                 for r in s_r]
        lines.append(f"| {style} | {before:.4f} | " + " | ".join(cells) + " |")
    lines.append("\n(the validation rows choose the rate among the rates that pass the closed-loop check, or among all "
                 "when none passes)" if checked else
                 "\n(the validation rows choose the rate; a style without validation rows keeps the first rate)")
    return lines


def write_finetune(result: FinetuneResult, directory: str | os.PathLike) -> dict[str, Path]:
    """Write ``finetuned_generators.npz`` (every generator, leading axes (new style, rate)) and
    ``chosen_rates.json`` (per new style its chosen rate and losses) into ``directory``."""
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
    paths["chosen"].write_text(json_text(chosen))
    return paths


def _number(value) -> float | None:
    return float(value) if np.isfinite(value) else None


def film_figure(model: Model, result: FinetuneResult, path: str | os.PathLike, *, clips_per_style: int = 50) -> Path:
    """The paper's Figure 11 with PCA: FiLM parameters of up to ``clips_per_style`` training clips of
    every style before and after fine-tuning (new styles at their chosen rates), written to ``path``."""
    gen0 = model.params["style"]["generator"]
    before, after = {}, {}
    for s, style in enumerate(model.data.styles):
        c = model.data.train_clips[s][:clips_per_style]
        before[style] = after[style] = film.clip_films(gen0, model.data.clips[c])
    for s, style in enumerate(result.styles):
        c = result.data.train_clips[s][:clips_per_style]
        before[style] = film.clip_films(gen0, result.data.clips[c])
        after[style] = film.clip_films(result.params(model, style)["style"]["generator"], result.data.clips[c])
    fig = viz.plot_film_projection({"before fine-tuning": before, "after fine-tuning": after},
                                   new_styles=result.styles, title="FiLM parameters of style clips (PCA)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    import matplotlib.pyplot as plt  # after viz chose the backend

    plt.close(fig)
    return path
