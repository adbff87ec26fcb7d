"""Few-shot style learning as one compiled program (Mason et al. 2018, section 7).

The base PFNN is frozen; for every (style, dropout rate) pair a fresh adapter is trained on that
style's few hundred frames. :func:`finetune_sweep` runs ALL pairs in one ``jit`` of a ``vmap``
over styles of a ``vmap`` over rates, each a ``lax.scan`` over steps; base parameters are closed
over (broadcast, never copied per pair) and gradients are taken with respect to the adapter only.

Ragged styles: every style gets ``epochs * max(1, rows // batch)`` real steps; shorter styles are
padded to the longest with masked steps, which leave the adapter and the optimiser state
untouched. :func:`finetune_one` is the same training for one pair, the reference the sweep is
tested against.

Keys and data order depend only on the seed and the style's index (:func:`pair_key`,
:func:`sweep_batches`), so appending a style leaves every other style's adapter unchanged (the
lifelong property). The steps may run in chunks (``chunk_steps``) for a progress bar, with the
same result. Speed options (:class:`SweepConfig`): dropout on the adapter path only, with the
frozen activations computed once; bfloat16 products in the frozen layers. The style axis can be
sharded over all devices (``shard=True``). Model selection, reports and the closed-loop check
are in :mod:`jaxstyle.mason2018.selection`.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxstyle.nn import pfnn
from jaxstyle.train.scan import pair_key, train_scan


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """Few-shot defaults of the paper and its code: batch 32, Adam 1e-4, 100 epochs, drop rates
    0.3 / 0.5 / 0.7 (the code's keep probabilities 0.7 / 0.5 / 0.3).

    ``adapter_dropout_only``: a faster mode that differs from the paper. Dropout then hits only the
    adapter's input, so the frozen network's first layer and the middle layer's main path do not
    depend on the step: they are computed once per frame (:func:`frozen_activations`) and reused
    by every step and every (style, rate) pair; each step runs only the adapter and the last
    layer. The paper also drops units of the frozen layers, which regularises the adapter more.

    ``matmul_dtype="bfloat16"``: the frozen base's layer products run in bfloat16 (weights cast
    once per call, activations per step, float32 accumulation; the adapter, its gradients and
    Adam stay float32). Faster where the hardware has bfloat16 matrix units (GPU tensor cores,
    CPUs with AMX); results differ from float32 by the bfloat16 rounding (about 3 significant
    digits) of the frozen layers' inputs and weights. ``benchmarks/sweep.py`` measures the speed
    and ``experiments/fewshot_sweep.py --matmul-dtype bfloat16`` the effect on the losses.
    """

    model: pfnn.PFNNConfig = pfnn.PFNNConfig()
    epochs: int = 100
    batch_size: int = 32
    learning_rate: float = 1e-4
    rates: tuple[float, ...] = (0.3, 0.5, 0.7)
    lambda_s: float = 0.01
    seed: int = 0
    adapter_dropout_only: bool = False
    matmul_dtype: str = "float32"

    def __post_init__(self):
        if self.matmul_dtype not in ("float32", "bfloat16"):
            raise ValueError(f"matmul_dtype must be 'float32' or 'bfloat16', got {self.matmul_dtype!r}")


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


def _pair_loss(params, adapter, x, y, phase, idx, key, rate, lambda_s, cache):
    """Eq. 3 without the frozen base's L1 term (a constant here): MSE + ``lambda_s`` L1(adapter)."""
    if cache is not None:
        return _cached_loss(params, adapter, cache, y, idx, key, rate, lambda_s)
    pred = pfnn.pfnn_apply(params, x[idx], phase[idx], adapter=adapter, key=key, dropout_rate=rate)
    return jnp.mean((pred - y[idx]) ** 2) + lambda_s * pfnn.l1_penalty(adapter)


def _train_pair(params, x, y, phase, adapter, opt_state, batches_TxB, mask_T, keys_T, rate, *, learning_rate,
                lambda_s, cache=None):
    """Steps of one (style, rate) pair: :func:`train_scan` over ``batches_TxB`` with one PRNG key
    per step. With ``cache`` (:func:`frozen_activations`), the adapter-path-only dropout mode."""
    def loss_fn(a, idx, k):
        return _pair_loss(params, a, x, y, phase, idx, k, rate, lambda_s, cache)

    return train_scan(loss_fn, adapter, opt_state, batches_TxB, mask_T, keys_T, learning_rate=learning_rate)


def _init_pair(config: SweepConfig, key, num_steps: int):
    """A fresh adapter, its Adam state and one dropout key per step, from the pair's key."""
    k_init, k_train = jax.random.split(key)
    adapter = pfnn.init_adapter(k_init, config.model)
    return adapter, optax.adam(config.learning_rate).init(adapter), jax.random.split(k_train, num_steps)


@functools.partial(jax.jit, static_argnames=("learning_rate", "adapter_dropout_only", "matmul_dtype"),
                   donate_argnums=(4, 5))
def _run_grid(params, x, y, phase, adapters_SxR, opt_SxR, keys_SxRxT, rates_R, batches_SxTxB, mask_SxT, lambda_s,
              *, learning_rate, adapter_dropout_only, matmul_dtype="float32"):
    """The compiled sweep (one chunk of steps): vmap over styles of vmap over rates of the
    per-pair scan; the base is closed over, i.e. broadcast to every pair."""
    params = pfnn.cast_weights(params, jnp.dtype(matmul_dtype))
    cache = frozen_activations(params, x, phase) if adapter_dropout_only else None

    def pair(a, o, k, r, batches, mask):
        return _train_pair(params, x, y, phase, a, o, batches, mask, k, r, cache=cache, learning_rate=learning_rate,
                           lambda_s=lambda_s)

    over_rates = jax.vmap(pair, in_axes=(0, 0, 0, 0, None, None))
    over_styles = jax.vmap(over_rates, in_axes=(0, 0, 0, None, 0, 0))
    return over_styles(adapters_SxR, opt_SxR, keys_SxRxT, rates_R, batches_SxTxB, mask_SxT)


