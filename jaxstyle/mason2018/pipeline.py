"""The workflow behind the ``jaxstyle`` command: a data folder, a base PFNN, a few-shot sweep.

Mason et al. 2018 end to end, on any folder in the 100STYLE layout
(``<root>/<Style>/<Style>_<GAIT>.bvh`` with ``Frame_Cuts.csv`` and ``Dataset_List.csv``): the real
100STYLE archive (``jaxstyle data fetch 100style``), the shared sample, or the procedural styles of
:mod:`jaxstyle.data.procedural` (``jaxstyle data generate``, what ``jaxstyle demo`` trains on).

1. data: :func:`jaxstyle.data.folders.split_styles` picks the base (training) styles and the
   held-out few-shot styles (the style-folder functions of :mod:`jaxstyle.data.folders`, shared with
   :mod:`jaxstyle.mason2022.pipeline`); :func:`fewshot_specs` cuts the few-shot clips;
   :func:`style_table` describes a dataset's styles;
2. train: :func:`jaxstyle.mason2018.base_model.train_base` trains (or resumes, or reloads) the base
   PFNN with one CP adapter per base style into a run folder
   (:class:`jaxstyle.mason2018.base_model.BaseSettings`; :func:`jaxstyle.mason2018.base_model.load_base`
   reads it back);
3. sweep and select: :func:`run_sweep` fine-tunes a new adapter for every (few-shot set, dropout
   rate) in one compiled program (:func:`jaxstyle.mason2018.selection.fewshot_sweep`), chooses a
   rate per set and writes the report (CSV, heatmap, chosen rates, adapters) and ``sweep.json``;
4. report: :func:`sweep_table` and :func:`check_table` (Markdown lines);
5. synthesis: :func:`characters` gathers base and few-shot styles, which
   :func:`jaxstyle.output.synthesis.synthesize` drives along paths with :meth:`Base.character_model`;
6. timing: :mod:`jaxstyle.mason2018.bench` (``jaxstyle bench``, the paper's Table 1).

The ``jaxstyle`` commands (:mod:`jaxstyle.cli`) and ``experiments/fewshot_sweep.py``,
``experiments/synthesize.py`` and ``experiments/mason2018_table1.py`` are this pipeline.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from pathlib import Path
from typing import NamedTuple, Sequence

import jax
import numpy as np

from jaxstyle.control.controller import PFNNModel
from jaxstyle.data import datasets
from jaxstyle.data.clips import ClipSpec
from jaxstyle.data.folders import PipelineError, clip_specs, located_path, portable_path
from jaxstyle.data.pfnn_features import valid_frames
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2018 import fewshot, selection, sweep_files
from jaxstyle.mason2018.base_model import Base, build
from jaxstyle.mason2018.train import with_contacts
from jaxstyle.motion import Motion
from jaxstyle.motion.bvh import frame_rate, read_joint_names
from jaxstyle.motion.skeleton import JointMap
from jaxstyle.output import drive
from jaxstyle.output.check import FAILED_MARK, failed_check, refusal
from jaxstyle.output.drive import Character
from jaxstyle.train import scan
from jaxstyle.train.checkpoint import json_text, read_json

# --- data ---------------------------------------------------------------------------------------

def fewshot_specs(root: str | os.PathLike, styles: Sequence[str], seconds: float,
                  gaits: Sequence[str] | None = None, joint_map: JointMap | None = None) -> list[ClipSpec]:
    """One few-shot set per style and gait, named ``<Style>_<GAIT>``: ONE clip of ``seconds`` (plus
    the trajectory window the rows need) and its mirror for symmetric styles (2018 section 7)."""
    root = Path(root)
    if seconds <= 0:
        raise PipelineError(f"few-shot seconds must be positive, got {seconds:g}")
    specs = []
    for spec in clip_specs(root, styles, gaits, joint_map=joint_map):
        fps = frame_rate(spec.path)
        n = int(round(10 * fps))
        window = n - len(valid_frames(n, fps))  # frames the trajectory window costs a clip
        stop = spec.start + int(round(seconds * fps)) + window
        specs.append(dataclasses.replace(spec, style=f"{spec.style}_{spec.gait}",
                                         stop=stop if spec.stop is None else min(spec.stop, stop)))
    return specs


def style_table(dataset: datasets.Dataset) -> list[str]:
    """Markdown lines: per style of PFNN rows its clips, training / validation / test rows, median
    speed and median step rate."""
    upm = estimate_units_per_meter(datasets.load_clip(dataset.specs[0]))
    lines = ["| style | clips | rows train / val / test | speed m/s (median) | steps/s (median) |",
             "|---|---|---|---|---|"]
    for s in dataset.styles:
        rows = dataset.rows_of_style(s)
        clips = len(np.unique(dataset.clip[rows]))
        split = [int((dataset.split[rows] == k).sum()) for k in range(3)]
        speed = PFNNModel.own_speed(dataset, rows, upm)
        dphase = np.mod(np.diff(dataset.phases[rows, 0]), 1.0)
        steps = 2 * 60.0 * np.median(dphase[dphase < 0.5]) if (dphase < 0.5).any() else float("nan")
        lines.append(f"| {s} | {clips} | {split[0]} / {split[1]} / {split[2]} | {speed:.2f} | {steps:.2f} |")
    return lines


# --- few-shot sweep -----------------------------------------------------------------------------

class SweepRun(NamedTuple):
    """What :func:`run_sweep` returns: the sweep's ``result`` (every (set, rate) pair's adapter,
    losses, check and the chosen rate), the few-shot sets' rows ``shots``, their clips ``specs`` and
    the sweep's ``config`` (what :func:`write_sweep` records beside the result)."""

    result: selection.SweepResult
    shots: datasets.Dataset
    specs: tuple[ClipSpec, ...]
    config: fewshot.SweepConfig


