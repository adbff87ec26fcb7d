"""Training and testing of the 2022 style models (Mason, Starke & Komura 2022, section 4.3), for
any of the seven models of :mod:`jaxstyle.nn.style_models`, on the rows of
:func:`jaxstyle.mason2022.styledata.style_data` with the loss of :mod:`jaxstyle.mason2022.loss`.

* :func:`train`: style-balanced training (each minibatch one style, round robin, an epoch one
  pass over the smallest style; :func:`jaxstyle.data.batching.balanced_batches`), Adam 1e-4, batch
  32, dropout 0.3, steps in jitted ``lax.scan`` chunks under a progress bar, per-epoch
  validation, orbax checkpoints with the config beside them, ``log.csv``; resumes. Options not in
  the paper: noise on the inputs (all of them, or only the joint features the closed loop feeds
  back) and rollout training (:mod:`jaxstyle.mason2022.loss`).
* :func:`evaluate`: per-style normalised MSE and bone-length loss, dropout off; a FiLM model uses
  each style's precomputed FiLM vector (the mean over its training clips, as at runtime).

New styles (fine-tuning the FiLM generator) are :mod:`jaxstyle.mason2022.finetune`'s.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxstyle.data.batching import balanced_batches
from jaxstyle.data.lpn_features import LPNLayout
from jaxstyle.mason2022.loss import Batch, LossWeights, batch_loss, positions_m, rollout_loss
from jaxstyle.mason2022.styledata import BonePositions, StaticBones, StyleData, bones_of, device_arrays, rollout_starts
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import lpn, pfnn, style_models
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.train import scan, shard
from jaxstyle.train.checkpoint import Checkpointer


@dataclasses.dataclass(frozen=True)
class LPNTrainConfig:
    """Paper: batch 32, Adam 1e-4, dropout 0.3 everywhere, MSE + BLL weighted 1:1, 90 epochs.

    Not in the paper (0: its recipe): ``input_noise``, Gaussian noise on the normalised inputs
    (:func:`jaxstyle.mason2022.loss.noisy_inputs`); ``feedback_noise``, the same noise on the joint
    features only (:func:`noise_std`); ``rollout_steps``, rollout training: each
    batch row starts a window of ``1 + rollout_steps`` consecutive frames in which the network reads
    its own previous output (:func:`jaxstyle.mason2022.loss.rollout_loss`); ``contact_loss_weight``,
    the weight of :func:`jaxstyle.mason2022.loss.contact_loss` (planted feet do not move);
    ``average_epochs``, the model is the mean of the weights after each of the last
    ``average_epochs`` epochs (:func:`averaged_params`; 0 or 1: the last epoch's, the paper's)."""

    model: StyleModelConfig = StyleModelConfig()
    epochs: int = 90
    batch_size: int = 32
    learning_rate: float = 1e-4
    dropout_rate: float = 0.3
    bone_loss_weight: float = 1.0
    seed: int = 0
    log_every: int = 50
    input_noise: float = 0.0
    rollout_steps: int = 0
    contact_loss_weight: float = 0.0
    feedback_noise: float = 0.0
    average_epochs: int = 0


#: The options outside the paper's recipe, written to ``config.json`` only when set.
EXTRA_OPTIONS = ("input_noise", "rollout_steps", "contact_loss_weight", "feedback_noise", "average_epochs")


def noise_std(config: LPNTrainConfig) -> np.ndarray:
    """``(input_size,)`` standard deviation of the training noise on each normalised input column:
    ``input_noise`` on every column, plus ``feedback_noise`` on the joint features (positions,
    velocities, forward and up vectors of :class:`jaxstyle.data.lpn_features.LPNLayout`).

    Not in the paper. At run time the joint features are the network's own previous output, while
    the trajectory columns come from the user's path and are never the network's error, so noise on
    the joint features alone imitates what the closed loop feeds back (the exposure-bias remedy
    applied where the exposure is); ``input_noise`` also perturbs the trajectory. Only the LPN
    backbone's layout is known here, so ``feedback_noise`` needs it."""
    size = config.model.input_size
    std = np.full(size, config.input_noise, np.float32)
    if config.feedback_noise:
        if config.model.backbone != "lpn":
            raise ValueError(f"feedback_noise needs the lpn backbone's inputs, got {config.model.backbone!r}")
        for name, columns in LPNLayout.of_inputs(size).input_groups.items():
            if name.startswith("joint_"):
                std[columns] += config.feedback_noise
    return std


PAPER_BATCH = 32


