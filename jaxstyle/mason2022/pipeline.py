"""The 2022 workflow: a style folder, a style model, its FiLM generator fine-tuned on new styles.

Mason, Starke & Komura 2022 end to end, in the shape of :mod:`jaxstyle.mason2018.pipeline`, on any
folder in the 100STYLE layout (:mod:`jaxstyle.data.folders`):

1. data: :func:`build_data` builds the LPN rows of the training styles and of the new styles (the
   latter normalised later with the training styles' statistics, as both papers do), every row
   with its local phases and its global phase;
2. train: :func:`model_config` sizes any of Table 2's seven models for the data and
   :func:`train_model` trains it into a folder (or resumes, or reloads it); :func:`train_for`
   trains within a wall-clock :class:`Budget` (whole epochs, early stop once validation has
   flattened), :func:`train_models` several models within one budget; :func:`model_losses`;
3. new styles: :mod:`jaxstyle.mason2022.finetune` (the FiLM generator fine-tuned for every (new
   style, dropout rate) pair in one compiled program, validated, checked closed-loop, a rate
   chosen by the 2018 sweep's rule, the user's own clips as new styles);
4. report: :mod:`jaxstyle.mason2022.report` (tables and figures).

``jaxstyle lpn`` (:mod:`jaxstyle.cli.lpn`) and ``experiments/mason2022_styles.py`` are this pipeline.
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from pathlib import Path
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from jaxstyle.data import datasets
from jaxstyle.data.folders import PipelineError, clip_specs, portable_path
from jaxstyle.mason2022 import styledata
from jaxstyle.mason2022 import train as train_lpn
from jaxstyle.motion import Motion
from jaxstyle.nn import film_generator as film
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.train.checkpoint import json_text, read_json

PAPER_NEW_STYLES = ("Elated", "Rushed")
"""The new (held-out) styles of ``experiments/mason2022_styles.py`` in the shared 100STYLE sample."""
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
    data: styledata.StyleData


def model_config(dataset: datasets.Dataset, name: str = MODEL, *, hidden: int = 512, generator_hidden: int = 2048,
                 filters: int = 256) -> StyleModelConfig:
    """Table 2's model ``name`` for the styles and layout of an LPN ``dataset``: ``hidden`` units
    (paper: 512), a FiLM generator of ``generator_hidden`` dense units (2048) and ``filters``
    convolution filters (256) reading the dataset's style clips.

    Every backbone predicts the dataset's whole output row (342 values on 100STYLE), where the
    paper's PFNN predicts 327 and its MANN 326 (:meth:`StyleModelConfig.paper`): with one output
    layout the test MSE of the seven models is over the same values and so comparable; the extra
    local-phase outputs of the PFNN and MANN rows are simply not fed back at runtime. The PFNN
    backbones' expert blend is the row's global phase (:func:`jaxstyle.mason2022.styledata.style_data`)."""
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
                compute_dtype: str = "float32", chosen: bool = True, **train_options) -> Model:
    """Train (or resume, or reload) a style model on the training styles into ``directory``
    (:func:`jaxstyle.mason2022.train.train`: style-balanced batches, the paper's optimiser;
    ``train_options``: other :class:`jaxstyle.mason2022.train.LPNTrainConfig` fields, e.g. the demo's
    ``learning_rate``; ``devices`` / ``compute_dtype``: data-parallel devices and bfloat16 products,
    as :func:`jaxstyle.mason2022.train.train`).

    The model's weights are the last epoch's, or those of the epoch recorded for this training by
    :func:`jaxstyle.mason2022.synthesis.choose_epoch` (:func:`chosen_epoch`) when the folder has one
    and ``chosen`` is true. With ``chosen`` false the last epoch's, and a record left in the folder
    is removed (:func:`drop_chosen_record`), so that :func:`jaxstyle.mason2022.synthesis.load_model`
    loads the same weights."""
    style_data = styledata.style_data(data.base, data.skeleton, backbone=config.backbone)
    write_data_file(data, directory, name)
    train_config = train_lpn.LPNTrainConfig(model=config, epochs=epochs, **train_options)
    state = train_lpn.train(style_data, train_config, directory, progress=progress, devices=devices,
                            compute_dtype=compute_dtype)
    if chosen:
        state = chosen_state(directory, state, train_config, style_data.styles, compute_dtype)
    else:
        drop_chosen_record(directory)
    return Model(name, config, state.params, style_data)


CHOSEN_EPOCH_FILE = "chosen_epoch.json"
"""The file of a run folder in which :func:`jaxstyle.mason2022.synthesis.choose_epoch` records the
epoch the model is taken from."""


def chosen_record(directory: str | os.PathLike, trained_epochs: int) -> dict | None:
    """The record in ``directory``'s :data:`CHOSEN_EPOCH_FILE` (``epoch``, ``trained_epochs``, the
    rule and the check's figures) for a run trained ``trained_epochs`` epochs; ``None`` without a
    record, or when the record was made before the run trained further (its ``trained_epochs``
    differ). A damaged record is refused in one line."""
    path = Path(directory) / CHOSEN_EPOCH_FILE
    if not path.is_file():
        return None
    try:
        record = read_json(path)
        recorded = int(record["trained_epochs"])
        record["epoch"] = int(record["epoch"])
    except (ValueError, KeyError, TypeError) as e:
        raise PipelineError(f"{path}: not a chosen-epoch record ({type(e).__name__}: {e}); remove it to use the "
                            "last epoch's weights") from None
    return record if recorded == int(trained_epochs) else None


def chosen_epoch(directory: str | os.PathLike, trained_epochs: int) -> int | None:
    """The epoch of :func:`chosen_record`, or ``None``."""
    record = chosen_record(directory, trained_epochs)
    return None if record is None else record["epoch"]


def chosen_state(directory: str | os.PathLike, state, config: train_lpn.LPNTrainConfig, styles: Sequence[str],
                 compute_dtype: str = "float32"):
    """``state``, a run's last epoch, or the epoch :func:`chosen_epoch` records for that training,
    loaded from ``directory`` (:func:`train_model` and
    :func:`jaxstyle.mason2022.synthesis.load_model`)."""
    epoch = chosen_epoch(directory, int(state.epoch))
    if epoch is None or epoch == int(state.epoch):
        return state
    return train_lpn.load(directory, config, styles, compute_dtype=compute_dtype, epoch=epoch)


def drop_chosen_record(directory: str | os.PathLike) -> None:
    """Remove ``directory``'s :data:`CHOSEN_EPOCH_FILE`, if it has one (the model is then the last
    epoch's wherever it is loaded)."""
    (Path(directory) / CHOSEN_EPOCH_FILE).unlink(missing_ok=True)


