"""A few-shot sweep's files (Mason et al. 2018 section 7, :mod:`jaxstyle.mason2018.selection`):
:func:`write_report` writes ``results.csv`` (every (set, rate) pair), ``heatmap.png``
(:func:`plot_heatmap`), ``chosen_rates.json`` and one orbax checkpoint of the chosen adapter per
set; :func:`read_chosen` reads ``chosen_rates.json`` back, checked; :func:`load_adapter` restores
an adapter.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path

import jax
import numpy as np

from jaxstyle.data.folders import PipelineError
from jaxstyle.mason2018 import fewshot
from jaxstyle.mason2018.selection import SweepResult
from jaxstyle.nn import pfnn
from jaxstyle.train.checkpoint import Checkpointer, json_text, read_json
from jaxstyle.train.defaults import ROLLOUT_FIELDS


def write_report(result: SweepResult, directory: str | os.PathLike, config: fewshot.SweepConfig, *,
                 replace: bool = False) -> dict[str, Path]:
    """Write ``results.csv``, ``heatmap.png``, ``chosen_rates.json`` and ``adapters/<style>/`` (an
    orbax checkpoint of the chosen adapter, its config beside it) under ``directory``; returns the
    paths.

    An earlier report there is merged, not replaced: its sets that this result does not hold keep
    their rows of ``results.csv``, their entries of ``chosen_rates.json`` and their adapters; a set
    swept again is updated. ``replace``: start over (the earlier sets' entries and adapters are
    removed). The heatmap shows this result's sets. The adapters are written first; then
    ``results.csv`` and ``chosen_rates.json`` (the index that synthesis and play read) are each
    written in full and renamed into place back to back, the index last: a run killed midway never
    names an adapter that is not there, and the two tables disagree only if it is killed between
    two renames (two system calls, not one atomic step)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = {"csv": directory / "results.csv", "heatmap": directory / "heatmap.png",
             "chosen": directory / "chosen_rates.json", "adapters": directory / "adapters"}
    earlier = {} if replace or not paths["chosen"].is_file() else read_chosen(paths["chosen"])
    earlier = {k: v for k, v in earlier.items() if k not in result.styles}
    kept_rows = []
    if earlier and paths["csv"].is_file():
        with open(paths["csv"], newline="") as f:
            kept_rows = [row for row in list(csv.reader(f))[1:] if row and row[0] in earlier]
    for s, style in enumerate(result.styles):
        # written beside, then renamed over any earlier report's adapter
        final = paths["adapters"] / style
        tmp = paths["adapters"] / f".{style}.tmp-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        ckpt = Checkpointer(tmp, {"sweep": config, "style": style, "rate": result.rates[int(result.chosen[s])]},
                            max_to_keep=1)
        ckpt.save(0, result.adapter(style))
        ckpt.close()
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
    tmp = paths["csv"].with_name("results.csv.tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["style", "rate", "train_rows", "validation_rows", "train_loss", "validation_loss"]
                   + [f"rollout_{k}" for k in ROLLOUT_FIELDS] + ["chosen"])
        w.writerows(kept_rows)
        for s, style in enumerate(result.styles):
            for r, rate in enumerate(result.rates):
                w.writerow([style, rate, result.train_rows[s], result.validation_rows[s],
                            f"{result.train_loss[s, r]:.6f}", f"{result.validation_loss[s, r]:.6f}"]
                           + [_fmt(result.rollout[k][s, r]) for k in ROLLOUT_FIELDS]
                           + [int(result.chosen[s] == r)])
    csv_tmp = tmp
    plot_heatmap(result, paths["heatmap"])
    chosen = {}
    for s, style in enumerate(result.styles):
        chosen[style] = {"rate": result.rates[int(result.chosen[s])],
                         "validation_loss": float(result.validation_loss[s, result.chosen[s]]),
                         "passed_check": bool(result.chosen_passed[s])}
        if not result.chosen_passed[s]:  # every rate failed: what the chosen one failed, for the refusal
            chosen[style]["failed"] = result.failed(style)
    tmp = paths["chosen"].with_name("chosen_rates.json.tmp")
    tmp.write_text(json_text({**earlier, **chosen}))  # strict JSON: a NaN loss is null
    # both written in full first, then renamed back to back, the index last
    os.replace(csv_tmp, paths["csv"])
    os.replace(tmp, paths["chosen"])
    if replace and paths["adapters"].is_dir():
        for folder in paths["adapters"].iterdir():
            if folder.is_dir() and folder.name not in result.styles and not folder.name.startswith("."):
                shutil.rmtree(folder)
    return paths


