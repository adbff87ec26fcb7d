"""The training drivers both papers share.

* :func:`train_scan`: Adam (or any optax) steps as one ``lax.scan``, gradients for a trainable tree
  only, with a mask for padded steps (:class:`Steps`: inputs, mask and keys).
* :func:`grid_sweep`: the (set, rate) grid of fine-tuning runs as ONE compiled program, ``jit`` of
  ``vmap`` over sets of ``vmap`` over rates of :func:`train_scan`; the frozen tree is broadcast
  (``in_axes=None``, never copied per pair), the rate is a traced array (not a Python branch), the
  steps may run in chunks under a progress bar, the set axis may be sharded over all devices.
  :func:`run_pair` is one cell of that grid without the vmaps (the reference the grid is tested
  against, and a single fine-tuning run). The 2018 few-shot adapter sweep
  (:func:`jaxstyle.mason2018.fewshot.adapter_sweep`) and the 2022 FiLM generator sweep
  (:func:`jaxstyle.mason2022.finetune.finetune_film_sweep`) are two uses of it with their own losses.
* :func:`fit`: the epoch loop of a full training run (resume from the last checkpoint, chunks of
  steps under a progress bar, a finite-loss check, a checkpoint and a ``log.csv`` row per epoch),
  used by :func:`jaxstyle.mason2018.train.train` and :func:`jaxstyle.mason2022.train.train`.
* :func:`sweep_batches` and :func:`pair_key`: per-set batch plans and the PRNG key of each cell;
  :func:`row_bucket` / :func:`pad_rows`: data rows padded to a few sizes, so that sets of other
  lengths (a second clip learned live) reuse the compiled program.

A grid loss is a hashable callable (a frozen dataclass, or a module-level function) called as
``loss_fn(trainable, frozen, step_inputs, key, rate, hparams) -> scalar``; it may have a
``prepare(frozen) -> frozen`` method, run once per compiled call outside the vmaps (casting weights,
caching activations that no step changes). It is a static argument of the compiled programs, so an
equal loss object reuses the compiled program.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxstyle.train import runlog
from jaxstyle.train.checkpoint import Checkpointer, NonFiniteError, non_finite_leaves
from jaxstyle.train.defaults import DEFAULT_RATES  # noqa: F401  (re-exported)
from jaxstyle.train.shard import gather

SMALL_ROWS = 16384  # up to this many rows the data is padded to a power of two


def row_bucket(num_rows: int) -> int:
    """The row count a grid's data is padded to (:func:`pad_rows`): the next power of two up to
    :data:`SMALL_ROWS` (a few MB of rows: clips of 4-17 s at 60 frames/s with their mirrors share one
    size), above it the next multiple of ``2 ** (bits - 3)`` (at most a quarter more rows). A
    compiled program takes the data's shape as part of its signature: without padding every clip
    length would compile the sweep again."""
    n = max(int(num_rows), 1)
    if n <= SMALL_ROWS:
        return 1 << (n - 1).bit_length()
    step = 1 << (n.bit_length() - 3)
    return -(-n // step) * step


def pad_rows(*arrays):
    """``arrays`` (equal first dimension) zero-padded along it to :func:`row_bucket` rows. Batches
    index only the real rows, so the padding changes no result."""
    n = arrays[0].shape[0]
    pad = row_bucket(n) - n
    return tuple(jnp.pad(jnp.asarray(a), [(0, pad)] + [(0, 0)] * (a.ndim - 1)) for a in arrays)


def sweep_batches(rows_per_style: Sequence[np.ndarray], epochs: int, batch_size: int, seed: int = 0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``(S, T, B)`` row indices and ``(S, T)`` step masks: each style's rows shuffled every epoch,
    ``max(1, rows // B)`` batches per epoch (a style smaller than a batch is sampled with
    replacement), padded to the longest style with masked steps."""
    per_style = []
    for s, rows in enumerate(rows_per_style):
        rows = np.asarray(rows)
        if len(rows) == 0:
            raise ValueError(f"style {s} has no training rows")
        rng = np.random.default_rng([seed, s])
        per_epoch = max(len(rows) // batch_size, 1)
        epochs_idx = []
        for _ in range(epochs):
            order = rng.permutation(rows)
            if len(order) < batch_size:
                order = rng.choice(rows, size=batch_size, replace=True)
            epochs_idx.append(order[:per_epoch * batch_size].reshape(per_epoch, batch_size))
        per_style.append(np.concatenate(epochs_idx))
    steps = max(len(b) for b in per_style)
    batches = np.zeros((len(per_style), steps, batch_size), dtype=np.int32)
    mask = np.zeros((len(per_style), steps), dtype=bool)
    for s, b in enumerate(per_style):
        batches[s, :len(b)], mask[s, :len(b)] = b, True
    return batches, mask


class Steps(NamedTuple):
    """The steps of a training scan, step axis ``T`` last of the leading axes: ``inputs``, a tree of
    per-step inputs (e.g. batch row indices); ``mask``, real steps (a masked step changes nothing
    and reports NaN); ``keys``, one raw PRNG key per step."""

    inputs: Any
    mask: Any
    keys: Any


Optimizer = float | optax.GradientTransformation
"""A learning rate for ``optax.adam``, or an optax optimizer (reuse the same object to reuse a
compiled program: it is a static argument)."""


def _optimiser(optimizer: Optimizer) -> optax.GradientTransformation:
    if isinstance(optimizer, optax.GradientTransformation):
        return optimizer
    if isinstance(optimizer, (int, float)) and not isinstance(optimizer, bool):
        return optax.adam(float(optimizer))
    raise TypeError(f"optimizer must be a learning rate (Adam) or an optax optimizer, got {optimizer!r}")


def train_scan(loss_fn, trainable, opt_state, steps: Steps, *, optimizer: Optimizer, has_aux: bool = False):
    """Optimiser steps as one ``lax.scan``: step ``t`` takes the gradient of
    ``loss_fn(trainable, steps.inputs[t], steps.keys[t])`` with respect to ``trainable`` alone
    (whatever else the loss uses is closed over, i.e. frozen); masked steps (``steps.mask[t]``
    false) change nothing. ``optimizer``: a learning rate for ``optax.adam`` or an optax optimizer.

    Returns the trained tree, the optimiser state and per-step losses (NaN when masked); with
    ``has_aux`` the loss returns ``(value, aux)`` and the last result is ``(losses, aux_T)``, the
    aux tree NaN on masked steps too."""
    optimiser = _optimiser(optimizer)

    def step(carry, inputs):
        a, opt = carry
        step_inputs, real, k = inputs
        value, grads = jax.value_and_grad(loss_fn, has_aux=has_aux)(a, step_inputs, k)
        updates, new_opt = optimiser.update(grads, opt, a)
        new_a = optax.apply_updates(a, updates)
        keep = lambda new, old: jnp.where(real, new, old)  # noqa: E731
        hide = lambda v: jnp.where(real, v, jnp.nan)  # noqa: E731
        return (jax.tree.map(keep, new_a, a), jax.tree.map(keep, new_opt, opt)), jax.tree.map(hide, value)

    (trainable, opt_state), losses = jax.lax.scan(step, (trainable, opt_state), tuple(steps))
    return trainable, opt_state, losses


def pair_key(seed: int, style: int, rate_index: int) -> jax.Array:
    """The PRNG key of one (style, rate) pair: its adapter's initial values and dropout masks."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(seed), style), rate_index)


# --- the (set, rate) grid ------------------------------------------------------------------------

def _prepared(loss_fn, frozen):
    prepare = getattr(loss_fn, "prepare", None)
    return frozen if prepare is None else prepare(frozen)


def _pair_scan(loss_fn, trainable, opt_state, frozen, steps: Steps, rate, hparams, optimizer):
    def loss(t, step_inputs, key):
        return loss_fn(t, frozen, step_inputs, key, rate, hparams)

    return train_scan(loss, trainable, opt_state, steps, optimizer=optimizer)


@functools.partial(jax.jit, static_argnames=("loss_fn", "optimizer"))
def run_pair(loss_fn, trainable, opt_state, frozen, steps: Steps, rate, hparams=None, *, optimizer: Optimizer):
    """One cell of :func:`grid_sweep` (one set, one rate) without the vmaps, compiled: the steps
    (``inputs`` a tree of ``(T, ...)`` arrays, ``mask (T,)``, ``keys (T, 2)``) from ``trainable`` and
    ``opt_state``. Returns ``(trainable, opt_state, losses_T)``."""
    return _pair_scan(loss_fn, trainable, opt_state, _prepared(loss_fn, frozen), Steps(*steps), rate, hparams,
                      optimizer)


@functools.partial(jax.jit, static_argnames=("loss_fn", "optimizer"), donate_argnames=("trainable_GxR", "opt_GxR"))
def _grid_chunk(loss_fn, trainable_GxR, opt_GxR, frozen, inputs_GxT, mask_GxT, keys_GxRxT, rates_R, hparams, *,
                optimizer):
    """One chunk of steps of every (set, rate) cell: vmap over sets of vmap over rates of the
    per-cell scan; ``frozen`` and ``hparams`` broadcast (``in_axes=None``) to every cell."""
    frozen = _prepared(loss_fn, frozen)

    def cell(t, o, k, r, inputs, mask, fz, hp):
        return _pair_scan(loss_fn, t, o, fz, Steps(inputs, mask, k), r, hp, optimizer)

    over_rates = jax.vmap(cell, in_axes=(0, 0, 0, 0, None, None, None, None))
    over_sets = jax.vmap(over_rates, in_axes=(0, 0, 0, None, 0, 0, None, None))
    return over_sets(trainable_GxR, opt_GxR, keys_GxRxT, rates_R, inputs_GxT, mask_GxT, frozen, hparams)


def _pad_axis(v, axis: int, n: int, *, edge: bool = False):
    """``v`` with ``n`` entries appended along ``axis``: zeros, or copies of the last entry."""
    if n == 0:
        return v
    if edge:
        last = jax.lax.slice_in_dim(jnp.asarray(v), v.shape[axis] - 1, v.shape[axis], axis=axis)
        return jnp.concatenate([v, jnp.repeat(last, n, axis=axis)], axis=axis)
    widths = [(0, 0)] * v.ndim
    widths[axis] = (0, n)
    return jnp.pad(v, widths) if isinstance(v, jax.Array) else np.pad(np.asarray(v), widths)


@dataclasses.dataclass(frozen=True)
class GridRun:
    """How :func:`grid_sweep` runs (none of it changes the result).

    Attributes:
      chunk_steps: run the steps in chunks of that many (one compiled program called
        ``ceil(T / chunk_steps)`` times, the last chunk padded with masked steps), so ``progress``
        can move a bar between chunks; ``None``: one call.
      shard: spread the set axis over all devices (a 1-D mesh, ``frozen`` replicated), padded
        with fully masked sets to a multiple of the device count. Under ``jax.distributed`` the
        devices of every process take part (every process calls with the same arguments) and
        every process gets the whole result back.
      progress, desc: a progress bar (moving between chunks) and its title.
    """

    chunk_steps: int | None = None
    shard: bool = False
    progress: bool = False
    desc: str | None = None


def grid_sweep(loss_fn, trainable_GxR, frozen, steps: Steps, rates_R, *, optimizer: Optimizer, hparams: Any = None,
               run: GridRun = GridRun()) -> tuple[Any, jax.Array]:
    """Train every (set, rate) cell of a grid in one compiled program.

    Args:
      loss_fn: ``loss_fn(trainable, frozen, step_inputs, key, rate, hparams) -> scalar``, hashable
        (see the module docstring), optionally with ``prepare(frozen)``.
      trainable_GxR: the tree trained, leaves stacked ``(G, R, ...)`` (one start per cell; not
        modified: the driver trains a copy), each cell with a fresh optimiser state.
      frozen: a tree the loss reads and no step changes (network, data), broadcast to every cell.
      steps: ``inputs``, a tree of ``(G, T, ...)`` per-set step inputs (e.g. batch row indices);
        ``mask``, ``(G, T)`` real steps (masked steps change nothing and report NaN); ``keys``,
        ``(G, R, T, 2)`` one raw PRNG key per cell and step.
      rates_R: ``(R,)`` the per-rate hyperparameter (or a tree of ``(R, ...)`` arrays), traced.
      optimizer: a learning rate for ``optax.adam``, or an optax optimizer (reuse the same object
        to reuse the compiled program).
      hparams: a tree of arrays shared by all cells (traced: changing a value does not recompile).
      run: chunks, sharding and progress (:class:`GridRun`).

    Returns the trained tree ``(G, R, ...)`` and per-step losses ``(G, R, T)``.
    """
    inputs_GxT, mask_GxT, keys_GxRxT = steps
    chunk_steps, shard, progress, desc = run.chunk_steps, run.shard, run.progress, run.desc
    if isinstance(rates_R, (tuple, list)):
        rates_R = jnp.asarray(rates_R, jnp.float32)
    mask = np.asarray(mask_GxT, bool)
    num_sets, num_steps = mask.shape
    num_rates = jax.tree.leaves(rates_R)[0].shape[0]
    padded = num_sets
    if shard:
        padded = -(-num_sets // jax.device_count()) * jax.device_count()
    chunk = num_steps if chunk_steps is None else max(1, min(int(chunk_steps), num_steps))
    total = -(-num_steps // chunk) * chunk

    inputs = jax.tree.map(lambda v: _pad_axis(_pad_axis(np.asarray(v), 0, padded - num_sets), 1, total - num_steps),
                          inputs_GxT)
    mask = _pad_axis(_pad_axis(mask, 0, padded - num_sets), 1, total - num_steps)
    keys = _pad_axis(_pad_axis(jnp.asarray(keys_GxRxT), 0, padded - num_sets), 2, total - num_steps)
    trainable = jax.tree.map(lambda v: _pad_axis(jnp.array(v, copy=True), 0, padded - num_sets, edge=True),
                             trainable_GxR)
    opt = jax.vmap(jax.vmap(_optimiser(optimizer).init))(trainable)
    inputs, mask = jax.tree.map(jnp.asarray, inputs), jnp.asarray(mask)
    if shard:
        from jax.sharding import Mesh, NamedSharding, PartitionSpec

        mesh = Mesh(np.array(jax.devices()), ("grid",))
        grid, everywhere = NamedSharding(mesh, PartitionSpec("grid")), NamedSharding(mesh, PartitionSpec())
        if jax.process_count() > 1:  # host copies, the same on every process, go onto the global mesh
            trainable, opt, keys, inputs, mask = jax.tree.map(np.asarray, (trainable, opt, keys, inputs, mask))
            frozen, rates_R, hparams = jax.tree.map(np.asarray, (frozen, rates_R, hparams))
        trainable, opt, keys, inputs, mask = jax.device_put((trainable, opt, keys, inputs, mask), grid)
        frozen, rates_R, hparams = jax.device_put((frozen, rates_R, hparams), everywhere)
    bar = runlog.progress_bar(num_steps, desc or f"sweep {num_sets} sets x {num_rates} rates", progress)
    losses = []
    for a in range(0, total, chunk):
        b = a + chunk
        trainable, opt, chunk_losses = _grid_chunk(
            loss_fn, trainable, opt, frozen, jax.tree.map(lambda v, a=a, b=b: v[:, a:b], inputs), mask[:, a:b],
            keys[:, :, a:b], rates_R, hparams, optimizer=optimizer)
        losses.append(chunk_losses)
        if bar is not None:
            jax.block_until_ready(chunk_losses)
            bar.update(min(b, num_steps) - a)
            bar.set_postfix(loss=f"{float(jnp.nanmean(chunk_losses)):.4f}")
    if bar is not None:
        bar.close()
    losses = jnp.concatenate(losses, axis=2)
    if shard and jax.process_count() > 1:  # sets trained on other processes' devices: gathered here
        trainable, losses = jax.tree.map(jnp.asarray, gather((trainable, losses)))
    return jax.tree.map(lambda v: v[:num_sets], trainable), losses[:num_sets, :, :num_steps]


# --- full training runs --------------------------------------------------------------------------

def _check_finite(epoch: int, losses: np.ndarray, state: dict, ckpt: Checkpointer | None) -> None:
    """Raise :class:`NonFiniteError` naming the epoch (1-based) when its losses or the state are
    not all finite; nothing of that epoch has been saved."""
    if np.isfinite(losses).all():
        bad = non_finite_leaves(state)
        if not bad:
            return
        what = f"the state's {', '.join(bad[:5])}{' ...' if len(bad) > 5 else ''} hold NaN or infinity"
    else:
        what = f"the training loss became non-finite ({int(np.sum(~np.isfinite(losses)))} values)"
    kept = ""
    if ckpt is not None:
        last = ckpt.latest_step()
        kept = f"; the last checkpoint kept is step {last} in {ckpt.steps_dir}" if last is not None else \
            "; no checkpoint was saved"
    raise NonFiniteError(f"epoch {epoch + 1}: {what}; not saving it{kept}. Check the data for absurd values "
                         "(jaxstyle data prepare) or lower the learning rate")


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """How :func:`fit` runs an epoch loop.

    Attributes:
      log_every: steps per chunk (the progress bar moves between chunks).
      progress: show a progress bar per epoch.
      stop_after_epochs: end the call after that many epochs (to test resuming).
      check_finite: raise :class:`~jaxstyle.train.checkpoint.NonFiniteError` (a
        ``FloatingPointError``) naming the epoch when an epoch's losses or the state's parameters
        are not all finite, before anything of that epoch is saved (the checkpointer refuses a
        non-finite tree in any case).
      say: where the line ``resumed from step N in DIR`` goes when a checkpoint is resumed
        (default ``print``; ``None`` for silence). A damaged newest step is a warning naming it and
        the step used instead; it is moved to ``DIR/damaged/`` so the resumed run can write it again.
      keep: how many of the newest epochs' checkpoints are kept.
    """

    log_every: int = 50
    progress: bool = True
    stop_after_epochs: int | None = None
    check_finite: bool = True
    say: Callable[[str], None] | None = print
    keep: int = 3


def fit(state: Any, epochs: int, plan_epoch: Callable[[int], tuple[int, Callable]], *,
        directory: str | Path | None = None, run_config: Any = None,
        end_epoch: Callable[[int, Any, np.ndarray], dict] | None = None,
        options: FitOptions = FitOptions()) -> Any:
    """The epoch loop of a training run; returns the final state.

    Args:
      state: the initial state, a NamedTuple with an ``epoch`` field (epochs done, an int32 array;
        e.g. :class:`jaxstyle.mason2018.train.BaseState`); replaced by the last checkpoint of
        ``directory`` when there is one (resuming; saved as the dict of its fields,
        :func:`jaxstyle.train.checkpoint.saved_form`).
      epochs: train until ``state.epoch`` reaches this.
      plan_epoch: ``plan_epoch(epoch) -> (num_steps, run_chunk)``; ``run_chunk(state, a, b)`` runs
        steps ``a..b-1`` of the epoch (one compiled ``lax.scan``) and returns the new state and
        the per-step losses ``(b - a,)`` or ``(b - a, K)`` (column 0 the training loss).
      directory: the run folder: ``config.json`` (``run_config``), orbax checkpoints (one per
        epoch, the last ``options.keep`` kept) and ``log.csv``; ``None`` keeps nothing.
      end_epoch: ``end_epoch(epoch, state, losses_TxK) -> row``, the epoch's ``log.csv`` columns
        after ``epoch`` (e.g. validation losses), called with a directory only; ``fit`` fills
        ``"seconds"`` (at the row's ``"seconds"`` key if present, else last).
      options: chunking, progress, early stop, the finite check, the resume line (:class:`FitOptions`).
    """
    log_every, progress, stop_after_epochs = options.log_every, options.progress, options.stop_after_epochs
    check_finite, say = options.check_finite, options.say
    ckpt = Checkpointer(directory, run_config, max_to_keep=options.keep) if directory is not None else None
    try:
        if ckpt is not None and ckpt.latest_step() is not None:
            state = ckpt.restore(state)
            ckpt.set_aside_after(ckpt.restored_step)
            if say is not None:
                say(f"resumed from step {ckpt.restored_step} in {ckpt.steps_dir} (epoch {int(state.epoch)} done)")
        start = int(state.epoch)
        log_path = Path(directory) / "log.csv" if directory is not None else None
        if log_path is not None:
            runlog.truncate_log(log_path, start)
        done = 0
        for epoch in range(start, epochs):
            if stop_after_epochs is not None and done >= stop_after_epochs:
                break
            t0 = time.perf_counter()
            num_steps, run_chunk = plan_epoch(epoch)
            bar = runlog.progress_bar(num_steps, f"epoch {epoch + 1}/{epochs}", progress)
            parts = []
            for a in range(0, num_steps, log_every):
                b = min(a + log_every, num_steps)
                state, out = run_chunk(state, a, b)
                parts.append(np.asarray(out))
                if bar is not None:
                    bar.update(b - a)
                    bar.set_postfix(loss=f"{float(np.mean(parts[-1].reshape(b - a, -1)[:, 0])):.4f}")
            if bar is not None:
                bar.close()
            out = np.concatenate(parts)
            if check_finite:
                _check_finite(epoch, out, state, ckpt)
            state = state._replace(epoch=jnp.asarray(epoch + 1, jnp.int32))
            if ckpt is not None:
                row = dict(end_epoch(epoch, state, out)) if end_epoch is not None else {}
                ckpt.save(epoch + 1, state, checked_finite=check_finite)  # _check_finite scanned it
                row = {"epoch": epoch + 1, **row}
                row["seconds"] = f"{time.perf_counter() - t0:.2f}"
                runlog.append_log(log_path, row)
            done += 1
    finally:
        if ckpt is not None:
            ckpt.close()
    return state