def with_batch_size(config: LPNTrainConfig, batch_size: int) -> LPNTrainConfig:
    """``config`` at another batch size with Adam's learning rate scaled by the square-root rule,
    ``lr = lr_32 * sqrt(batch / 32)`` (Malladi et al. 2022, "On the SDEs and Scaling Rules for
    Adaptive Gradient Algorithms": for Adam the noise scale is kept by scaling the rate with the
    square root of the batch, where SGD's linear rule overshoots). Not the paper's setting (batch
    32, 1e-4): a FiLM step reads ONE style clip whatever the batch, so a batch of 128 does the
    generator's work (most of a step, ``benchmarks/lpn_training.py``) once per 128 rows instead of
    per 32, an epoch of a quarter of the steps."""
    if batch_size < 1:
        raise ValueError(f"batch_size must be positive, got {batch_size}")
    lr = config.learning_rate * (batch_size / config.batch_size) ** 0.5
    return dataclasses.replace(config, batch_size=int(batch_size), learning_rate=float(lr))


# --- training -----------------------------------------------------------------------------------

class ModelState(NamedTuple):
    """A 2022 style model's training state: its ``params``, the Adam ``opt_state`` and the epochs
    done (``epoch``, int32). Checkpointed as the dict of these fields."""

    params: dict
    opt_state: Any
    epoch: jax.Array


def init_state(key: jax.Array, config: LPNTrainConfig) -> ModelState:
    """The :class:`ModelState` before training: random weights
    (:func:`jaxstyle.nn.style_models.init_model`), a fresh Adam state, epoch 0."""
    params = style_models.init_model(key, config.model)
    return ModelState(params, optax.adam(config.learning_rate).init(params), jnp.zeros((), jnp.int32))


COMPUTE_DTYPES = ("float32", "bfloat16")


def _step_loss(params, config: StyleModelConfig, arrays, inputs, key, rate, weight, bones, compute_dtype: str,
               noise=0.0, feedback=None, rollout_steps: int = 0, contact_weight=None):
    """One step's loss; ``compute_dtype="bfloat16"`` casts every weight matrix to bfloat16 for the
    products (accumulated in float32: :func:`jaxstyle.nn.pfnn.pf_dense`,
    :func:`jaxstyle.nn.film_generator.generator_apply`), the float32 master weights get float32
    gradients through the cast and Adam runs in float32 (mixed precision, Micikevicius et al. 2018)."""
    if compute_dtype != "float32":
        params = pfnn.cast_weights(params, jnp.dtype(compute_dtype))
    weights = LossWeights(rate, weight, noise, contact_weight)
    if rollout_steps:
        return rollout_loss(params, config, arrays, feedback, Batch(*inputs), key, weights, bones_of(bones),
                            steps=rollout_steps)
    return batch_loss(params, config, arrays, Batch(*inputs), key, weights, bones_of(bones))


@functools.partial(jax.jit, static_argnames=("config", "bones", "learning_rate", "compute_dtype", "rollout_steps"),
                   donate_argnames=("params", "opt_state"))
def _train_chunk(params, opt_state, arrays, batches_TxB, styles_T, clips_T, keys_T, rate, weight, noise=0.0,
                 feedback=None, contact_weight=None, *, config: StyleModelConfig, bones: BonePositions,
                 learning_rate: float, compute_dtype: str = "float32", rollout_steps: int = 0):
    """Steps of full training as one ``lax.scan``: per step the gradient of
    :func:`jaxstyle.mason2022.loss.batch_loss` and an ``optax.adam(learning_rate)`` update; returns
    the new parameters, optimiser state and per step ``(loss, mse, bll)``.

    The same steps as :func:`jaxstyle.train.scan.train_scan` (the fine-tuning sweeps' driver, kept
    as the reference in ``tests/test_lpn_fast.py``) with two changes that do not change a value:
    no padded-step mask (full training has none; the mask's ``where`` kept the old and new
    39 M-value trees alive together) and the parameters and Adam state are DONATED, so XLA updates
    them in place instead of writing 3 x 177 MB of fresh buffers per call. On this 2-core CPU fresh
    memory is costly: a donated Adam update of LPN-FiLM's 44 M values ran ~9x faster than an
    undonated one (the kernel zero-fills every new page; ``docs/mason2022.md``, "Training
    speed"). The caller's
    ``params`` and ``opt_state`` are consumed."""
    optimiser = optax.adam(learning_rate)

    def step(carry, inputs):
        p, opt = carry
        *step_inputs, key = inputs
        (value, (mse, bll)), grads = jax.value_and_grad(_step_loss, has_aux=True)(
            p, config, arrays, step_inputs, key, rate, weight, bones, compute_dtype, noise, feedback, rollout_steps,
            contact_weight)
        updates, opt = optimiser.update(grads, opt, p)
        return (optax.apply_updates(p, updates), opt), jnp.stack([value, mse, bll])

    (params, opt_state), out = jax.lax.scan(step, (params, opt_state), (batches_TxB, styles_T, clips_T, keys_T))
    return params, opt_state, out


