"""Multi-style base training of the PFNN with one residual adapter per style (2018 section 6).

Each minibatch comes from one style (:func:`jaxstyle.data.batching.balanced_batches`) and trains the
base network together with that style's adapter. Steps run inside ``lax.scan`` in chunks of
``log_every`` steps (one compiled call per chunk, the progress bar moving between chunks); the
optimiser is Adam over the base and all adapters (lr 1e-4, as in the paper). After every epoch
the per-style validation loss is computed, a checkpoint saved (orbax, config beside it) and a
row appended to ``log.csv``; :func:`train` resumes from the last checkpoint of its directory.

Data parallelism: with ``data_parallel=True`` the batch axis is sharded over all devices with
``jax.sharding`` (parameters replicated); the same code runs on one CPU or several GPUs.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxstyle.data.batching import balanced_batches
from jaxstyle.mason2018 import fewshot
from jaxstyle.nn import pfnn
from jaxstyle.train import scan
from jaxstyle.train.checkpoint import Checkpointer


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Base training settings (paper: batch 32, Adam 1e-4, 25 epochs, keep 0.7 = rate 0.3)."""

    model: pfnn.PFNNConfig = pfnn.PFNNConfig()
    epochs: int = 25
    batch_size: int = 32
    learning_rate: float = 1e-4
    dropout_rate: float = 0.3
    lambda_ag: float = 0.01
    lambda_s: float = 0.01
    seed: int = 0
    half_mirrored: bool = False
    log_every: int = 50


class TrainData(NamedTuple):
    """Normalised arrays and row sets: ``x (N, I)``, ``y (N, O)``, ``phase (N,)``; for each style
    its training and validation rows; ``mirror_of (N,)`` for half-mirrored batches (or None)."""

    x: np.ndarray
    y: np.ndarray
    phase: np.ndarray
    train_rows: tuple[np.ndarray, ...]
    val_rows: tuple[np.ndarray, ...]
    styles: tuple[str, ...]
    mirror_of: np.ndarray | None = None


def with_contacts(dataset, base=None):
    """``dataset`` with the optional foot contact outputs of the 2018 layout
    (:class:`jaxstyle.data.pfnn_features.PFNNLayout` ``contacts=True``; not in the paper, whose
    network predicts none): per row the labels of the frame it predicts (:func:`contact_labels`
    of each clip, as loaded for the features), and their statistics appended to the output
    normaliser (per-column mean, one standard deviation for the group, as the other groups);
    with ``base`` (a dataset already with contacts) its statistics are reused. A dataset that
    has them already is returned as it is."""
    from jaxstyle.data.datasets import load_clip
    from jaxstyle.data.pfnn_features import NUM_CONTACTS, PFNNLayout, contact_labels

    num_joints = (dataset.inputs.shape[1] - 48) // 6
    if PFNNLayout.from_output_size(num_joints, dataset.outputs.shape[1]).contacts:
        return dataset
    labels = np.zeros((len(dataset.outputs), NUM_CONTACTS), np.float32)
    for c, spec in enumerate(dataset.specs):
        rows = np.flatnonzero(dataset.clip == c)
        if len(rows):
            labels[rows] = contact_labels(load_clip(spec, fps=60.0))[dataset.frame[rows] + 1]
    if base is not None:
        mean, std = base.output_mean[-NUM_CONTACTS:], base.output_std[-NUM_CONTACTS:]
    else:
        train = labels[dataset.split == 0] if (dataset.split == 0).any() else labels
        mean = train.mean(axis=0)
        std = np.full(NUM_CONTACTS, max(float(np.sqrt(np.mean((train - mean) ** 2))), 1e-3))
    dtype = dataset.output_mean.dtype
    return dataclasses.replace(dataset, outputs=np.concatenate([dataset.outputs, labels], axis=1),
                               output_mean=np.concatenate([dataset.output_mean, mean]).astype(dtype),
                               output_std=np.concatenate([dataset.output_std, std]).astype(dtype))


def data_from_dataset(dataset, base=None) -> TrainData:
    """:class:`TrainData` from a :class:`jaxstyle.data.datasets.Dataset` built by ``build_pfnn_dataset``,
    normalised with its own statistics or those of ``base``."""
    x, y = dataset.normalised(base)
    mirror = dataset.mirror_rows()
    return TrainData(x, y, dataset.phases[:, 0].astype(np.float32),
                     tuple(dataset.rows_of_style(s, "train") for s in dataset.styles),
                     tuple(dataset.rows_of_style(s, "validation") for s in dataset.styles), dataset.styles,
                     mirror if (mirror >= 0).all() else None)


