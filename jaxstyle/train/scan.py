"""The training loop both papers share: Adam steps as one ``lax.scan`` with a mask for padded steps,
per-style batch plans for (style, rate) sweeps, and the PRNG key of each grid cell.

The 2018 few-shot adapter sweep and the 2022 FiLM generator sweep are two uses of these functions:
each vmaps :func:`train_scan` over styles and rates, with its own loss and frozen network closed over.
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax


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


def train_scan(loss_fn, trainable, opt_state, inputs_T, mask_T, keys_T, *, learning_rate: float):
    """Adam steps as one ``lax.scan``: step ``t`` takes the gradient of
    ``loss_fn(trainable, inputs_T[t], keys_T[t])`` with respect to ``trainable`` alone (whatever
    else the loss uses is closed over, i.e. frozen); masked steps (``mask_T[t]`` false) change
    nothing. Returns the trained tree, the optimiser state and per-step losses (NaN when masked).
    The 2018 adapter sweep (:mod:`jaxstyle.mason2018.fewshot`) and the 2022 FiLM generator sweep
    (:mod:`jaxstyle.mason2022.train`) vmap this function over their (style, rate) grids."""
    optimiser = optax.adam(learning_rate)

    def step(carry, inputs):
        a, opt = carry
        step_inputs, real, k = inputs
        value, grads = jax.value_and_grad(loss_fn)(a, step_inputs, k)
        updates, new_opt = optimiser.update(grads, opt)
        new_a = optax.apply_updates(a, updates)
        keep = lambda new, old: jnp.where(real, new, old)  # noqa: E731
        return (jax.tree.map(keep, new_a, a), jax.tree.map(keep, new_opt, opt)), jnp.where(real, value, jnp.nan)

    (trainable, opt_state), losses = jax.lax.scan(step, (trainable, opt_state), (inputs_T, mask_T, keys_T))
    return trainable, opt_state, losses


def pair_key(seed: int, style: int, rate_index: int) -> jax.Array:
    """The PRNG key of one (style, rate) pair: its adapter's initial values and dropout masks."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(seed), style), rate_index)