@functools.partial(jax.jit, static_argnames=("learning_rate", "adapter_dropout_only", "matmul_dtype"))
def _run_one(params, x, y, phase, adapter, opt_state, batches_TxB, mask_T, keys_T, rate, lambda_s, *, learning_rate,
             adapter_dropout_only, matmul_dtype="float32"):
    params = pfnn.cast_weights(params, jnp.dtype(matmul_dtype))
    cache = frozen_activations(params, x, phase) if adapter_dropout_only else None
    return _train_pair(params, x, y, phase, adapter, opt_state, batches_TxB, mask_T, keys_T, rate, cache=cache,
                       learning_rate=learning_rate, lambda_s=lambda_s)


def finetune_one(params: dict, x, y, phase, batches_TxB, mask_T, rate: float, key: jax.Array,
                 config: SweepConfig) -> tuple[dict, jax.Array]:
    """Train one fresh adapter for one (style, rate) pair, with the sweep's initialisation, keys
    and data order but no vmap: the reference the sweep is tested against. Returns the adapter
    and the per-step losses."""
    adapter, opt_state, keys = _init_pair(config, key, len(batches_TxB))
    adapter, _, losses = _run_one(params, x, y, phase, adapter, opt_state, jnp.asarray(batches_TxB),
                                  jnp.asarray(mask_T), keys, jnp.float32(rate), jnp.float32(config.lambda_s),
                                  learning_rate=config.learning_rate, adapter_dropout_only=config.adapter_dropout_only,
                                  matmul_dtype=config.matmul_dtype)
    return adapter, losses


def finetune_sweep(params: dict, x, y, phase, batches_SxTxB, mask_SxT, config: SweepConfig, *,
                   shard: bool = False, chunk_steps: int | None = None, progress: bool = False
                   ) -> tuple[dict, jax.Array]:
    """Adapters ``(S, R, ...)`` and per-step losses ``(S, R, T)`` for every style x rate, in one
    compiled program. ``x, y, phase`` hold all styles' normalised rows (with the base
    statistics); ``batches``/``mask`` come from :func:`sweep_batches`.

    ``chunk_steps`` runs the steps in chunks of that many (the same program, compiled once, called
    ``ceil(T / chunk_steps)`` times, the last chunk padded with masked steps), so ``progress=True``
    can move a bar between chunks; the result is the same as in one call.

    ``shard=True`` spreads the style axis over all devices (a 1-D ``jax.sharding`` mesh; the base
    and the data are replicated), padding it with fully masked styles to a multiple of the device
    count; the result is the same as on one device.
    """
    batches_SxTxB, mask_SxT = np.asarray(batches_SxTxB), np.asarray(mask_SxT)
    num_styles, num_steps = batches_SxTxB.shape[:2]
    num_rates = len(config.rates)
    padded = num_styles
    if shard:
        padded = -(-num_styles // jax.device_count()) * jax.device_count()
    chunk = num_steps if chunk_steps is None else max(1, min(int(chunk_steps), num_steps))
    total = -(-num_steps // chunk) * chunk
    batches = np.zeros((padded, total) + batches_SxTxB.shape[2:], batches_SxTxB.dtype)
    mask = np.zeros((padded, total), bool)
    batches[:num_styles, :num_steps], mask[:num_styles, :num_steps] = batches_SxTxB, mask_SxT

    keys = jax.vmap(jax.vmap(lambda s, r: pair_key(config.seed, s, r), in_axes=(None, 0)), in_axes=(0, None))(
        jnp.arange(padded), jnp.arange(num_rates))
    adapters, opt_state, step_keys = jax.vmap(jax.vmap(lambda k: _init_pair(config, k, num_steps)))(keys)
    step_keys = jnp.pad(step_keys, ((0, 0), (0, 0), (0, total - num_steps), (0, 0)))
    batches, mask = jnp.asarray(batches), jnp.asarray(mask)
    if shard:
        grid = NamedSharding(Mesh(np.array(jax.devices()), ("grid",)), PartitionSpec("grid"))
        adapters, opt_state, step_keys, batches, mask = jax.device_put(
            (adapters, opt_state, step_keys, batches, mask), grid)
    rates = jnp.asarray(config.rates, jnp.float32)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=num_steps, desc=f"sweep {num_styles} styles x {num_rates} rates", unit="step")
    losses = []
    for a in range(0, total, chunk):
        b = a + chunk
        adapters, opt_state, chunk_losses = _run_grid(
            params, x, y, phase, adapters, opt_state, step_keys[:, :, a:b], rates, batches[:, a:b], mask[:, a:b],
            jnp.float32(config.lambda_s), learning_rate=config.learning_rate,
            adapter_dropout_only=config.adapter_dropout_only, matmul_dtype=config.matmul_dtype)
        losses.append(chunk_losses)
        if bar is not None:
            jax.block_until_ready(chunk_losses)
            bar.update(min(b, num_steps) - a)
            bar.set_postfix(loss=f"{float(jnp.nanmean(chunk_losses)):.4f}")
    if bar is not None:
        bar.close()
    losses = jnp.concatenate(losses, axis=2)[:num_styles, :, :num_steps]
    return jax.tree.map(lambda v: v[:num_styles], adapters), losses
