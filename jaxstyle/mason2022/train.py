"""Training, testing and new-style fine-tuning of the 2022 style models (Mason, Starke & Komura
2022, sections 4.3 and 5.3), for any of the seven models of :mod:`jaxstyle.nn.style_models`.

* :func:`style_data` turns an LPN :class:`jaxstyle.data.datasets.Dataset` into normalised arrays:
  inputs, outputs, the gating input of the backbone, normalised style clips, and per style its
  training / validation / test rows and training clips (clips lying wholly in training rows).
* :func:`batch_loss`: Eq. 5-7, MSE on the normalised outputs plus ``bone_loss_weight`` times the
  bone-length loss on the de-normalised joint positions in metres (the authors' data is in
  metres; 100STYLE files are in centimetres, so positions are divided by the skeleton's units per
  metre). A FiLM model's style comes from one training clip of the batch's style per step.
* :func:`train`: style-balanced training (each minibatch one style, round robin, an epoch one
  pass over the smallest style; :func:`jaxstyle.data.batching.balanced_batches`), Adam 1e-4, batch
  32, dropout 0.3, steps in jitted ``lax.scan`` chunks under a progress bar, per-epoch
  validation, orbax checkpoints with the config beside them, ``log.csv``; resumes.
* not in the paper, options evaluated against the closed loop's freezing (docs/mason2022.md):
  :func:`noisy_inputs` (noise on the normalised inputs) and :func:`rollout_loss` (windows of
  frames fed the network's own outputs through the runtime's feed-back).
* :func:`evaluate`: per-style normalised MSE and bone-length loss, dropout off; a FiLM model uses
  each style's precomputed FiLM vector (the mean over its training clips, as at runtime).
* :func:`finetune_film_sweep`: new styles by fine-tuning only the FiLM generator (LPN and gating
  frozen) for every (new style, dropout rate) pair in one compiled ``vmap`` x ``vmap`` of
  :func:`jaxstyle.train.scan.train_scan`, as the 2018 few-shot sweep.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxstyle.data.batching import balanced_batches
from jaxstyle.data.datasets import consecutive_rows
from jaxstyle.data.lpn_features import LPNLayout, bone_parents, end_effector_columns
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.motion import Motion
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import lpn, pfnn, style_models
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.train import scan, shard
from jaxstyle.train.checkpoint import Checkpointer
from jaxstyle.train.defaults import FILM_DEFAULT_RATES


@dataclasses.dataclass(frozen=True)
class LPNTrainConfig:
    """Paper: batch 32, Adam 1e-4, dropout 0.3 everywhere, MSE + BLL weighted 1:1, 90 epochs.

    Not in the paper (0: its recipe): ``input_noise``, Gaussian noise on the normalised inputs
    (:func:`noisy_inputs`), and ``rollout_steps``, rollout training: each batch row starts a window
    of ``1 + rollout_steps`` consecutive frames in which the network reads its own previous output
    (:func:`rollout_loss`)."""

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


class BonePositions(NamedTuple):
    """Where the joint positions sit in the outputs and how to de-normalise them to metres:
    ``metres = y[:, start:start + 3 J] * scale + offset``; ``parents (J,)`` of the bones."""

    start: int
    scale: np.ndarray
    offset: np.ndarray
    parents: tuple[int, ...]


class StyleData(NamedTuple):
    """Normalised arrays of an LPN dataset for the style models (see :func:`style_data`)."""

    x: np.ndarray
    y: np.ndarray
    gate: np.ndarray
    clips: np.ndarray
    train_rows: tuple[np.ndarray, ...]
    val_rows: tuple[np.ndarray, ...]
    test_rows: tuple[np.ndarray, ...]
    train_clips: tuple[np.ndarray, ...]
    styles: tuple[str, ...]
    bones: BonePositions
    next_row: np.ndarray | None = None
    stats: tuple | None = None


def next_rows(clip_N: np.ndarray, frame_N: np.ndarray) -> np.ndarray:
    """``(N,)``: for each row the row of the next frame of the same clip, -1 where there is none."""
    out = np.full(len(clip_N), -1, np.int64)
    a, b = consecutive_rows(clip_N, frame_N)
    out[a] = b
    return out


def rollout_starts(rows: np.ndarray, next_row: np.ndarray, steps: int) -> np.ndarray:
    """The ``rows`` followed by ``steps`` more frames of their clip that are all among ``rows``
    (the starts of :func:`rollout_loss`'s windows; a window never runs into another split)."""
    rows = np.asarray(rows)
    inside = np.zeros(len(next_row) + 1, bool)
    inside[rows] = True
    cur, ok = rows.copy(), np.ones(len(rows), bool)
    for _ in range(steps):
        cur = next_row[cur]
        ok &= (cur >= 0) & inside[cur]
        cur = np.where(cur >= 0, cur, rows)
    return rows[ok]


def global_phase_rows(dataset) -> np.ndarray:
    """``(N,)`` the global phase of every row of an LPN dataset (the PFNN backbone's gate); an
    error naming the fix when the dataset was built (or cached) without it."""
    phase = np.asarray(getattr(dataset, "global_phase", np.zeros(0)))
    if len(phase) != len(dataset.inputs):
        raise ValueError(f"the dataset has {len(phase)} global phases for {len(dataset.inputs)} rows: build it "
                         "again with jaxstyle.data.datasets.build_lpn_dataset (its cache predates the global phase)")
    return phase


def style_data(dataset, skeleton: Motion, *, backbone: str = "lpn", styles: Sequence[str] | None = None,
               base=None, gate: np.ndarray | None = None) -> StyleData:
    """Arrays for training or testing on ``styles`` (default all) of an LPN dataset.

    ``skeleton``: a clip of the dataset's skeleton (bone parents and units). ``base``: normalise
    with another dataset's statistics (a new style with the base model's, as both papers do).
    The gating input (unless ``gate`` gives one per row) is the 8 local-phase values (``"lpn"``),
    the 12 end-effector velocity inputs (``"mann"``) or the global phase in cycles (``"pfnn"``,
    ``(N, 1)``: the dataset's ``global_phase``, :func:`jaxstyle.global_phase` of each row's frame).
    """
    styles = tuple(dataset.styles if styles is None else styles)
    layout = LPNLayout.of_inputs(dataset.inputs.shape[1])
    if dataset.clips.shape[0] == 0:
        raise ValueError("the dataset has no style clips: build it with jaxstyle.data.datasets.build_lpn_dataset")
    x, y = dataset.normalised(base)
    x_norm, y_norm = (base or dataset).normalisers()
    if gate is None:
        if backbone == "lpn":
            gate = dataset.phases
        elif backbone == "mann":
            gate = x[:, end_effector_columns(skeleton)]
        elif backbone == "pfnn":
            gate = global_phase_rows(dataset)[:, None]
        else:
            raise ValueError(f"unknown backbone {backbone!r}")
    gate = np.asarray(gate, np.float32)
    if len(gate) != len(x):
        raise ValueError(f"gate has {len(gate)} rows, the dataset {len(x)}")
    joints = layout.input_groups
    clips = ((dataset.clips - x_norm.mean[joints["joint_position"].start:])
             / x_norm.std[joints["joint_position"].start:]).astype(np.float32)
    pos = layout.output_groups["joint_position"]
    unit = estimate_units_per_meter(skeleton)
    parents = bone_parents(skeleton)
    if len(parents) != layout.num_bones:
        raise ValueError(f"the skeleton has {len(parents)} LPN bones, the dataset {layout.num_bones}")
    bones = BonePositions(pos.start, (y_norm.std[pos] / unit).astype(np.float32),
                          (y_norm.mean[pos] / unit).astype(np.float32), tuple(int(p) for p in parents))
    train_clips = tuple(dataset.clips_of_style(s, "train") for s in styles)
    for s, c in zip(styles, train_clips, strict=True):
        if len(c) == 0:
            raise ValueError(f"style {s!r} has no style clip inside its training rows")
    stats = tuple(np.asarray(a, np.float32) for a in (x_norm.mean, x_norm.std, y_norm.mean, y_norm.std))
    return StyleData(x, y, gate, clips, tuple(dataset.rows_of_style(s, "train") for s in styles),
                     tuple(dataset.rows_of_style(s, "validation") for s in styles),
                     tuple(dataset.rows_of_style(s, "test") for s in styles), train_clips, styles, bones,
                     next_rows(dataset.clip, dataset.frame), stats)


# --- loss ---------------------------------------------------------------------------------------

def positions_m(y_BxO, bones: BonePositions):
    """``(B, J, 3)`` joint positions in metres from normalised outputs."""
    n = len(bones.parents)
    p = y_BxO[:, bones.start:bones.start + 3 * n] * bones.scale + bones.offset
    return p.reshape(len(y_BxO), n, 3)


def losses(pred_BxO, y_BxO, bones: BonePositions) -> tuple[jax.Array, jax.Array]:
    """``(mse, bll)``: Eq. 5 and Eq. 7 for one batch (bone lengths in metres)."""
    mse = jnp.mean(jnp.square(pred_BxO - y_BxO))
    bll = lpn.bone_length_loss(positions_m(pred_BxO, bones), positions_m(y_BxO, bones), bones.parents)
    return mse, bll


def _style(params, config: StyleModelConfig, clips, style, clip, key, rate):
    if config.modulation == "film":
        return film.generator_apply(params["style"]["generator"], clips[clip][None], key=key, dropout_rate=rate)
    return style_models.style_runtime(params, config, style)


def batch_loss(params, config: StyleModelConfig, arrays, idx_B, style, clip, key, rate, bones: BonePositions,
               bone_loss_weight, input_noise=0.0) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """``MSE + w BLL`` of one minibatch of style ``style`` (rows ``idx_B``), a FiLM model's
    parameters from clip ``clip``; returns the total and ``(mse, bll)``. ``input_noise``: the
    standard deviation of Gaussian noise added to the normalised inputs (:func:`noisy_inputs`; 0:
    the paper's recipe, the same value as without it)."""
    x, y, gate, clips = arrays
    k_style, k_model = jax.random.split(key)
    st = _style(params, config, clips, style, clip, k_style, rate)
    x_B = noisy_inputs(x[idx_B], jax.random.fold_in(key, 1), input_noise)
    pred = style_models.model_apply(params, config, x_B, gate[idx_B], st, key=k_model, dropout_rate=rate)
    mse, bll = losses(pred, y[idx_B], bones)
    return mse + bone_loss_weight * bll, (mse, bll)


def noisy_inputs(x_BxD: jax.Array, key: jax.Array, std) -> jax.Array:
    """``x + std * N(0, 1)`` (normalised inputs; ``std = 0`` returns ``x``). Not in the paper: at
    runtime the network reads its own previous output (pose, velocities, predicted trajectory),
    never exactly a captured row, and trained only on clean rows it learns to copy the input
    pose forward; the closed loop then settles on a still pose (docs/mason2022.md, "The closed loop:
    why it froze"). Noise on the inputs, with the clean next frame as the target, is the
    standard remedy for a model fed its own outputs (a denoising objective). An array, so sweeps
    vmap over it."""
    return x_BxD + std * jax.random.normal(key, x_BxD.shape, x_BxD.dtype)


def rollout_loss(params, config: StyleModelConfig, arrays, feedback, idx_B, style, clip, key, rate,
                 bones: BonePositions, bone_loss_weight, input_noise=0.0, *, steps: int
                 ) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """Rollout training (not in the paper): the mean of :func:`batch_loss`'s ``MSE + w BLL`` over
    windows of ``1 + steps`` consecutive frames starting at rows ``idx_B``
    (:func:`rollout_starts`). The first frame reads the captured input; each later frame reads
    the captured trajectory (the user's control at runtime) with the joint features the network
    predicted one frame before, re-expressed in the frame it predicted
    (:func:`jaxstyle.control.lpn_controller.feed_back`, what the runtime feeds back), and, for the
    LPN, the local phases the runtime would carry; every frame's target is the captured next
    frame. Gradients flow through the fed-back inputs (back-propagation through time).

    Why: the network trained only on captured inputs (the paper's recipe) learns to carry the
    input pose forward, and its closed loop stalls on a still pose (docs/mason2022.md, "The closed loop:
    why it froze"); exposed to its own outputs, it learns to step from them (the remedy
    of scheduled sampling, Bengio et al. 2015, and of the rollout losses of later character
    controllers). ``feedback``: ``(next_row, x_mean, x_std, y_mean, y_std)`` of
    :class:`StyleData`."""
    from jaxstyle.control.lpn_controller import feed_back

    x, y, gate, clips = arrays
    next_row, x_mean, x_std, y_mean, y_std = feedback
    layout = LPNLayout.of_inputs(x.shape[1])
    j0 = layout.input_groups["joint_position"].start
    k_style, k_model = jax.random.split(key)
    st = _style(params, config, clips, style, clip, k_style, rate)
    rows = idx_B
    x_B, g_B = x[rows], gate[rows]
    total = mse_sum = bll_sum = 0.0
    for k in range(steps + 1):
        kk = jax.random.fold_in(k_model, k)
        pred = style_models.model_apply(params, config, noisy_inputs(x_B, jax.random.fold_in(kk, 1), input_noise),
                                        g_B, st, key=kk, dropout_rate=rate)
        mse, bll = losses(pred, y[rows], bones)
        total, mse_sum, bll_sum = total + mse + bone_loss_weight * bll, mse_sum + mse, bll_sum + bll
        if k < steps:
            joints = x_B[:, j0:] * x_std[j0:] + x_mean[j0:]
            _, nxt_joints, phases = jax.vmap(feed_back, in_axes=(0, 0, 0, None))(
                joints, g_B if config.backbone == "lpn" else jnp.zeros((len(rows), 8), x.dtype),
                pred * y_std + y_mean, layout.num_bones)
            rows = next_row[rows]
            x_B = jnp.concatenate([x[rows][:, :j0], (nxt_joints - x_mean[j0:]) / x_std[j0:]], axis=1)
            g_B = phases if config.backbone == "lpn" else gate[rows]
    n = steps + 1
    return total / n, (mse_sum / n, bll_sum / n)


# --- training -----------------------------------------------------------------------------------

def init_state(key: jax.Array, config: LPNTrainConfig) -> dict:
    params = style_models.init_model(key, config.model)
    return {"params": params, "opt_state": optax.adam(config.learning_rate).init(params),
            "epoch": jnp.zeros((), jnp.int32)}


COMPUTE_DTYPES = ("float32", "bfloat16")


def _step_loss(params, config: StyleModelConfig, arrays, inputs, key, rate, weight, bones, compute_dtype: str,
               noise=0.0, feedback=None, rollout_steps: int = 0):
    """One step's loss; ``compute_dtype="bfloat16"`` casts every weight matrix to bfloat16 for the
    products (accumulated in float32: :func:`jaxstyle.nn.pfnn.pf_dense`,
    :func:`jaxstyle.nn.film_generator.generator_apply`), the float32 master weights get float32
    gradients through the cast and Adam runs in float32 (mixed precision, Micikevicius et al. 2018)."""
    idx, style, clip = inputs
    if compute_dtype != "float32":
        params = pfnn.cast_weights(params, jnp.dtype(compute_dtype))
    if rollout_steps:
        return rollout_loss(params, config, arrays, feedback, idx, style, clip, key, rate, _bones(bones), weight,
                            noise, steps=rollout_steps)
    return batch_loss(params, config, arrays, idx, style, clip, key, rate, _bones(bones), weight, noise)


@functools.partial(jax.jit, static_argnames=("config", "bones", "learning_rate", "compute_dtype", "rollout_steps"),
                   donate_argnames=("params", "opt_state"))
def _train_chunk(params, opt_state, arrays, batches_TxB, styles_T, clips_T, keys_T, rate, weight, noise=0.0,
                 feedback=None, *, config: StyleModelConfig, bones: BonePositions, learning_rate: float,
                 compute_dtype: str = "float32", rollout_steps: int = 0):
    """Steps of full training as one ``lax.scan``: per step the gradient of :func:`batch_loss` and
    an ``optax.adam(learning_rate)`` update; returns the new parameters, optimiser state and per
    step ``(loss, mse, bll)``.

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
            p, config, arrays, step_inputs, key, rate, weight, bones, compute_dtype, noise, feedback, rollout_steps)
        updates, opt = optimiser.update(grads, opt, p)
        return (optax.apply_updates(p, updates), opt), jnp.stack([value, mse, bll])

    (params, opt_state), out = jax.lax.scan(step, (params, opt_state), (batches_TxB, styles_T, clips_T, keys_T))
    return params, opt_state, out


class _Static:
    """Wraps :class:`BonePositions` so ``jit`` can take it as a static argument (by identity of
    its values)."""

    def __init__(self, bones: BonePositions):
        self.bones = bones
        self._key = (bones.start, bones.parents, bones.scale.tobytes(), bones.offset.tobytes())

    def __hash__(self):
        return hash(self._key)

    def __eq__(self, other):
        return isinstance(other, _Static) and self._key == other._key


def _bones(b):
    return b.bones if isinstance(b, _Static) else b


def _device_arrays(data: StyleData):
    return tuple(jnp.asarray(a) for a in (data.x, data.y, data.gate, data.clips))


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
          devices: str | int | None = None) -> dict:
    """Train (or resume) a style model; returns ``{"params", "opt_state", "epoch"}``.

    ``directory`` keeps ``config.json``, orbax checkpoints (one per epoch, the last 3 kept) and
    ``log.csv`` (train loss, MSE and BLL, validation MSE and BLL, seconds per epoch); a second call
    with the same directory resumes from the last checkpoint. ``stop_after_epochs`` ends the call
    early (to test resuming).

    ``compute_dtype="bfloat16"``: the layer products in bfloat16, accumulated in float32, float32
    master weights and Adam (an option, not the paper's setting; recorded in ``config.json``).
    ``devices="all"`` (or a count): data-parallel over that many devices
    (:mod:`jaxstyle.train.shard`: each batch's rows split over the devices, the parameters
    replicated); the batch size must divide by the device count. The result equals the one-device
    run up to the order of float sums, so a run may resume on another device count.

    ``config.rollout_steps > 0``: batches are drawn from the training rows that start a whole
    window (:func:`rollout_starts`) and each step is :func:`rollout_loss`."""
    if config.model.num_styles != len(data.styles):
        raise ValueError(f"the model has {config.model.num_styles} styles, the data {len(data.styles)}")
    mesh = shard.data_mesh(devices)
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
    arrays = shard.replicate(_device_arrays(data), mesh)
    bones = _Static(data.bones)

    def plan_epoch(epoch):
        batches, styles, clips = epoch_batches(data, config, epoch)
        keys = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(config.seed), epoch), len(batches))
        batches_dev = shard.shard_batches(batches, mesh)
        styles_dev, clips_dev, keys = shard.replicate((jnp.asarray(styles), jnp.asarray(clips), keys), mesh)

        def run_chunk(state, a, b):
            params, opt_state = shard.replicate((state["params"], state["opt_state"]), mesh)
            params, opt_state, out = _train_chunk(
                params, opt_state, arrays, batches_dev[a:b], styles_dev[a:b], clips_dev[a:b], keys[a:b],
                jnp.float32(config.dropout_rate), jnp.float32(config.bone_loss_weight),
                jnp.float32(config.input_noise), feedback, config=config.model, bones=bones,
                learning_rate=config.learning_rate, compute_dtype=compute_dtype, rollout_steps=config.rollout_steps)
            return {**state, "params": params, "opt_state": opt_state}, out

        return len(batches), run_chunk

    def end_epoch(epoch, state, out):
        val = evaluate(state["params"], config.model, data, "validation")
        return {"train_loss": f"{out[:, 0].mean():.6f}", "train_mse": f"{out[:, 1].mean():.6f}",
                "train_bll": f"{out[:, 2].mean():.6f}", "val_mse": f"{np.nanmean(val['mse']):.6f}",
                "val_bll": f"{np.nanmean(val['bll']):.6f}"}

    state = scan.fit(init_state(jax.random.PRNGKey(config.seed), config), config.epochs, plan_epoch,
                     directory=directory, run_config=_run_config(config, data.styles, compute_dtype),
                     log_every=config.log_every, end_epoch=end_epoch, progress=progress,
                     stop_after_epochs=stop_after_epochs)
    if jax.process_count() > 1:  # replicated over several processes: this process's copy, for what follows
        state = jax.tree.map(jnp.asarray, shard.gather(state))
    return state


def _run_config(config: LPNTrainConfig, styles: Sequence[str], compute_dtype: str = "float32") -> dict:
    """``config.json`` of a run: the compute dtype only when it is not float32, and the options
    outside the paper's recipe (``input_noise``, ``rollout_steps``) only when set, so the run
    folders made before those options existed still resume and load."""
    train = {k: v for k, v in dataclasses.asdict(config).items()
             if not (k in ("input_noise", "rollout_steps") and not v)}
    train["model"] = config.model
    run = {"train": train, "styles": list(styles)}
    if compute_dtype != "float32":
        run["compute_dtype"] = compute_dtype
    return run


def load(directory: str | Path, config: LPNTrainConfig, styles: Sequence[str], *,
         compute_dtype: str = "float32") -> dict:
    """The last checkpoint of a :func:`train` run folder."""
    ckpt = Checkpointer(directory, _run_config(config, styles, compute_dtype))
    try:
        return ckpt.restore(init_state(jax.random.PRNGKey(config.seed), config))
    finally:
        ckpt.close()


# --- testing ------------------------------------------------------------------------------------

@functools.partial(jax.jit, static_argnames=("config", "bones"))
def _eval_chunk(params, x, y, gate, style, *, config, bones):
    pred = style_models.model_apply(params, config, x, gate, style)
    n = len(x)
    mse = jnp.sum(jnp.mean(jnp.square(pred - y), axis=1))
    bll = lpn.bone_length_loss(positions_m(pred, _bones(bones)), positions_m(y, _bones(bones)), _bones(bones).parents)
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
    bones = _Static(data.bones)
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


# --- new styles: fine-tune the FiLM generator ---------------------------------------------------



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
    bones: _Static

    def __call__(self, generator, frozen, inputs, key, rate, hparams):
        idx, clip = inputs
        params = {**frozen["params"], "style": {"generator": generator}}
        return batch_loss(params, self.config, frozen["arrays"], idx, 0, clip, key, rate, _bones(self.bones),
                          hparams["weight"])[0]


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
    frozen = {"params": {k: v for k, v in params.items() if k != "style"}, "arrays": _device_arrays(data)}
    gens = jax.tree.map(lambda v: jnp.broadcast_to(v, (num_styles, num_rates) + v.shape),
                        params["style"]["generator"])
    gens, per_step = scan.grid_sweep(
        GeneratorLoss(config, _Static(data.bones)), gens, frozen, (batches, clips), mask, keys,
        jnp.asarray(finetune.rates, jnp.float32), learning_rate=finetune.learning_rate,
        hparams={"weight": jnp.float32(finetune.bone_loss_weight)}, chunk_steps=chunk_steps, shard=shard,
        progress=progress, desc=f"FiLM fine-tuning {num_styles} styles x {num_rates} rates")
    return FilmSweep(gens, np.asarray(per_step))


def with_generator(params: dict, generators: dict, style: int, rate: int) -> dict:
    """``params`` with the fine-tuned generator of one (style, rate) pair of the sweep."""
    return {**params, "style": {"generator": jax.tree.map(lambda v: v[style, rate], generators)}}
