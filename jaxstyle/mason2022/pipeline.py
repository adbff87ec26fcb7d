"""The 2022 workflow: a style folder, a style model, its FiLM generator fine-tuned on new styles.

Mason, Starke & Komura 2022 end to end, in the shape of :mod:`jaxstyle.mason2018.pipeline`, on any
folder in the 100STYLE layout (:mod:`jaxstyle.data.folders`):

1. data: :func:`build_data` builds the LPN rows of the training styles and of the new styles (the
   latter normalised later with the training styles' statistics, as both papers do);
2. train: :func:`model_config` sizes one of Table 2's models (the LPN and MANN ones) for the data
   and :func:`train_model` trains it into a folder (or resumes, or reloads it); :func:`model_losses`;
3. sweep: :func:`finetune_sweep` fine-tunes the FiLM generator alone for every (new style, dropout
   rate) pair in one compiled program, then tests every pair and the model before fine-tuning;
4. select: :func:`choose_rates` keeps per new style the rate of the lowest validation MSE + bone-length
   loss (a style without validation rows keeps the first rate);
5. report: Markdown lines (:func:`losses_table`, :func:`models_table`, :func:`finetune_summary`,
   :func:`finetune_table`) and files (:func:`write_finetune`: the generators and chosen rates;
   :func:`film_figure`: the paper's Figure 11 with PCA).

``jaxstyle lpn`` (:mod:`jaxstyle.cli.lpn`) and ``experiments/mason2022_styles.py`` are this pipeline.
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from pathlib import Path
from typing import NamedTuple, Sequence

import jax
import numpy as np

from jaxstyle.data import datasets
from jaxstyle.data.folders import PipelineError, clip_specs
from jaxstyle.mason2022 import train as train_lpn
from jaxstyle.motion import Motion
from jaxstyle.nn import film_generator as film
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.output import viz
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


def build_data(root: Path, styles: Sequence[str], new_styles: Sequence[str] = (), *,
               gaits: Sequence[str] | None = None, max_seconds: float | None = None,
               cache: str | os.PathLike | None = None, progress: bool = False) -> LPNData:
    """LPN rows (cached) of ``styles`` and ``new_styles`` of the style folder ``root``
    (:func:`jaxstyle.data.folders.clip_specs`: ``gaits``, ``max_seconds``); short clips skipped."""
    def build(names):
        return datasets.build_lpn_dataset(clip_specs(root, names, gaits, max_seconds), cache_dir=cache,
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
    convolution filters (256) reading the dataset's style clips."""
    paper = StyleModelConfig.paper(name, len(dataset.styles))
    if paper.backbone == "pfnn":
        raise PipelineError(f"{name}: the PFNN backbone needs a global phase per row, which the LPN dataset lacks")
    gen = film.FiLMConfig(clip_frames=dataset.clips.shape[1], clip_features=dataset.clips.shape[2], filters=filters,
                          hidden=generator_hidden, film_size=4 * hidden)
    return dataclasses.replace(paper, hidden_size=hidden, input_size=dataset.inputs.shape[1],
                               output_size=dataset.outputs.shape[1], generator=gen)


def train_model(data: LPNData, config: StyleModelConfig, directory: str | os.PathLike, *, name: str = MODEL,
                epochs: int = 6, progress: bool = True) -> Model:
    """Train (or resume, or reload) a style model on the training styles into ``directory``
    (:func:`jaxstyle.mason2022.train.train`: style-balanced batches, the paper's optimiser)."""
    style_data = train_lpn.style_data(data.base, data.skeleton, backbone=config.backbone)
    state = train_lpn.train(style_data, train_lpn.LPNTrainConfig(model=config, epochs=epochs), directory,
                            progress=progress)
    return Model(name, config, state["params"], style_data)


def model_losses(model: Model, split: str = "test") -> dict[str, np.ndarray]:
    """``{"mse", "bll"}`` per training style on ``split``'s rows (bone-length loss in metres)."""
    return train_lpn.evaluate(model.params, model.config, model.data, split)


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


def choose_rates(validation_loss_SxR: np.ndarray) -> np.ndarray:
    """Per style the index of the rate with the lowest finite validation loss (0 when none is finite)."""
    loss = np.where(np.isfinite(validation_loss_SxR), validation_loss_SxR, np.inf)
    return np.argmin(loss, axis=1).astype(np.int32)


SPLITS = ("validation", "test")


def finetune_sweep(model: Model, data: LPNData, *, rates: Sequence[float] = FINETUNE_RATES, steps: int = 150,
                   epochs: int = 100, chunk_steps: int = 10, progress: bool = True) -> FinetuneResult:
    """Fine-tune ``model``'s FiLM generator on every new style of ``data`` at every dropout rate,
    at most ``steps`` steps each (over at most ``epochs`` epochs), in one compiled sweep
    (:func:`jaxstyle.mason2022.train.finetune_film_sweep`); test every pair and the model as it was on
    the new styles' validation and test rows, and choose a rate per style (:func:`choose_rates`)."""
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
    chosen = choose_rates(after["validation"]["mse"] + after["validation"]["bll"])
    return FinetuneResult(tuple(new.styles), config.rates, gens, int(per_step.shape[2]), seconds, before, after,
                          chosen, new)


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


def finetune_table(result: FinetuneResult) -> list[str]:
    """Markdown lines: per new style its test MSE before and after fine-tuning at each rate, the
    chosen rate and the test bone-length loss there; then the validation loss that chose it."""
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
    lines.append("\n(the validation rows choose the rate; a style without validation rows keeps the first rate)")
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