def read_chosen(path: str | os.PathLike) -> dict[str, dict]:
    """A ``chosen_rates.json``, checked: an object of set name -> ``{"rate": a number in [0, 1),
    "validation_loss": a number or null, "passed_check": true or false, and for a set whose every
    rate failed the check "failed": the criteria its chosen rate failed}``. A file that is not so
    (hand-edited, damaged) raises a PipelineError naming the file and the key."""
    path = Path(path)
    try:
        data = read_json(path)
    except ValueError as e:
        raise PipelineError(str(e)) from None
    if not isinstance(data, dict):
        raise PipelineError(f"{path}: expected an object of set name -> chosen rate, got {type(data).__name__}")
    for name, info in data.items():
        where = f"{path}: {name!r}"
        if not isinstance(info, dict) or "rate" not in info:
            raise PipelineError(f"{where}: expected an object with a 'rate'")
        rate = info["rate"]
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 <= rate < 1:
            raise PipelineError(f"{where}: 'rate' must be a dropout rate in [0, 1), got {json.dumps(rate)}")
        loss = info.get("validation_loss")
        if loss is not None and (isinstance(loss, bool) or not isinstance(loss, (int, float))):
            raise PipelineError(f"{where}: 'validation_loss' must be a number or null, got {json.dumps(loss)}")
        if not isinstance(info.get("passed_check", True), bool):
            raise PipelineError(f"{where}: 'passed_check' must be true or false, got "
                                 f"{json.dumps(info['passed_check'])}")
        failed = info.get("failed", [])
        if not isinstance(failed, list) or not all(isinstance(f, str) for f in failed):
            raise PipelineError(f"{where}: 'failed' must be a list of strings, got {json.dumps(failed)}")
    return data


def load_adapter(directory: str | os.PathLike, config: pfnn.PFNNConfig) -> dict:
    """An adapter written by :func:`write_report` (``directory`` = ``.../adapters/<style>``)."""
    path = Path(directory)
    saved = json.loads((path / "config.json").read_text())
    ckpt = Checkpointer(path, saved)
    try:
        return ckpt.restore(pfnn.init_adapter(jax.random.PRNGKey(0), config))
    finally:
        ckpt.close()  # also when the restore is refused


def _fmt(v) -> str:
    v = float(v)
    return "" if np.isnan(v) else f"{v:.6g}"


def plot_heatmap(result: SweepResult, path: str | os.PathLike) -> None:
    """Styles x rates validation loss, chosen rates boxed, failed closed-loop checks crossed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    val = result.validation_loss
    fig, ax = plt.subplots(figsize=(1.6 + 1.1 * len(result.rates), 0.9 + 0.45 * len(result.styles)))
    im = ax.imshow(val, cmap="viridis_r", aspect="auto")
    ax.set_xticks(range(len(result.rates)), [f"{r:g}" for r in result.rates])
    ax.set_yticks(range(len(result.styles)), result.styles)
    ax.set_xlabel("dropout rate")
    for s in range(len(result.styles)):
        for r in range(len(result.rates)):
            mark = "" if result.rollout["passed"][s, r] else " x"
            ax.text(r, s, f"{val[s, r]:.3f}{mark}", ha="center", va="center", fontsize=8,
                    color="white" if val[s, r] > np.nanmean(val) else "black")
        ax.add_patch(plt.Rectangle((result.chosen[s] - 0.5, s - 0.5), 1, 1, fill=False, edgecolor="red", lw=2))
    fig.colorbar(im, ax=ax, label="validation MSE (normalised)")
    ax.set_title("few-shot sweep (red: chosen; x: failed closed-loop check)", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
