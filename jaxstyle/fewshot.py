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
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxstyle import pfnn


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """Few-shot defaults of the paper and its code: batch 32, Adam 1e-4, 100 epochs, drop rates
    0.3 / 0.5 / 0.7 (the code's keep probabilities 0.7 / 0.5 / 0.3)."""

    model: pfnn.PFNNConfig = pfnn.PFNNConfig()
    epochs: int = 100
    batch_size: int = 32
    learning_rate: float = 1e-4
    rates: tuple[float, ...] = (0.3, 0.5, 0.7)
    lambda_s: float = 0.01
    seed: int = 0


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


def _train_pair(params, x, y, phase, adapter, batches_TxB, mask_T, rate, key, *, learning_rate, lambda_s):
    """One (style, rate) pair: ``lax.scan`` over steps; masked steps change nothing."""
    optimiser = optax.adam(learning_rate)

    def step(carry, inputs):
        a, opt_state = carry
        idx, real, k = inputs
        value, grads = jax.value_and_grad(
            lambda a: pfnn.loss(params, a, x[idx], y[idx], phase[idx], key=k, dropout_rate=rate,
                                lambda_ag=0.0, lambda_s=lambda_s))(a)
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


def finetune_one(params: dict, x, y, phase, batches_TxB, mask_T, rate: float, key: jax.Array,
                 config: SweepConfig) -> tuple[dict, jax.Array]:
    """Train one fresh adapter for one (style, rate) pair, exactly as inside the sweep."""
    adapter, k_train = _init_pair(config, key)
    run = jax.jit(lambda a, b, m, r, k: _train_pair(params, x, y, phase, a, b, m, r, k,
                                                    learning_rate=config.learning_rate, lambda_s=config.lambda_s))
    return run(adapter, jnp.asarray(batches_TxB), jnp.asarray(mask_T), jnp.float32(rate), k_train)


def finetune_sweep(params: dict, x, y, phase, batches_SxTxB, mask_SxT, config: SweepConfig
                   ) -> tuple[dict, jax.Array]:
    """Adapters ``(S, R, ...)`` and per-step losses ``(S, R, T)`` for every style x rate, in one
    compiled program. ``x, y, phase`` hold all styles' normalised rows (with the base statistics);
    ``batches``/``mask`` come from :func:`sweep_batches`."""
    num_styles, num_rates = batches_SxTxB.shape[0], len(config.rates)
    keys = jnp.stack([jnp.stack([pair_key(config.seed, s, r) for r in range(num_rates)]) for s in range(num_styles)])
    init = jax.vmap(jax.vmap(lambda k: _init_pair(config, k)))(keys)
    rates = jnp.asarray(config.rates, jnp.float32)

    def per_style(adapters_R, k_R, batches, mask):
        return jax.vmap(lambda a, r, k: _train_pair(params, x, y, phase, a, batches, mask, r, k,
                                                    learning_rate=config.learning_rate,
                                                    lambda_s=config.lambda_s))(adapters_R, rates, k_R)

    run = jax.jit(jax.vmap(per_style))
    return run(init[0], init[1], jnp.asarray(batches_SxTxB), jnp.asarray(mask_SxT))