class LoadedSweep(NamedTuple):
    """A sweep reloaded by :func:`load_sweep`: the ``chosen`` rates (``chosen_rates.json``) and the
    few-shot sets' rows ``shots``."""

    chosen: dict
    shots: datasets.Dataset


def run_sweep(base: Base, specs: Sequence[ClipSpec], config: fewshot.SweepConfig | None = None, *,
              skeleton: Motion | None = None, cache: str | os.PathLike | None = None, progress: bool = True,
              shard: bool | None = None) -> SweepRun:
    """Fine-tune a new adapter per (few-shot set of ``specs``, rate) on the frozen base in one compiled
    sweep, validate and check them closed-loop (on ``skeleton``, default the base's) and choose a rate
    per set. Returns the result, the few-shot dataset, the specs and the config; writes nothing
    (:func:`write_sweep` writes the report). ``config``: rates, epochs and the rest of
    :class:`jaxstyle.mason2018.fewshot.SweepConfig` (default its defaults; its ``model`` is replaced by the
    base's).
    ``cache``: where :func:`jaxstyle.mason2018.base_model.build` caches the few-shot rows (``None``: no cache).

    ``shard``: spread the sets over all devices (default: when ``jax.distributed`` runs several
    processes; every process then calls this alike and gets the whole result)."""
    if shard is None:
        shard = jax.process_count() > 1
    if not specs:
        raise PipelineError("no few-shot clips")
    config = config or fewshot.SweepConfig()
    epochs, rates = config.epochs, config.rates
    if epochs < 1 or not rates or any(not 0 <= r < 1 for r in rates):
        raise PipelineError(f"need epochs >= 1 and dropout rates in [0, 1), got {epochs} and {list(rates)}")
    _check_joint_order(specs, base)
    shots = build(specs, cache)
    if base.settings.contacts:
        shots = with_contacts(shots, base.dataset)
    if shots.inputs.shape[1] != base.model.input_size:
        raise PipelineError(f"the few-shot clips give {shots.inputs.shape[1]} inputs but the base takes "
                            f"{base.model.input_size}: they need the base's skeleton ({base.skeleton.num_joints} "
                            "joints)")
    config = dataclasses.replace(config, model=base.model, rates=tuple(float(r) for r in rates))
    result = selection.fewshot_sweep(base.params, base.normalisers, shots, skeleton or base.skeleton, config,
                                     selection.FewshotOptions(run=scan.GridRun(chunk_steps=100, shard=shard,
                                                                                progress=progress)))
    return SweepRun(result, shots, tuple(specs), config)