class BaseState(NamedTuple):
    """A base model's training state: the shared ``params``, the base styles' ``adapters``
    (stacked, leading axis = style), the Adam ``opt_state`` of both and the epochs done
    (``epoch``, int32). Checkpointed as the dict of these fields."""

    params: dict
    adapters: dict
    opt_state: Any
    epoch: jax.Array


def init_state(key: jax.Array, config: TrainConfig, num_styles: int) -> BaseState:
    """The :class:`BaseState` before training: random weights (:func:`jaxstyle.nn.pfnn.init_pfnn`,
    one :func:`jaxstyle.nn.pfnn.init_adapter` per style), a fresh Adam state, epoch 0."""
    kp, ka = jax.random.split(key)
    params = pfnn.init_pfnn(kp, config.model)
    adapters = jax.vmap(lambda k: pfnn.init_adapter(k, config.model))(jax.random.split(ka, num_styles))
    opt_state = optax.adam(config.learning_rate).init((params, adapters))
    return BaseState(params, adapters, opt_state, jnp.zeros((), jnp.int32))


def _make_chunk_fn(config: TrainConfig, optimiser):
    """The compiled steps of base training: ``run(trainable, opt_state, x, y, phase, batches, styles,
    key) -> (trainable, opt_state, losses)``, :func:`jaxstyle.train.scan.train_scan` over the
    base and all adapters (each step uses its batch's style's adapter), one key per step split
    from ``key``."""
    def objective(trainable, inputs, key, x, y, phase):
        idx, style = inputs
        p, a = trainable
        adapter = jax.tree.map(lambda v: v[style], a)
        return pfnn.loss(p, adapter, x[idx], y[idx], phase[idx], key=key, dropout_rate=config.dropout_rate,
                         lambda_ag=config.lambda_ag, lambda_s=config.lambda_s)

    @jax.jit
    def run(trainable, opt_state, x, y, phase, batches, styles, key):
        keys = jax.random.split(key, batches.shape[0])
        return scan.train_scan(lambda t, inputs, k: objective(t, inputs, k, x, y, phase), trainable, opt_state,
                               scan.Steps((batches, styles), jnp.ones(batches.shape[0], bool), keys),
                               optimizer=optimiser)

    return run


@jax.jit
def _mse(params, adapter, x, y, phase):
    return jnp.mean((pfnn.pfnn_apply(params, x, phase, adapter=adapter) - y) ** 2)


def validation_losses(params: dict, adapters: dict, data: TrainData, chunk: int = 4096) -> np.ndarray:
    """``(S,)`` MSE (normalised outputs, no dropout, no L1) of each style's validation rows with
    its own adapter; NaN for a style without validation rows."""
    out = []
    for s, rows in enumerate(data.val_rows):
        adapter = jax.tree.map(lambda v, s=s: v[s], adapters)
        total = 0.0
        for a in range(0, len(rows), chunk):
            r = rows[a:a + chunk]
            total += float(_mse(params, adapter, data.x[r], data.y[r], data.phase[r])) * len(r)
        out.append(total / len(rows) if len(rows) else np.nan)
    return np.array(out)


def mean_predictor_losses(data: TrainData) -> np.ndarray:
    """``(S,)`` validation MSE of always predicting the training mean (0 after normalisation);
    NaN for a style without validation rows."""
    return np.array([float(np.mean(data.y[r] ** 2)) if len(r) else np.nan for r in data.val_rows])


def _shard(batches: np.ndarray, data_parallel: bool):
    if not data_parallel:
        return jnp.asarray(batches)
    devices = np.array(jax.devices())
    if batches.shape[1] % len(devices):
        raise ValueError(f"batch size {batches.shape[1]} is not divisible by {len(devices)} devices")
    mesh = Mesh(devices, ("data",))
    return jax.device_put(batches, NamedSharding(mesh, PartitionSpec(None, "data")))


