"""A toy training run for tests of :func:`jaxstyle.train.scan.fit`: least squares on ``w``, 3 epochs of
4 steps of batch 3."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxstyle.train import scan


class ToyState(NamedTuple):
    w: jax.Array
    opt_state: Any
    epoch: jax.Array


def toy_fit(directory, run_config, *, poison_epoch: int | None = None, end_epoch=None, **options) -> ToyState:
    """Run (or resume) the toy run in ``directory``; from ``poison_epoch`` on, the weights turn
    NaN while the reported loss stays finite. ``end_epoch`` goes to :func:`scan.fit`, ``options``
    to its :class:`scan.FitOptions` (3 steps per chunk, no progress bar unless given)."""
    X = jnp.asarray(np.random.default_rng(0).normal(size=(12, 3)).astype(np.float32))
    Y = X @ jnp.array([1.0, -2.0, 0.5])
    opt = optax.adam(0.1)
    loss = lambda w, idx, k: jnp.mean((X[idx] @ w - Y[idx]) ** 2)  # noqa: E731
    run = jax.jit(lambda w, o, idx, keys: scan.train_scan(loss, w, o, scan.Steps(idx, jnp.ones(len(idx), bool), keys),
                                                          optimizer=opt))

    def plan_epoch(epoch):
        idx = np.random.default_rng(epoch).permutation(12).reshape(4, 3)
        keys = jax.random.split(jax.random.PRNGKey(epoch), 4)

        def chunk(state, a, b):
            w, o, losses = run(state.w, state.opt_state, jnp.asarray(idx[a:b]), keys[a:b])
            if poison_epoch is not None and epoch >= poison_epoch:
                w, losses = w * jnp.nan, jnp.nan_to_num(losses)
            return state._replace(w=w, opt_state=o), losses

        return 4, chunk

    w = jnp.zeros(3)
    state = ToyState(w, opt.init(w), jnp.zeros((), jnp.int32))
    options = {"log_every": 3, "progress": False, **options}
    return scan.fit(state, 3, plan_epoch, directory=directory, run_config=run_config, end_epoch=end_epoch,
                    options=scan.FitOptions(**options))