def write_chosen_record(directory: str | os.PathLike, record: dict) -> Path:
    """``directory``'s :data:`CHOSEN_EPOCH_FILE`: ``record`` as strict JSON (a NaN figure as
    ``null``), written whole and renamed into place."""
    path = Path(directory) / CHOSEN_EPOCH_FILE
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json_text(record) + "\n")
    os.replace(tmp, path)
    return path


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
    ``flat_tolerance`` (relative) below the best of the epochs before them (``flat_epochs=None``:
    no early stop)."""

    seconds: float
    max_epochs: int = 90
    flat_epochs: int | None = 3
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

    style_data = styledata.style_data(data.base, data.skeleton, backbone=config.backbone)
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
        epochs = int(state.epoch)
        if epochs >= budget.max_epochs:
            stopped = "max epochs"
            break
        if budget.flat_epochs is not None and log and flattened(log["val_mse"] + log["val_bll"], budget.flat_epochs,
                                                                 budget.flat_tolerance):
            stopped = "flattened"
            break
        if time.perf_counter() - t0 + last_epoch_s > budget.seconds:
            stopped = "budget"
            break
    return BudgetRun(Model(name, config, state.params, style_data), int(state.epoch),
                     time.perf_counter() - t0, stopped)


def steps_per_epoch(data: styledata.StyleData, batch_size: int = 32) -> int:
    """Steps of one style-balanced epoch (:func:`jaxstyle.data.batching.balanced_batches`)."""
    from jaxstyle.data.batching import balanced_batches

    return len(balanced_batches(data.train_rows, batch_size, seed=0))


class ModelRuns(NamedTuple):
    """What :func:`train_models` did: per model name its :class:`BudgetRun` (``runs``), its
    training log (``logs``, :func:`read_log`) and its test losses (``results``,
    :func:`model_losses`)."""

    runs: dict[str, BudgetRun]
    logs: dict[str, dict[str, np.ndarray]]
    results: dict[str, dict[str, np.ndarray]]


def model_folder(out: str | os.PathLike, name: str) -> Path:
    """A Table 2 model's run folder inside ``out`` (its name with underscores: ``LPN_FiLM``)."""
    return Path(out) / name.replace(" ", "_")


@dataclasses.dataclass(frozen=True)
class SharedBudget:
    """One wall-clock budget for several jobs (:func:`train_models`): it ends at ``deadline``
    (``time.perf_counter()`` seconds); ``jobs_after`` later jobs (e.g. a fine-tuning sweep) get
    their shares of it; each model trains at most ``max_epochs`` epochs (the paper: 90), stopping
    early once its validation loss has flattened unless ``early_stop`` is off."""

    deadline: float
    jobs_after: int = 0
    max_epochs: int = 90
    early_stop: bool = True

    @classmethod
    def epochs(cls, epochs: int) -> "SharedBudget":
        """No wall clock: every model trains exactly ``epochs`` epochs (Table 2's comparison at equal
        epochs; a time budget would favour the cheaper models and depend on the machine's load)."""
        return cls(float("inf"), 0, int(epochs), early_stop=False)


def train_models(data: LPNData, configs: Mapping[str, StyleModelConfig], out: str | os.PathLike,
                 budget: SharedBudget, *, train_config: dict | None = None, progress: bool = True,
                 after_each=None) -> ModelRuns:
    """Train several of Table 2's models (``configs``, name to :func:`model_config`, in order) into
    ``out/<name>`` within one wall-clock budget (:class:`SharedBudget`), and test each.

    The rule: as each model starts, the time left is split evenly over the models left and the
    budget's later jobs, so a model that stops early hands its unused time to the jobs after it;
    each model trains by :func:`train_for` (whole epochs, at most ``budget.max_epochs``, early stop
    once validation has flattened). ``train_config``: further
    :class:`jaxstyle.mason2022.train.LPNTrainConfig` fields (e.g. a ``learning_rate``).
    ``after_each(name, model_runs)`` is called after each model (a partial report). A second call
    with a later deadline resumes every folder."""
    out = Path(out)
    runs, logs, results = {}, {}, {}
    jobs = len(configs) + budget.jobs_after
    for i, (name, config) in enumerate(configs.items()):
        share = max(0.0, (budget.deadline - time.perf_counter()) / (jobs - i))
        folder = model_folder(out, name)
        stop = {} if budget.early_stop else {"flat_epochs": None}
        runs[name] = train_for(data, config, folder, Budget(share, max_epochs=budget.max_epochs, **stop), name=name,
                               progress=progress, train_config=train_config)
        logs[name] = read_log(folder)
        results[name] = model_losses(runs[name].model)
        if after_each is not None:
            after_each(name, ModelRuns(runs, logs, results))
    return ModelRuns(runs, logs, results)