def train(data: TrainData, config: TrainConfig, directory: str | Path | None = None, *,
          data_parallel: bool = False, progress: bool = True, stop_after_epochs: int | None = None) -> BaseState:
    """Train (or resume) a base model; returns the final :class:`BaseState`.

    Args:
      data: normalised arrays and row sets (:func:`data_from_dataset`).
      config: settings; saved as ``config.json`` beside the checkpoints.
      directory: run folder (checkpoints, ``config.json``, ``log.csv``); ``None`` keeps nothing.
      data_parallel: shard each batch over all devices.
      progress: a tqdm bar per epoch with the running loss.
      stop_after_epochs: end this call after that many epochs (to test resuming).
    """
    run_chunk = _make_chunk_fn(config, optax.adam(config.learning_rate))
    x, y, phase = jnp.asarray(data.x), jnp.asarray(data.y), jnp.asarray(data.phase)
    style_of_row = np.zeros(len(data.x), np.int32)
    for s, rows in enumerate(data.train_rows):
        style_of_row[rows] = s

    def plan_epoch(epoch):
        mirror = data.mirror_of if config.half_mirrored else None
        batches = balanced_batches(data.train_rows, config.batch_size, seed=config.seed * 100_003 + epoch,
                                   mirror_of=mirror)
        styles = jnp.asarray(style_of_row[batches[:, 0]])
        batches_dev = _shard(batches, data_parallel)
        key = jax.random.fold_in(jax.random.PRNGKey(config.seed), epoch)

        def chunk(state, a, b):
            (params, adapters), opt_state, losses = run_chunk(
                (state.params, state.adapters), state.opt_state, x, y, phase, batches_dev[a:b],
                styles[a:b], jax.random.fold_in(key, a))
            return state._replace(params=params, adapters=adapters, opt_state=opt_state), losses

        return len(batches), chunk

    def end_epoch(epoch, state, losses):
        return _log_row(float(np.mean(losses)), validation_losses(state.params, state.adapters, data),
                        data.styles)

    return scan.fit(init_state(jax.random.PRNGKey(config.seed), config, len(data.styles)), config.epochs,
                    plan_epoch, directory=directory, run_config={"train": config, "styles": list(data.styles)},
                    end_epoch=end_epoch, options=scan.FitOptions(log_every=config.log_every, progress=progress,
                                                                  stop_after_epochs=stop_after_epochs))


def load_trained(config: TrainConfig, styles, directory: str | Path) -> BaseState:
    """The newest good state that :func:`train` saved in ``directory`` for ``config`` and ``styles``
    (read only: nothing is trained or written). A folder without a checkpoint raises
    ``FileNotFoundError``; one of another config, ``ValueError``."""
    if not (Path(directory) / "config.json").is_file():
        raise FileNotFoundError(f"no checkpoint in {directory}")
    ckpt = Checkpointer(directory, {"train": config, "styles": list(styles)})
    try:
        if ckpt.latest_step() is None:
            raise FileNotFoundError(f"no checkpoint in {directory}")
        return ckpt.restore(init_state(jax.random.PRNGKey(config.seed), config, len(styles)))
    finally:
        ckpt.close()


def _log_row(train_loss: float, val: np.ndarray, styles) -> dict:
    mean = float(np.mean(val[np.isfinite(val)])) if np.isfinite(val).any() else float("nan")
    per_style = {f"val_{s}": f"{v:.6f}" for s, v in zip(styles, val, strict=True)}
    return {"train_loss": f"{train_loss:.6f}", "val_loss_mean": f"{mean:.6f}", "seconds": None, **per_style}


def finetune_adapter(params: dict, adapter: dict, data: TrainData, style: int, config: TrainConfig) -> dict:
    """Train only ``adapter`` on one style's training rows, the base frozen (2018 few-shot).

    ``config.epochs`` passes over the rows in shuffled batches of ``config.batch_size``, all inside
    one jitted ``lax.scan`` (compiled once per shape; the same program as one pair of
    :func:`jaxstyle.mason2018.fewshot.adapter_sweep`); gradients are taken with respect to the adapter alone.
    """
    rows = np.asarray(data.train_rows[style])
    per_epoch = max(len(rows) // config.batch_size, 1)
    rng = np.random.default_rng(config.seed)
    batches = np.concatenate([rng.permutation(rows)[:per_epoch * config.batch_size].reshape(per_epoch, -1)
                              for _ in range(config.epochs)])
    keys = jax.random.split(jax.random.PRNGKey(config.seed), len(batches))
    adapter, _, _ = scan.run_pair(fewshot.AdapterLoss(), adapter, optax.adam(config.learning_rate).init(adapter),
                                  fewshot.frozen_inputs(params, data.x, data.y, data.phase),
                                  scan.Steps(jnp.asarray(batches), jnp.ones(len(batches), bool), keys),
                                  jnp.float32(config.dropout_rate), {"lambda_s": jnp.float32(config.lambda_s)},
                                  optimizer=config.learning_rate)
    return adapter