def epoch_batches(data: StyleData, config: LPNTrainConfig, epoch: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One epoch: ``(steps, batch)`` rows (one style per batch, round robin), ``(steps,)`` style of
    each batch and ``(steps,)`` a random training clip of that style."""
    seed = config.seed * 100_003 + epoch
    batches = balanced_batches(data.train_rows, config.batch_size, seed=seed)
    styles = np.tile(np.arange(len(data.styles)), len(batches) // len(data.styles)).astype(np.int32)
    rng = np.random.default_rng([config.seed, epoch, 7])
    clips = np.array([rng.choice(data.train_clips[s]) for s in styles], dtype=np.int32)
    return batches.astype(np.int32), styles, clips


def train(data: StyleData, config: LPNTrainConfig, directory: str | Path | None = None, *, progress: bool = True,
          stop_after_epochs: int | None = None, compute_dtype: str = "float32",
          devices: str | int | None = None) -> ModelState:
    """Train (or resume) a style model; returns the final :class:`ModelState`.

    ``directory`` keeps ``config.json``, orbax checkpoints (one per epoch, the last 3 kept, or the
    last ``config.average_epochs`` when more) and ``log.csv`` (train loss, MSE and BLL, validation
    MSE and BLL, seconds per epoch); a second call with the same directory resumes from the last
    checkpoint. ``stop_after_epochs`` ends the call early (to test resuming).

    ``compute_dtype="bfloat16"``: the layer products in bfloat16, accumulated in float32, float32
    master weights and Adam (an option, not the paper's setting; recorded in ``config.json``).
    ``devices="all"`` (or a count): data-parallel over that many devices
    (:mod:`jaxstyle.train.shard`: each batch's rows split over the devices, the parameters
    replicated); the batch size must divide by the device count. The result equals the one-device
    run up to the order of float sums, so a run may resume on another device count.

    ``config.rollout_steps > 0``: batches are drawn from the training rows that start a whole
    window (:func:`jaxstyle.mason2022.styledata.rollout_starts`) and each step is
    :func:`jaxstyle.mason2022.loss.rollout_loss`.

    ``config.average_epochs > 1``: the returned parameters are the mean of the last epochs' saved
    ones (:func:`averaged_params`; the checkpoints keep the last epoch's training state, so a run
    resumes as without it); it needs ``directory``."""
    if config.model.num_styles != len(data.styles):
        raise ValueError(f"the model has {config.model.num_styles} styles, the data {len(data.styles)}")
    if config.average_epochs < 0 or (config.average_epochs > 1 and directory is None):
        raise ValueError(f"average_epochs must be >= 0 and, above 1, needs a run directory to keep the epochs' "
                         f"weights (got {config.average_epochs}, directory {directory})")
    if config.average_epochs > 1 and jax.process_count() > 1:
        raise ValueError("average_epochs above 1 reads every kept epoch back from the run folder, which only the first "
                         "of several processes writes: train with one process, or average when loading (load)")
    mesh = shard.data_mesh(devices)
    if config.contact_loss_weight and data.bones.contact is None:
        raise ValueError("contact_loss_weight needs the feet of the skeleton: build the data with style_data")
    feedback = None
    if config.rollout_steps:
        if config.rollout_steps < 0 or config.model.backbone == "mann":
            raise ValueError("rollout_steps must be non-negative, and rollout training feeds back the LPN and PFNN "
                             f"backbones' inputs only (got {config.rollout_steps} steps, {config.model.backbone})")
        if data.next_row is None or data.stats is None:
            raise ValueError("rollout training needs the data's next rows and normalisers: build it with style_data")
        starts = tuple(rollout_starts(r, data.next_row, config.rollout_steps) for r in data.train_rows)
        data = data._replace(train_rows=starts)
        feedback = shard.replicate((jnp.asarray(np.maximum(data.next_row, 0).astype(np.int32)),
                                    *(jnp.asarray(a) for a in data.stats)), mesh)
    if compute_dtype not in COMPUTE_DTYPES:
        raise ValueError(f"compute_dtype must be one of {COMPUTE_DTYPES}, got {compute_dtype!r}")
    shard.check_batch(mesh, config.batch_size)
    arrays = shard.replicate(device_arrays(data), mesh)
    bones = StaticBones(data.bones)
    noise = shard.replicate(jnp.asarray(noise_std(config)), mesh)

    def plan_epoch(epoch):
        batches, styles, clips = epoch_batches(data, config, epoch)
        keys = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(config.seed), epoch), len(batches))
        batches_dev = shard.shard_batches(batches, mesh)
        styles_dev, clips_dev, keys = shard.replicate((jnp.asarray(styles), jnp.asarray(clips), keys), mesh)

        def run_chunk(state, a, b):
            params, opt_state = shard.replicate((state.params, state.opt_state), mesh)
            params, opt_state, out = _train_chunk(
                params, opt_state, arrays, batches_dev[a:b], styles_dev[a:b], clips_dev[a:b], keys[a:b],
                jnp.float32(config.dropout_rate), jnp.float32(config.bone_loss_weight),
                noise, feedback,
                jnp.float32(config.contact_loss_weight) if config.contact_loss_weight else None,
                config=config.model, bones=bones,
                learning_rate=config.learning_rate, compute_dtype=compute_dtype, rollout_steps=config.rollout_steps)
            return state._replace(params=params, opt_state=opt_state), out

        return len(batches), run_chunk

    def end_epoch(epoch, state, out):
        val = evaluate(state.params, config.model, data, "validation")
        return {"train_loss": f"{out[:, 0].mean():.6f}", "train_mse": f"{out[:, 1].mean():.6f}",
                "train_bll": f"{out[:, 2].mean():.6f}", "val_mse": f"{np.nanmean(val['mse']):.6f}",
                "val_bll": f"{np.nanmean(val['bll']):.6f}"}

    state = scan.fit(init_state(jax.random.PRNGKey(config.seed), config), config.epochs, plan_epoch,
                     directory=directory, run_config=_run_config(config, data.styles, compute_dtype),
                     end_epoch=end_epoch, options=scan.FitOptions(log_every=config.log_every, progress=progress,
                                                                   stop_after_epochs=stop_after_epochs,
                                                                   keep=_kept_epochs(config)))
    if jax.process_count() > 1:  # replicated over several processes: this process's copy, for what follows
        state = jax.tree.map(jnp.asarray, shard.gather(state))
    if config.average_epochs > 1:
        ckpt = _checkpointer(directory, config, data.styles, compute_dtype)
        try:
            state = state._replace(params=averaged_params(ckpt, state, config.average_epochs))
        finally:
            ckpt.close()
    return state


def averaged_params(ckpt: Checkpointer, state: ModelState, epochs: int) -> dict:
    """The mean of the parameters saved after each of the last ``epochs`` epochs up to
    ``state.epoch`` (fewer when fewer were saved) in ``ckpt``: checkpoint averaging (Vaswani et al.
    2017, section 6.1, averaged the last checkpoints of their models), not in the 2022 paper.

    Why: at the paper's size the closed loop changes from one epoch to the next as much as
    between two seeds; on the four paper-size runs measured, the mean of the last three epochs'
    weights slid less than the last epoch's (and reached the path's end on more rows on three), but
    showed the styles less (docs/mason2022.md, "Averaged weights"), so it is an option. The mean is taken in float32.
    The parameters come back with ``state.params``' dtypes; ``state`` is the one saved at epoch
    ``state.epoch`` (the callers' newest restored or trained state), so that step is not read again."""
    done = int(state.epoch)
    steps = [s for s in ckpt.all_steps() if s <= done][-max(epochs, 1):]
    if not steps:
        raise FileNotFoundError(f"no checkpoint up to epoch {done} in {ckpt.directory}")
    total = None
    for step in steps:
        saved = state.params if step == done else ckpt.restore(state, step=step).params
        params = jax.tree.map(lambda a: np.asarray(a, np.float32), saved)
        total = params if total is None else jax.tree.map(np.add, total, params)
    return jax.tree.map(lambda a, like: jnp.asarray(a / len(steps), jnp.asarray(like).dtype), total, state.params)


def saved_epochs(directory: str | Path, config: LPNTrainConfig, styles: Sequence[str], *,
                 compute_dtype: str = "float32") -> list[int]:
    """The epochs whose checkpoints a :func:`train` run folder keeps, in order (the last 3, or the
    last ``config.average_epochs`` when more)."""
    ckpt = _checkpointer(directory, config, styles, compute_dtype)
    try:
        return sorted(int(s) for s in ckpt.all_steps())
    finally:
        ckpt.close()


def _kept_epochs(config: LPNTrainConfig) -> int:
    """How many epochs' checkpoints a run folder keeps: 3, or the epochs averaged when more."""
    return max(3, config.average_epochs)


def _checkpointer(directory: str | Path, config: LPNTrainConfig, styles: Sequence[str],
                  compute_dtype: str = "float32") -> Checkpointer:
    """The :class:`Checkpointer` of a :func:`train` run folder (its config, its kept epochs)."""
    return Checkpointer(directory, _run_config(config, styles, compute_dtype), max_to_keep=_kept_epochs(config))


def _run_config(config: LPNTrainConfig, styles: Sequence[str], compute_dtype: str = "float32") -> dict:
    """``config.json`` of a run: the compute dtype only when it is not float32, and the options
    outside the paper's recipe (:data:`EXTRA_OPTIONS`) only when set, so the run folders made
    before those options existed still resume and load."""
    train = {k: v for k, v in dataclasses.asdict(config).items() if not (k in EXTRA_OPTIONS and not v)}
    train["model"] = config.model
    run = {"train": train, "styles": list(styles)}
    if compute_dtype != "float32":
        run["compute_dtype"] = compute_dtype
    return run


def load(directory: str | Path, config: LPNTrainConfig, styles: Sequence[str], *,
         compute_dtype: str = "float32", epoch: int | None = None) -> ModelState:
    """The last checkpoint of a :func:`train` run folder (its parameters the mean of the last
    ``config.average_epochs`` epochs' when that is above 1, :func:`averaged_params`), or the one
    saved after ``epoch`` (one of :func:`saved_epochs`; its own weights, never averaged)."""
    ckpt = _checkpointer(directory, config, styles, compute_dtype)
    try:
        state = ckpt.restore(init_state(jax.random.PRNGKey(config.seed), config), step=epoch)
        if epoch is None and config.average_epochs > 1:
            state = state._replace(params=averaged_params(ckpt, state, config.average_epochs))
        return state
    finally:
        ckpt.close()


# --- testing ------------------------------------------------------------------------------------

@functools.partial(jax.jit, static_argnames=("config", "bones"))
def _eval_chunk(params, x, y, gate, style, *, config, bones):
    pred = style_models.model_apply(params, config, x, gate, style)
    n = len(x)
    mse = jnp.sum(jnp.mean(jnp.square(pred - y), axis=1))
    b = bones_of(bones)
    bll = lpn.bone_length_loss(positions_m(pred, b), positions_m(y, b), b.parents)
    return mse, bll * n


def film_vectors(params: dict, data: StyleData) -> np.ndarray:
    """``(S, 2048)`` each style's FiLM vector: the mean over its training clips (dropout off)."""
    gen = params["style"]["generator"]
    return np.stack([film.clip_films(gen, data.clips[c]).mean(axis=0) for c in data.train_clips])


def evaluate(params: dict, config: StyleModelConfig, data: StyleData, split: str = "test", *,
             styles: Sequence[int] | None = None, vectors: np.ndarray | None = None,
             chunk: int = 2048) -> dict[str, np.ndarray]:
    """``{"mse", "bll"}`` per style (NaN without rows) on ``split``'s rows, dropout off. A FiLM
    model uses ``vectors`` (default :func:`film_vectors`); style ``s`` of the data is style ``s``
    of a one-hot or adapter model."""
    rows_per_style = {"train": data.train_rows, "validation": data.val_rows, "test": data.test_rows}[split]
    styles = range(len(data.styles)) if styles is None else styles
    if config.modulation == "film" and vectors is None:
        vectors = film_vectors(params, data)
    bones = StaticBones(data.bones)
    mse, bll = [], []
    for s in styles:
        rows = rows_per_style[s]
        st = vectors[s] if config.modulation == "film" else style_models.style_runtime(params, config, s)
        total = np.zeros(2)
        for a in range(0, len(rows), chunk):
            r = rows[a:a + chunk]
            total += np.array(_eval_chunk(params, data.x[r], data.y[r], data.gate[r], st, config=config, bones=bones))
        mse.append(total[0] / len(rows) if len(rows) else np.nan)
        bll.append(total[1] / len(rows) if len(rows) else np.nan)
    return {"mse": np.array(mse), "bll": np.array(bll)}


