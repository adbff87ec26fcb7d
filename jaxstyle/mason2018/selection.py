"""Few-shot style learning end to end: hold-out, sweep, model selection, report (2018 section 7).

The paper chose each new style's dropout rate by eye. jaxstyle chooses it automatically:

1. **Hold-out** (:func:`holdout_rows`): the last locomotion cycle of every clip of a style (by its
   phase) is kept for validation, after a gap of ``gap_seconds`` so that the trajectory windows of
   the last training rows and the first validation rows overlap less; a clip's mirrored copy
   holds out the same frames.
2. **Sweep**: every (style, rate) pair is fine-tuned in one compiled program
   (:func:`jaxstyle.mason2018.fewshot.adapter_sweep`).
3. **Validation loss** per pair (:func:`validation_grid`): MSE of the held-out rows on normalised
   outputs, dropout off.
4. **Closed-loop check** per pair (:func:`check_rollouts`): the character walks a turning path
   (:func:`jaxstyle.control.loop.turning_path`, the style's own median speed, ``turn_deg_per_s``)
   for ``seconds``, driven only by its own predictions, i.e. beyond anything in the clip; the
   frozen base without an adapter (the style-agnostic "average motion") walks the same path from
   the same start. A pair passes (:func:`jaxstyle.output.check.passes_check`, the measures of
   :func:`jaxstyle.output.check.rollout_measures`, both shared with the 2022 sweep) when
   (:class:`jaxstyle.train.defaults.RolloutCheck`) every output is finite, bones keep
   their length (mean relative error <= ``max_bone_error``), feet touch the floor (fraction of
   frames with a foot on the floor >= ``min_contact_ratio`` x the real clip's), the adapter does
   not make feet slide (median speed of feet on the floor <= ``max_skating_ratio`` x the base's
   on the same path + ``skating_slack_m_s``) and the character travels between ``min_progress``
   and ``1 / min_progress`` times the requested distance (checked when the style moves at least
   0.1 m/s). Sliding is judged against the base rather than the real clip because raw PFNN
   output slides more than motion capture whatever the adapter (on the shared 100STYLE sample,
   0.3-0.5 m/s against 0.1-0.2 m/s; the 2022 paper removes it with foot IK): what the check must
   catch is an adapter that breaks what the base can do. The real clip's figures are reported
   beside it.
5. **Selection rule** (:func:`jaxstyle.output.check.choose_rates`, shared with the 2022 sweep): the
   rate with the lowest validation loss among the rates that pass the check; if none passes, the
   lowest validation loss, flagged as failing.

:func:`fewshot_sweep` runs all of it; :func:`jaxstyle.mason2018.sweep_files.write_report` saves one
orbax adapter checkpoint per style (with its config), ``results.csv`` (all pairs), ``heatmap.png``
and ``chosen_rates.json``.
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control.controller import PFNNModel
from jaxstyle.data.datasets import Dataset
from jaxstyle.data.normalise import Normaliser
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2018 import fewshot
from jaxstyle.mason2018.train import TrainData
from jaxstyle.motion import Motion
from jaxstyle.nn import pfnn
from jaxstyle.output import metrics
from jaxstyle.output.check import Judging, StyleStart, check_pairs, choose_rates, failed_criteria
from jaxstyle.train import scan
from jaxstyle.train.defaults import ROLLOUT_FIELDS, RolloutCheck

# --- 1. hold-out -----------------------------------------------------------------------------------

def holdout_rows(dataset: Dataset, style: str, *, cycles: float = 1.0, gap_seconds: float = 0.25,
                 max_fraction: float = 0.34, fps: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    """``(train, validation)`` row indices of ``style``: per clip, the rows of its last ``cycles``
    locomotion cycles (measured by the phase, at most ``max_fraction`` of the clip's rows) are
    validation, the ``gap_seconds`` before them are dropped, the rest is training.

    Warns when a clip's last ``cycles`` span more than ``max_fraction`` of its rows, so that only
    that fraction is held out: the clip's phase then advances too slowly for its motion, which
    usually means footsteps were missed (e.g. a fast gait at a low frame rate) and validation does
    not cover a whole cycle."""
    rows = dataset.rows_of_style(style)
    phase = dataset.phases[:, 0]
    train, val = [], []
    gap = int(round(gap_seconds * fps))
    for clip in np.unique(dataset.clip[rows]):
        r = rows[dataset.clip[rows] == clip]
        r = r[np.argsort(dataset.frame[r])]
        step = np.mod(np.diff(phase[r]), 1.0)
        from_end = np.concatenate([np.cumsum(step[::-1])[::-1], [0.0]])  # phase still to go after each row
        n_val = int(np.count_nonzero(from_end < cycles))
        if n_val > int(max_fraction * len(r)):
            warnings.warn(f"style {style!r}: the last {cycles:g} cycle(s) of {dataset.specs[clip].path} span "
                          f"{n_val} of its {len(r)} rows (the phase advances {from_end[0]:.1f} cycles in all); "
                          f"holding out {int(max_fraction * len(r))} rows ({max_fraction:.0%}) instead. Check the "
                          f"clip's phase labels (missed footsteps?)", stacklevel=2)
        n_val = max(1, min(n_val, int(max_fraction * len(r))))
        if len(r) - n_val - gap < 1:
            raise ValueError(f"style {style!r}: clip {dataset.specs[clip].path} has {len(r)} rows, too few to hold "
                             f"out {n_val} validation rows after a gap of {gap}")
        val.append(r[-n_val:])
        train.append(r[:len(r) - n_val - gap])
    return np.concatenate(train), np.concatenate(val)


def fewshot_data(dataset: Dataset, normalisers: tuple[Normaliser, Normaliser], styles: Sequence[str] | None = None,
                 **holdout) -> TrainData:
    """:class:`TrainData` of the few-shot ``styles`` (default: all of the dataset's), normalised with
    the BASE model's statistics, split by :func:`holdout_rows` (its keyword arguments)."""
    styles = tuple(dataset.styles if styles is None else styles)
    x_norm, y_norm = normalisers
    splits = [holdout_rows(dataset, s, **holdout) for s in styles]
    return TrainData(x_norm.apply(dataset.inputs).astype(np.float32), y_norm.apply(dataset.outputs).astype(np.float32),
                     dataset.phases[:, 0].astype(np.float32), tuple(t for t, _ in splits),
                     tuple(v for _, v in splits), styles)


# --- 3. validation loss ------------------------------------------------------------------------------

@jax.jit
def _mse_over_rates(params, adapters_R, x, y, phase):
    def one(a):
        return jnp.mean((pfnn.pfnn_apply(params, x, phase, adapter=a) - y) ** 2)

    return jax.vmap(one)(adapters_R)


def validation_grid(params: dict, adapters_SxR: dict, data: TrainData) -> np.ndarray:
    """``(S, R)`` validation MSE (normalised outputs, no dropout, no L1) of every pair."""
    out = []
    for s, rows in enumerate(data.val_rows):
        adapters_R = jax.tree.map(lambda v, s=s: v[s], adapters_SxR)
        out.append(np.asarray(_mse_over_rates(params, adapters_R, data.x[rows], data.y[rows], data.phase[rows])))
    return np.stack(out)


# --- 4. closed-loop check ----------------------------------------------------------------------------



class RolloutChecks(NamedTuple):
    """:func:`check_rollouts`' figures: per (set, rate) pair the ``measures`` ``(S, R)`` named by
    :data:`jaxstyle.train.defaults.ROLLOUT_FIELDS`, and per set the ``references`` ``(S,)`` (the real training rows' and
    the base's on the same path)."""

    measures: dict[str, np.ndarray]
    references: dict[str, np.ndarray]


def check_rollouts(model: PFNNModel, adapters_SxR: dict, dataset: Dataset, data: TrainData, skeleton: Motion, *,
                   fps: float = 60.0, check: RolloutCheck | None = None) -> RolloutChecks:
    """The closed-loop check of every pair of the base ``model`` with its ``(S, R)`` adapters
    (:func:`jaxstyle.output.check.check_pairs`, the base without an adapter as the last column: a
    zero adapter, whose residual is exactly zero) and its measures: ``(S, R)`` arrays named by
    :data:`jaxstyle.train.defaults.ROLLOUT_FIELDS`, and per-style reference figures: of the real training rows
    (``contact_fraction``, ``skating_m_s``, ``speed_m_s``; their feet as the network's output rows
    give them) and of the base on the same path (``base_skating_m_s``, ``base_bone_error``). Each
    style starts at its first training row."""
    check = check or RolloutCheck()
    upm = estimate_units_per_meter(skeleton)
    num_styles = len(data.styles)
    num_rates = jax.tree.leaves(adapters_SxR)[0].shape[1]
    ref = {k: np.zeros(num_styles) for k in ("contact_fraction", "skating_m_s", "speed_m_s")}
    starts, styles = [], []
    zero = jax.tree.map(lambda v: jnp.zeros_like(v[0, 0]), adapters_SxR)
    for s in range(num_styles):
        rows = data.train_rows[s]
        real_y = dataset.outputs[rows]
        real, floor = metrics.reference_foot_stats(real_y, skeleton, fps, units_per_meter=upm,
                                                   tolerance_m=check.tolerance_m)
        speed = float(np.median(np.linalg.norm(real_y[:, :2], axis=-1))) * fps  # units / s
        ref["contact_fraction"][s], ref["skating_m_s"][s], ref["speed_m_s"][s] = (
            real.contact_fraction, real.skating, speed / upm)
        first = rows[np.argmin(dataset.frame[rows])]
        starts.append(StyleStart(model.initial_state(dataset, first), speed, floor, real.contact_fraction))
        styles.append([jax.tree.map(lambda v, s=s, r=r: v[s, r], adapters_SxR) for r in range(num_rates)] + [zero])
    out, base_figures = check_pairs(model, styles, starts, Judging(skeleton, fps, upm, check))
    return RolloutChecks(out, {**ref, **base_figures})


# --- the whole pipeline and its report ------------------------------------------------------------

@dataclasses.dataclass
class SweepResult:
    """Everything a few-shot sweep produced; ``adapters`` has leading axes ``(S, R)``."""

    styles: tuple[str, ...]
    rates: tuple[float, ...]
    adapters: dict
    train_loss: np.ndarray
    validation_loss: np.ndarray
    rollout: dict[str, np.ndarray]
    reference: dict[str, np.ndarray]
    chosen: np.ndarray
    chosen_passed: np.ndarray
    train_rows: tuple[int, ...]
    validation_rows: tuple[int, ...]
    seconds: dict[str, float]
    check: RolloutCheck = dataclasses.field(default_factory=RolloutCheck)

    def failed(self, style: str) -> list[str]:
        """The closed-loop check's criteria the chosen pair of ``style`` fails
        (:func:`jaxstyle.output.check.failed_criteria`; ``[]`` when it passed, or when the result
        holds no reference figures to judge against)."""
        s = self.styles.index(style)
        r = int(self.chosen[s])
        ref = self.reference
        if not all(k in ref for k in ("contact_fraction", "base_skating_m_s", "speed_m_s")):
            return []
        return failed_criteria({k: float(self.rollout[k][s, r]) for k in ROLLOUT_FIELDS if k != "passed"},
                               float(ref["contact_fraction"][s]), float(ref["base_skating_m_s"][s]),
                               float(ref["speed_m_s"][s]), self.check)

    def chosen_rate(self, style: str) -> float:
        return self.rates[int(self.chosen[self.styles.index(style)])]

    def adapter(self, style: str, rate_index: int | None = None) -> dict:
        """One style's adapter, at its chosen rate unless ``rate_index`` is given."""
        s = self.styles.index(style)
        r = int(self.chosen[s]) if rate_index is None else rate_index
        return jax.tree.map(lambda v: v[s, r], self.adapters)


@dataclasses.dataclass(frozen=True)
class FewshotOptions:
    """What :func:`fewshot_sweep` uses of its dataset, how it judges and how it runs.

    Attributes:
      styles: a subset of the dataset's styles (``None``: all).
      holdout: keyword arguments of :func:`holdout_rows` (the validation rows).
      fps: the rows' frame rate.
      check: the closed-loop check's thresholds (:class:`jaxstyle.train.defaults.RolloutCheck`).
      run: steps per compiled call between progress updates, sharding of the styles over all
        devices, progress bars (:class:`jaxstyle.train.scan.GridRun`; here with progress bars and
        100 steps per call by default).
    """

    styles: Sequence[str] | None = None
    holdout: dict | None = None
    fps: float = 60.0
    check: RolloutCheck = RolloutCheck()
    run: scan.GridRun = scan.GridRun(chunk_steps=100, progress=True)


def fewshot_sweep(params: dict, normalisers: tuple[Normaliser, Normaliser], dataset: Dataset, skeleton: Motion,
                  config: fewshot.SweepConfig | None = None, options: FewshotOptions = FewshotOptions()
                  ) -> SweepResult:
    """Fine-tune a new adapter for every (style, rate) of ``dataset`` (few-shot styles, PFNN rows)
    on a frozen base, then validate, check and choose a rate per style (module docstring).

    Args:
      params: the frozen base PFNN; ``normalisers``: its input and output statistics.
      dataset: the few-shot styles' rows (:func:`jaxstyle.data.datasets.build_pfnn_dataset`).
      skeleton: a clip of the skeleton (bone lengths, feet, units) for the closed-loop check.
      config: sweep settings (:class:`jaxstyle.mason2018.fewshot.SweepConfig`); its ``model`` must describe
        ``params`` (the default is the paper's 234 -> 512 -> 512 -> 400 network).
      options: styles, validation rows, frame rate, check thresholds, chunks, sharding and progress
        (:class:`FewshotOptions`).
    """
    config = config or fewshot.SweepConfig()
    check, fps = options.check, options.fps
    if params["l0"]["W"].shape[1] != dataset.inputs.shape[1]:
        raise ValueError(f"the base model takes {params['l0']['W'].shape[1]} inputs but the few-shot "
                         f"dataset has {dataset.inputs.shape[1]} (a different skeleton?)")
    timings = {}
    data = fewshot_data(dataset, normalisers, options.styles, fps=fps, **(options.holdout or {}))
    batches, mask = scan.sweep_batches(data.train_rows, config.epochs, config.batch_size, seed=config.seed)
    t0 = time.perf_counter()
    adapters, losses = fewshot.adapter_sweep(params, jnp.asarray(data.x), jnp.asarray(data.y),
                                              jnp.asarray(data.phase), batches, mask, config, run=options.run)
    jax.block_until_ready(adapters)
    timings["sweep"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    val = validation_grid(params, adapters, data)
    model = PFNNModel.create(params, normalisers, skeleton.num_joints)
    rollout, reference = check_rollouts(model, adapters, dataset, data, skeleton, fps=fps, check=check)
    timings["selection"] = time.perf_counter() - t0
    chosen, passed = choose_rates(val, rollout["passed"])
    losses = np.asarray(losses)
    per_epoch = np.maximum(mask.sum(1) // max(config.epochs, 1), 1)
    final_train = np.stack([np.nanmean(losses[s, :, mask[s].sum() - per_epoch[s]:mask[s].sum()], axis=-1)
                            for s in range(len(data.styles))])
    return SweepResult(data.styles, tuple(config.rates), adapters, final_train, val, rollout, reference, chosen,
                       passed, tuple(len(r) for r in data.train_rows), tuple(len(r) for r in data.val_rows), timings,
                       check)
