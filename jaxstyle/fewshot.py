"""Few-shot style learning as one compiled program (Mason et al. 2018, section 7).

The base PFNN is frozen; for every (style, dropout rate) pair a fresh adapter is trained on that
style's few hundred frames. :func:`finetune_sweep` runs ALL pairs in one ``jit`` of a ``vmap``
over styles of a ``vmap`` over rates, each a ``lax.scan`` over steps; base parameters are closed
over (broadcast, never copied per pair) and gradients are taken with respect to the adapter only.

Ragged styles: every style gets ``epochs * max(1, rows // batch)`` real steps; shorter styles are
padded to the longest with masked steps, which leave the adapter and the optimiser state
untouched. :func:`finetune_one` is the same training for one pair, the reference the sweep is
tested against.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxstyle import pfnn


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """Few-shot defaults of the paper and its code: batch 32, Adam 1e-4, 100 epochs, drop rates
    0.3 / 0.5 / 0.7 (the code's keep probabilities 0.7 / 0.5 / 0.3).

    ``adapter_dropout_only``: a faster mode that differs from the paper. Dropout then hits only the
    adapter's input, so the frozen network's first layer and the middle layer's main path do not
    depend on the step: they are computed once per frame (:func:`frozen_activations`) and reused
    by every step and every (style, rate) pair; each step runs only the adapter and the last
    layer. The paper also drops units of the frozen layers, which regularises the adapter more.
    """

    model: pfnn.PFNNConfig = pfnn.PFNNConfig()
    epochs: int = 100
    batch_size: int = 32
    learning_rate: float = 1e-4
    rates: tuple[float, ...] = (0.3, 0.5, 0.7)
    lambda_s: float = 0.01
    seed: int = 0
    adapter_dropout_only: bool = False


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


def frozen_activations(params: dict, x, phase) -> dict:
    """Per-frame quantities of the frozen base that no adapter-path dropout mask changes: the
    spline weights ``w (N, 4)``, ``h1 (N, H)`` and the middle layer's main-path pre-activation
    ``pre (N, H)``."""
    w = pfnn.spline_weights(phase)
    h1 = jax.nn.elu(pfnn.pf_dense(params["l0"], x, w))
    return {"w": w, "h1": h1, "pre": pfnn.pf_dense(params["l1"], h1, w)}


def _cached_loss(params, adapter, cache, y, idx, key, rate, lambda_s):
    """The adapter-path-only dropout forward from cached activations (see :class:`SweepConfig`)."""
    w, h1 = cache["w"][idx], cache["h1"][idx]
    pre = cache["pre"][idx] + pfnn.apply_adapter(adapter, pfnn.dropout(key, h1, rate), w)
    pred = pfnn.pf_dense(params["l2"], jax.nn.elu(pre), w)
    return jnp.mean((pred - y[idx]) ** 2) + lambda_s * pfnn.l1_penalty(adapter)


def _train_pair(params, x, y, phase, adapter, batches_TxB, mask_T, rate, key, *, learning_rate, lambda_s,
                cache=None):
    """One (style, rate) pair: ``lax.scan`` over steps; masked steps change nothing. With
    ``cache`` (:func:`frozen_activations`), the adapter-path-only dropout mode."""
    optimiser = optax.adam(learning_rate)

    def objective(a, idx, k):
        if cache is not None:
            return _cached_loss(params, a, cache, y, idx, k, rate, lambda_s)
        return pfnn.loss(params, a, x[idx], y[idx], phase[idx], key=k, dropout_rate=rate,
                         lambda_ag=0.0, lambda_s=lambda_s)

    def step(carry, inputs):
        a, opt_state = carry
        idx, real, k = inputs
        value, grads = jax.value_and_grad(objective)(a, idx, k)
        updates, new_opt = optimiser.update(grads, opt_state)
        new_a = optax.apply_updates(a, updates)
        keep = lambda new, old: jnp.where(real, new, old)  # noqa: E731
        return (jax.tree.map(keep, new_a, a), jax.tree.map(keep, new_opt, opt_state)), jnp.where(real, value, jnp.nan)

    keys = jax.random.split(key, batches_TxB.shape[0])
    (adapter, _), losses = jax.lax.scan(step, (adapter, optimiser.init(adapter)), (batches_TxB, mask_T, keys))
    return adapter, losses


def pair_key(seed: int, style: int, rate_index: int) -> jax.Array:
    """The PRNG key of one (style, rate) pair: its adapter's initial values and dropout masks."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(seed), style), rate_index)


def _init_pair(config: SweepConfig, key):
    k_init, k_train = jax.random.split(key)
    return pfnn.init_adapter(k_init, config.model), k_train


@functools.partial(jax.jit, static_argnames=("learning_rate", "adapter_dropout_only"))
def _run_grid(params, x, y, phase, adapters_SxR, keys_SxR, rates_R, batches_SxTxB, mask_SxT, lambda_s, *,
              learning_rate, adapter_dropout_only):
    """The compiled sweep: vmap over styles of vmap over rates of the per-pair scan."""
    cache = frozen_activations(params, x, phase) if adapter_dropout_only else None

    def pair(a, r, k, batches, mask):
        return _train_pair(params, x, y, phase, a, batches, mask, r, k, cache=cache, learning_rate=learning_rate,
                           lambda_s=lambda_s)

    over_rates = jax.vmap(pair, in_axes=(0, 0, 0, None, None))
    return jax.vmap(over_rates, in_axes=(0, None, 0, 0, 0))(adapters_SxR, rates_R, keys_SxR, batches_SxTxB, mask_SxT)


@functools.partial(jax.jit, static_argnames=("learning_rate", "adapter_dropout_only"))
def _run_one(params, x, y, phase, adapter, batches_TxB, mask_T, rate, key, lambda_s, *, learning_rate,
             adapter_dropout_only):
    cache = frozen_activations(params, x, phase) if adapter_dropout_only else None
    return _train_pair(params, x, y, phase, adapter, batches_TxB, mask_T, rate, key, cache=cache,
                       learning_rate=learning_rate, lambda_s=lambda_s)


def finetune_one(params: dict, x, y, phase, batches_TxB, mask_T, rate: float, key: jax.Array,
                 config: SweepConfig) -> tuple[dict, jax.Array]:
    """Train one fresh adapter for one (style, rate) pair, with the sweep's initialisation, keys
    and data order but no vmap: the reference the sweep is tested against."""
    adapter, k_train = _init_pair(config, key)
    return _run_one(params, x, y, phase, adapter, jnp.asarray(batches_TxB), jnp.asarray(mask_T), jnp.float32(rate),
                    k_train, jnp.float32(config.lambda_s), learning_rate=config.learning_rate,
                    adapter_dropout_only=config.adapter_dropout_only)


def finetune_sweep(params: dict, x, y, phase, batches_SxTxB, mask_SxT, config: SweepConfig, *,
                   shard: bool = False) -> tuple[dict, jax.Array]:
    """Adapters ``(S, R, ...)`` and per-step losses ``(S, R, T)`` for every style x rate, in one
    compiled program (compiled once per shape and config). ``x, y, phase`` hold all styles'
    normalised rows (with the base statistics); ``batches``/``mask`` come from :func:`sweep_batches`.

    ``shard=True`` spreads the style axis over all devices (a 1-D ``jax.sharding`` mesh; the base
    and the data are replicated), padding it with fully masked styles to a multiple of the device
    count; the result is the same as on one device.
    """
    batches_SxTxB, mask_SxT = np.asarray(batches_SxTxB), np.asarray(mask_SxT)
    num_styles, num_rates = batches_SxTxB.shape[0], len(config.rates)
    padded = num_styles
    if shard:
        padded = -(-num_styles // jax.device_count()) * jax.device_count()
        extra = padded - num_styles
        pad = np.zeros((extra,) + batches_SxTxB.shape[1:], batches_SxTxB.dtype)
        batches_SxTxB = np.concatenate([batches_SxTxB, pad])
        mask_SxT = np.concatenate([mask_SxT, np.zeros((extra,) + mask_SxT.shape[1:], bool)])
    keys = jnp.stack([jnp.stack([pair_key(config.seed, s, r) for r in range(num_rates)]) for s in range(padded)])
    adapters, train_keys = jax.vmap(jax.vmap(lambda k: _init_pair(config, k)))(keys)
    batches, mask = jnp.asarray(batches_SxTxB), jnp.asarray(mask_SxT)
    if shard:
        grid = NamedSharding(Mesh(np.array(jax.devices()), ("grid",)), PartitionSpec("grid"))
        adapters, train_keys, batches, mask = jax.device_put((adapters, train_keys, batches, mask), grid)
    adapters, losses = _run_grid(params, x, y, phase, adapters, train_keys, jnp.asarray(config.rates, jnp.float32),
                                 batches, mask, jnp.float32(config.lambda_s), learning_rate=config.learning_rate,
                                 adapter_dropout_only=config.adapter_dropout_only)
    return jax.tree.map(lambda v: v[:num_styles], adapters), losses[:num_styles]