def write_sweep(sweep: SweepRun, directory: str | os.PathLike, *, replace: bool = False) -> dict[str, Path]:
    """Write a sweep's report to ``directory`` (:func:`jaxstyle.mason2018.sweep_files.write_report`:
    tables, heat map, ``chosen_rates.json``, one adapter folder per set) with ``sweep.json`` (the
    sets' clips, paths relative to the folder). An earlier report there is merged (its other sets
    kept) unless ``replace``. Returns the paths written."""
    result, config = sweep.result, sweep.config
    path = Path(directory) / "sweep.json"
    kept = []
    if not replace and path.is_file() and (Path(directory) / "chosen_rates.json").is_file():
        earlier = _read_sweep_json(path)
        kept = [d for d in earlier.get("specs", []) if d.get("style") not in result.styles]
    paths = sweep_files.write_report(result, directory, config, replace=replace)
    kept_styles = list(dict.fromkeys(d.get("style") for d in kept))
    meta = {"specs": kept + [_portable_spec(s, directory) for s in sweep.specs], "rates": list(config.rates),
            "epochs": config.epochs, "styles": kept_styles + list(result.styles), "seconds": result.seconds}
    path.with_name("sweep.json.tmp").write_text(json_text(meta))
    os.replace(path.with_name("sweep.json.tmp"), path)
    paths["sweep"] = path
    return paths


def _check_joint_order(specs: Sequence[ClipSpec], base: Base) -> None:
    """Refuse a clip whose joints are the base's but listed in another order (left and right
    swapped, say): its features would put each joint's values where the base expects another
    joint's, and the sweep would train on them without a word. Clips with a joint map are read
    through it and not checked here."""
    want = tuple(base.skeleton.names)
    for path in dict.fromkeys(s.path for s in specs if s.joint_map is None):
        names = read_joint_names(path)
        if names != want and sorted(names) == sorted(want):
            k = next(i for i, (a, b) in enumerate(zip(names, want, strict=True)) if a != b)
            raise PipelineError(f"{path}: its joints are the base's in another order (joint {k} is {names[k]!r}, "
                                f"the base's is {want[k]!r}); write it in the base's joint order")


def sweep_table(result: selection.SweepResult) -> list[str]:
    """Markdown lines: per set, its training and validation rows, validation loss per rate (marked
    where the closed-loop check fails), the chosen rate and its check."""
    lines = ["| set | train rows | validation rows | " + " | ".join(f"val @ {r:g}" for r in result.rates)
             + " | chosen | check |", "|---|---|---|" + "---|" * len(result.rates) + "---|---|"]
    for s, style in enumerate(result.styles):
        cells = [f"{result.validation_loss[s, r]:.3f}" + ("" if result.rollout["passed"][s, r] else " (fails)")
                 for r in range(len(result.rates))]
        lines.append(f"| {style} | {result.train_rows[s]} | {result.validation_rows[s]} | " + " | ".join(cells)
                     + f" | {result.chosen_rate(style):g} | {'passed' if result.chosen_passed[s] else 'FAILED'} |")
    return lines


def check_table(result: selection.SweepResult) -> list[str]:
    """Markdown lines: the closed-loop check of each set's chosen rate beside the base and real clips,
    and the mean validation loss per rate."""
    lines = ["| set | bone error (base) | feet on floor (real) | skating m/s (base; real) | distance / requested |",
             "|---|---|---|---|---|"]
    ro, ref = result.rollout, result.reference
    for s, style in enumerate(result.styles):
        r = int(result.chosen[s])
        lines.append(f"| {style} | {100 * ro['bone_error'][s, r]:.1f}% ({100 * ref['base_bone_error'][s]:.1f}%) "
                     f"| {ro['contact_fraction'][s, r]:.2f} ({ref['contact_fraction'][s]:.2f}) "
                     f"| {ro['skating_m_s'][s, r]:.2f} ({ref['base_skating_m_s'][s]:.2f}; "
                     f"{ref['skating_m_s'][s]:.2f}) | {ro['progress'][s, r]:.2f} |")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a rate without any finite loss
        mean = np.nanmean(result.validation_loss, axis=0)
    lines.append("")
    lines.append("mean validation loss per rate: "
                 + ", ".join(f"{r:g}: {m:.3f}" for r, m in zip(result.rates, mean, strict=True)))
    return lines


