"""Few-shot style learning as one compiled program (Mason et al. 2018, section 7).

The base PFNN is frozen; for every (style, dropout rate) pair a fresh adapter is trained on that
style's few hundred frames. :func:`adapter_sweep` runs ALL pairs in one ``jit`` of a ``vmap``
over styles of a ``vmap`` over rates, each a ``lax.scan`` over steps; base parameters are
broadcast (``in_axes=None``, never copied per pair) and gradients are taken with respect to the
adapter only. The program is the shared grid driver :func:`jaxstyle.train.scan.grid_sweep` with
this paper's loss, :class:`AdapterLoss` (the 2022 FiLM generator sweep is the same driver).

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
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxstyle.nn import pfnn
from jaxstyle.train import scan
from jaxstyle.train.defaults import DEFAULT_RATES
from jaxstyle.train.scan import pair_key


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """Few-shot defaults of the paper and its code: batch 32, Adam 1e-4, 100 epochs, drop rates
    0.3 / 0.5 / 0.7 (the code's keep probabilities 0.7 / 0.5 / 0.3).

    ``adapter_dropout_only``: a faster mode that differs from the paper. Dropout then hits only the
    adapter's input, so the frozen network's first layer and the middle layer's main path do not
    depend on the step: they are computed once per frame (:func:`frozen_activations`) and reused
    by every step and every (style, rate) pair; each step runs only the adapter and the last
    layer. The paper also drops units of the frozen layers, which regularises the adapter more.

    ``matmul_dtype="bfloat16"``: the frozen base's layer products, forward and input gradient,
    run in bfloat16 (weights cast once per call, activations and cotangents per step, float32
    accumulation: :func:`jaxstyle.nn.pfnn.frozen_product`; the adapter, its gradients and Adam
    stay float32). Faster where the hardware multiplies bfloat16 faster (GPU tensor cores, CPUs
    with AMX or avx512_bf16); results differ from float32 by the bfloat16 rounding (about 3
    significant digits) of the frozen layers' inputs, cotangents and weights.
    ``benchmarks/sweep.py`` measures the speed and ``experiments/fewshot_sweep.py --matmul-dtype
    bfloat16`` the effect on the losses.
    """

    model: pfnn.PFNNConfig = pfnn.PFNNConfig()
    epochs: int = 100
    batch_size: int = 32
    learning_rate: float = 1e-4
    rates: tuple[float, ...] = DEFAULT_RATES
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
    w = pfnn.catmull_rom_weights(phase)
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


@dataclasses.dataclass(frozen=True)
class AdapterLoss:
    """The loss of one (style, rate) cell for :func:`jaxstyle.train.scan.grid_sweep` and
    :func:`jaxstyle.train.scan.run_pair`: the trainable tree is the adapter, ``frozen`` is
    :func:`frozen_inputs`, the step input a batch of row indices, ``hparams`` ``{"lambda_s"}``.
    :meth:`prepare` lays the base's weights out frozen in ``matmul_dtype``
    (:func:`jaxstyle.nn.pfnn.freeze_weights`) and, with
    ``adapter_dropout_only``, caches :func:`frozen_activations` once per compiled call."""

    adapter_dropout_only: bool = False
    matmul_dtype: str = "float32"

    def prepare(self, frozen: dict) -> dict:
        params = pfnn.freeze_weights(frozen["params"], jnp.dtype(self.matmul_dtype))
        cache = frozen_activations(params, frozen["x"], frozen["phase"]) if self.adapter_dropout_only else None
        return {**frozen, "params": params, "cache": cache}

    def __call__(self, adapter, frozen, idx, key, rate, hparams):
        return _pair_loss(frozen["params"], adapter, frozen["x"], frozen["y"], frozen["phase"], idx, key, rate,
                          hparams["lambda_s"], frozen.get("cache"))


def frozen_inputs(params: dict, x, y, phase) -> dict:
    """The frozen tree of :class:`AdapterLoss`: the base network and all styles' rows, zero-padded
    to :func:`jaxstyle.train.scan.row_bucket` rows (batches index the real rows only), so clips of
    other lengths reuse the compiled sweep."""
    x, y, phase = scan.pad_rows(x, y, phase)
    return {"params": params, "x": x, "y": y, "phase": phase}


def _loss_of(config: SweepConfig) -> AdapterLoss:
    return AdapterLoss(config.adapter_dropout_only, config.matmul_dtype)


def _init_pair(config: SweepConfig, key, num_steps: int):
    """A fresh adapter and one dropout key per step, from the pair's key."""
    k_init, k_train = jax.random.split(key)
    return pfnn.init_adapter(k_init, config.model), jax.random.split(k_train, num_steps)


def finetune_one(params: dict, x, y, phase, batches_TxB, mask_T, rate: float, key: jax.Array,
                 config: SweepConfig) -> tuple[dict, jax.Array]:
    """Train one fresh adapter for one (style, rate) pair, with the sweep's initialisation, keys
    and data order but no vmap: the reference the sweep is tested against. Returns the adapter
    and the per-step losses."""
    adapter, keys = _init_pair(config, key, len(batches_TxB))
    adapter, _, losses = scan.run_pair(
        _loss_of(config), adapter, optax.adam(config.learning_rate).init(adapter), frozen_inputs(params, x, y, phase),
        scan.Steps(jnp.asarray(batches_TxB), jnp.asarray(mask_T), keys), jnp.float32(rate),
        {"lambda_s": jnp.float32(config.lambda_s)}, optimizer=config.learning_rate)
    return adapter, losses


class AdapterSweep(NamedTuple):
    """The fine-tuned residual ``adapters`` (leading axes ``(S, R)``: few-shot set, dropout rate)
    and the per-step training ``losses`` ``(S, R, T)`` of :func:`adapter_sweep`."""

    adapters: dict
    losses: jax.Array


def adapter_sweep(params: dict, x, y, phase, batches_SxTxB, mask_SxT, config: SweepConfig, *,
                  run: scan.GridRun | None = None) -> AdapterSweep:
    """Adapters ``(S, R, ...)`` and per-step losses ``(S, R, T)`` for every style x rate, in one
    compiled program. ``x, y, phase`` hold all styles' normalised rows (with the base
    statistics); ``batches``/``mask`` come from :func:`sweep_batches`.

    ``run`` (:class:`jaxstyle.train.scan.GridRun`, default one call, no bar; none of it changes the result):
    ``chunk_steps`` runs the steps in chunks of that many (the same program, compiled once, called
    ``ceil(T / chunk_steps)`` times, the last chunk padded with masked steps), so ``progress=True``
    can move a bar between chunks; ``shard=True`` spreads the style axis over all devices (a 1-D
    ``jax.sharding`` mesh; the base and the data are replicated), padding it with fully masked
    styles to a multiple of the device count. Its ``desc`` is this sweep's own.
    """
    batches_SxTxB = np.asarray(batches_SxTxB)
    num_styles, num_steps = batches_SxTxB.shape[:2]
    num_rates = len(config.rates)
    keys = jax.vmap(jax.vmap(lambda s, r: pair_key(config.seed, s, r), in_axes=(None, 0)), in_axes=(0, None))(
        jnp.arange(num_styles), jnp.arange(num_rates))
    adapters, step_keys = jax.vmap(jax.vmap(lambda k: _init_pair(config, k, num_steps)))(keys)
    return AdapterSweep(*scan.grid_sweep(
        _loss_of(config), adapters, frozen_inputs(params, x, y, phase), scan.Steps(batches_SxTxB, mask_SxT, step_keys),
        jnp.asarray(config.rates, jnp.float32), optimizer=config.learning_rate,
        hparams={"lambda_s": jnp.float32(config.lambda_s)},
        run=dataclasses.replace(run or scan.GridRun(), desc=f"sweep {num_styles} styles x {num_rates} rates")))