def load_sweep(directory: str | os.PathLike, base: Base, *, cache: str | os.PathLike | None = None
               ) -> LoadedSweep:
    """``(chosen rates, few-shot dataset)`` of a sweep written by :func:`run_sweep`."""
    directory = Path(directory)
    for name in ("sweep.json", "chosen_rates.json"):
        if not (directory / name).is_file():
            raise PipelineError(f"no few-shot sweep in {directory} (no {name}): run `jaxstyle sweep --run RUN` first")
    meta = _read_sweep_json(directory / "sweep.json")
    chosen = sweep_files.read_chosen(directory / "chosen_rates.json")
    try:
        specs = [ClipSpec.from_json({**s, "path": located_path(s["path"], directory)}) for s in meta["specs"]]
    except (KeyError, TypeError, ValueError) as e:
        raise PipelineError(f"{directory / 'sweep.json'}: 'specs' is not a list of clip specs ({e})") from None
    shots = build(specs, cache)
    if base.settings.contacts:
        shots = with_contacts(shots, base.dataset)
    return LoadedSweep(chosen, shots)


def _portable_spec(spec: ClipSpec, directory) -> dict:
    d = spec.to_json()
    d["path"] = portable_path(spec.path, directory)
    return d


def _read_sweep_json(path: Path) -> dict:
    try:
        meta = read_json(path)
    except ValueError as e:
        raise PipelineError(str(e)) from None
    if not isinstance(meta, dict) or not isinstance(meta.get("specs", []), list):
        raise PipelineError(f"{path}: expected an object with a list of 'specs'")
    return meta


def characters(base: Base, sweep_dir: str | os.PathLike | None, shots: datasets.Dataset | None, chosen: dict | None,
               *, base_styles: Sequence[str] = (), fewshot_sets: Sequence[str] = (), blend: bool = False,
               allow_failed: bool = False) -> list[Character]:
    """:class:`~jaxstyle.output.drive.Character` s: base styles (the base network with that style's
    adapter), few-shot sets (their chosen adapters from ``sweep_dir``), and with ``blend`` a 50/50
    blend of the first two few-shot sets (:func:`jaxstyle.output.drive.blend_character`).

    A few-shot set that failed the closed-loop check at every rate
    (:func:`jaxstyle.output.check.failed_check`) is refused with one line naming it and the failing
    figures, unless ``allow_failed``: then its title carries
    :data:`jaxstyle.output.check.FAILED_MARK`."""
    out = []
    for style in base_styles:
        if style not in base.dataset.styles:
            raise PipelineError(f"unknown base style {style!r}; the base has {', '.join(base.dataset.styles)}")
        s = base.dataset.styles.index(style)
        out.append(Character(f"{style} (base)", style, jax.tree.map(lambda v, s=s: v[s], base.adapters),
                             base.dataset, style))
    for name in fewshot_sets:
        if chosen is None or name not in chosen:
            raise PipelineError(f"unknown few-shot set {name!r}; the sweep has {', '.join(chosen or {}) or 'none'}")
        failed = failed_check(chosen[name], name)
        if failed and not allow_failed:
            raise PipelineError(refusal("few-shot set", failed))
        adapter = sweep_files.load_adapter(Path(sweep_dir) / "adapters" / name, base.model)
        mark = FAILED_MARK if failed else ""
        out.append(Character(f"{name} (few-shot, rate {chosen[name]['rate']:g}){mark}", name, adapter, shots, name))
    if blend:
        shot_chars = out[len(base_styles):]
        if len(shot_chars) < 2:
            raise PipelineError("a blend needs two few-shot sets")
        out.append(drive.blend_character(base.character_model(), shot_chars[:2], (0.5, 0.5)))
    return out


def default_sets(chosen: dict, limit: int = 3) -> list[str]:
    """The few-shot sets to show by default: the sweep's walking (``_FW``) sets, else any, up to ``limit``."""
    walks = [s for s in chosen if s.endswith("_FW")]
    return (walks or list(chosen))[:limit]
