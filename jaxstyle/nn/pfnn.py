"""Phase-functioned neural network with residual style adapters (Mason et al. 2018, sections 3, 6, 7).

Pure functions over parameter pytrees (dicts of arrays). The paper's equations are separate
functions (docs/equations.md maps every equation to its function):

* :func:`catmull_rom_weights`: the cubic Catmull-Rom phase
  function (Mason et al. 2018, Eq. 1a-1c) as 4 weights, one per control point, for any batch of
  phases. Every phase-functioned quantity is linear in its control points, so layers are evaluated
  for the 4 control points and their OUTPUTS blended with these weights (:func:`pf_dense`); no
  per-sample weight matrix is ever built.
* :func:`full_residual`, :func:`diag_residual`, :func:`cp_residual`: the three residual adapters
  ``R_s(h)`` of the middle layer (Mason et al. 2018, Eq. 4's ``W_res h + b_res``; the CP one is
  Eq. 6's ``A D B^T`` factorisation) at one phase; :func:`apply_adapter` evaluates an adapter's
  phase-functioned parameters and calls them.
* :func:`init_pfnn` / :func:`init_adapter`: parameters (uniform ``+-sqrt(6 / (fan_in * fan_out))``
  weights, the product as in the authors' code, zero biases).
* :func:`pfnn_apply`: Mason et al. 2018, Eq. 4, ``234 -> 512 -> 512 -> 400`` with ELU, a residual
  adapter on the middle layer with its own dropout mask, or no adapter (the style-agnostic
  "average motion").
* :func:`dropout`: dropout whose rate is an array, so sweeps can ``vmap`` over rates.
* :func:`l1_penalty` and :func:`loss`: MSE plus the L1 terms (``lambda_ag``, ``lambda_s``) of
  Mason et al. 2018, Eq. 3.
* :func:`discretise` / :func:`pfnn_apply_table`: the runtime's 50 precomputed phase bins
  (section 7.1).

Shapes: ``x_BxI`` inputs, ``phase_B`` in cycles ``[0, 1)``, outputs ``y_BxO``. A phase-functioned
dense layer holds ``W (4, I, O)`` and ``b (4, O)``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

ADAPTER_KINDS = ("full", "diagonal", "cp")
NUM_CONTROL_POINTS = 4


@dataclasses.dataclass(frozen=True)
class PFNNConfig:
    """Sizes of the network (paper: 234 -> 512 -> 512 -> 400) and of its adapters."""

    input_size: int = 234
    hidden_size: int = 512
    output_size: int = 400
    adapter: str = "cp"
    rank: int = 30

    def __post_init__(self):
        if self.adapter not in ADAPTER_KINDS:
            raise ValueError(f"adapter must be one of {ADAPTER_KINDS}, got {self.adapter!r}")
        if self.rank < 1:
            raise ValueError(f"rank must be positive, got {self.rank}")


# --- the phase function (Mason et al. 2018, Eq. 1a-1c) -----------------------------------------

def catmull_rom_weights(phase_B: jax.Array) -> jax.Array:
    """``(B, 4)`` weights of the 4 control points for phases in cycles: Mason et al. 2018, Eq. 1a-1c.

    The phase function ``W(p) = sum_j weights[:, j] alpha_j`` (:func:`blend`). The paper's phase is
    in radians; jaxstyle's ``phase_B`` is in cycles, so Eq. 1b's ``d = 4 p / 2 pi mod 1`` is
    ``mu = 4 p mod 1`` and Eq. 1c's ``k_n = floor(4 p) + n - 1 mod 4``, ``n = 0..3``. With
    ``t = 4 p``, ``k = floor(t)`` and ``mu = t - k``, the spline passes through control point
    ``k`` at ``mu = 0`` and uses points ``k-1, k, k+1, k+2`` (mod 4) with the Catmull-Rom cubic
    (Eq. 1a) ``(-y0/2 + 3y1/2 - 3y2/2 + y3/2) mu^3 + (y0 - 5y1/2 + 2y2 - y3/2) mu^2 + (-y0/2 + y2/2) mu
    + y1``. The 4 weights sum to 1 for every phase.
    """
    t = 4.0 * jnp.mod(jnp.asarray(phase_B, dtype=jnp.float32), 1.0)
    k = jnp.floor(t)
    mu = t - k
    mu2, mu3 = mu * mu, mu * mu * mu
    coef = jnp.stack([-0.5 * mu3 + mu2 - 0.5 * mu,          # y0 = P[k-1]
                      1.5 * mu3 - 2.5 * mu2 + 1.0,          # y1 = P[k]
                      -1.5 * mu3 + 2.0 * mu2 + 0.5 * mu,    # y2 = P[k+1]
                      0.5 * mu3 - 0.5 * mu2], axis=-1)      # y3 = P[k+2]
    idx = (k.astype(jnp.int32)[..., None] + jnp.arange(-1, 3)) % NUM_CONTROL_POINTS
    return jnp.sum(jax.nn.one_hot(idx, NUM_CONTROL_POINTS, dtype=coef.dtype) * coef[..., None], axis=-2)



def blend(values_4x: jax.Array, weights_Bx4: jax.Array) -> jax.Array:
    """``(B, ...)`` phase-functioned values from their ``(4, ...)`` control points and the
    :func:`catmull_rom_weights` of the phases (Mason et al. 2018, Eq. 1a for vectors and biases)."""
    return jnp.tensordot(weights_Bx4, values_4x, axes=1)


SMALL_BATCH = 8
"""Up to this batch size :func:`pf_dense` multiplies per control point when the weights are traced
(the runtime's one character per call); otherwise one product covers all control points."""


def pf_dense(layer: dict, h_BxI: jax.Array, weights_Bx4: jax.Array) -> jax.Array:
    """Phase-functioned dense layer ``W(p) h + b(p)`` with ``W(p), b(p)`` the phase function of
    Mason et al. 2018, Eq. 1a (or the expert blend ``W = sum_k alpha_k W_k`` of Mason, Starke &
    Komura 2022, section 4.1): ``sum_k weights[:, k] (h W_k + b_k)``, the ``K`` control-point
    layers' outputs blended, never a weight matrix per sample.

    The product runs in the dtype of ``W`` (e.g. a frozen base cast to bfloat16 by
    :func:`cast_weights`), accumulating in float32; the result is float32. A layer whose ``W`` is
    2-D was made frozen by :func:`freeze_weights`: its product (forward and input gradient) is
    :func:`frozen_product`."""
    w = layer["W"]
    if w.ndim == 2:  # a frozen layer laid out by freeze_weights: (I, K*O)
        out_BxKO = frozen_product(h_BxI, w)
        out_BxKxO = out_BxKO.reshape(h_BxI.shape[0], weights_Bx4.shape[-1], -1) + layer["b"]
        return jnp.einsum("bk,bko->bo", weights_Bx4, out_BxKxO)
    h = h_BxI.astype(w.dtype)
    if h.shape[0] <= SMALL_BATCH and isinstance(w, jax.core.Tracer):
        # K products h @ W_k, batched over the control points: W is read in its stored (K, I, O)
        # layout. The single product below makes XLA on CPU copy W into another layout on every
        # call when W is traced (a jit argument): 4-8x slower at batch 1. A W that is a
        # compile-time constant (closed over, as in a runtime) is laid out once when compiling, and
        # there the single product is the faster one.
        hk = jnp.broadcast_to(h, (w.shape[0],) + h.shape)
        out_KxBxO = jax.lax.dot_general(hk, w, (((2,), (1,)), ((0,), (0,))), preferred_element_type=jnp.float32)
        return jnp.einsum("bk,kbo->bo", weights_Bx4, out_KxBxO + layer["b"][:, None])
    out_Bx4xO = jnp.einsum("bi,kio->bko", h, w, preferred_element_type=jnp.float32) + layer["b"]
    return jnp.einsum("bk,bko->bo", weights_Bx4, out_Bx4xO)


@jax.custom_vjp
def frozen_product(h_BxI: jax.Array, W_IxN: jax.Array) -> jax.Array:
    """``h @ W`` for a frozen ``W`` (no gradient flows to it), operands in ``W``'s dtype, accumulated
    and returned in float32. Its input gradient ``g @ W^T`` also runs in ``W``'s dtype (the float32
    cotangent rounded to it): automatic differentiation of a bfloat16 product with a float32 result
    would multiply the float32 cotangent by ``W`` converted to float32, at the float32 rate."""
    return jnp.matmul(h_BxI.astype(W_IxN.dtype), W_IxN, preferred_element_type=jnp.float32)


def _frozen_product_fwd(h_BxI, W_IxN):
    return frozen_product(h_BxI, W_IxN), (W_IxN, jnp.zeros((0,), h_BxI.dtype))  # h's dtype, as an array


def _frozen_product_bwd(res, g_BxN):
    W_IxN, h_dtype = res[0], res[1].dtype
    dh = jax.lax.dot_general(g_BxN.astype(W_IxN.dtype), W_IxN, (((1,), (1,)), ((), ())),
                             preferred_element_type=jnp.float32)
    return dh.astype(h_dtype), None


frozen_product.defvjp(_frozen_product_fwd, _frozen_product_bwd)


def freeze_weights(params: dict, dtype=jnp.float32) -> dict:
    """``params`` of phase-functioned layers (``W (K, I, O)``) made frozen: every ``W`` stored as
    ``(I, K*O)`` in ``dtype`` (control points side by side, biases unchanged), which
    :func:`pf_dense` multiplies as one product of contiguous operands forward (``h @ W``) and
    backward (``g @ W^T``) through :func:`frozen_product`, with no gradient for the weights. In
    the ``(K, I, O)`` layout a traced ``W`` is copied into another layout on every product
    (``python benchmarks/sweep.py`` measures the difference)."""
    def one(layer):
        w = layer["W"]
        return {**layer, "W": jnp.transpose(w, (1, 0, 2)).reshape(w.shape[1], -1).astype(dtype)}
    return {name: one(layer) for name, layer in params.items()}


def cast_weights(params: dict, dtype) -> dict:
    """``params`` with every weight matrix ``W`` in ``dtype`` (biases stay float32), layout
    unchanged: layer products then run in that precision (see :func:`pf_dense`) and gradients
    still reach the float32 weights through the cast (mixed-precision training). A frozen base
    is laid out by :func:`freeze_weights` instead."""
    return jax.tree_util.tree_map_with_path(
        lambda path, v: v.astype(dtype) if getattr(path[-1], "key", None) == "W" else v, params)


# --- parameters ---------------------------------------------------------------------------------

def _uniform(key, shape, fan_in, fan_out):
    bound = math.sqrt(6.0 / (fan_in * fan_out))
    return jax.random.uniform(key, shape, jnp.float32, -bound, bound)


def _pf_layer(key, n_in, n_out):
    return {"W": _uniform(key, (NUM_CONTROL_POINTS, n_in, n_out), n_in, n_out),
            "b": jnp.zeros((NUM_CONTROL_POINTS, n_out), jnp.float32)}


def init_pfnn(key: jax.Array, config: PFNNConfig = PFNNConfig()) -> dict:
    """Base PFNN parameters: three phase-functioned layers ``l0, l1, l2``."""
    k0, k1, k2 = jax.random.split(key, 3)
    c = config
    return {"l0": _pf_layer(k0, c.input_size, c.hidden_size), "l1": _pf_layer(k1, c.hidden_size, c.hidden_size),
            "l2": _pf_layer(k2, c.hidden_size, c.output_size)}


def init_adapter(key: jax.Array, config: PFNNConfig = PFNNConfig()) -> dict:
    """One style's residual adapter on the middle layer (section 3.2; random, also for few-shot).

    * full: a phase-spline ``H x H`` matrix and bias: ``{"W": (4, H, H), "b": (4, H)}``;
    * diagonal: a phase-spline vector and bias: ``{"d": (4, H), "b": (4, H)}``;
    * cp: ``B (d(p) * (A h)) + b`` with ``A (rank, H)``, a phase-spline core ``d (4, rank)``,
      ``B (H, rank)`` and a phase-independent bias ``b (H,)``.
    """
    h, r = config.hidden_size, config.rank
    ka, kb, kd = jax.random.split(key, 3)
    if config.adapter == "full":
        return _pf_layer(ka, h, h)
    if config.adapter == "diagonal":
        return {"d": jax.random.uniform(kd, (NUM_CONTROL_POINTS, h), jnp.float32, -1.0, 1.0) * math.sqrt(6.0 / h),
                "b": jnp.zeros((NUM_CONTROL_POINTS, h), jnp.float32)}
    return {"A": _uniform(ka, (r, h), h, r), "d": jax.random.uniform(kd, (NUM_CONTROL_POINTS, r), jnp.float32, -1, 1),
            "B": _uniform(kb, (h, r), r, h), "b": jnp.zeros((h,), jnp.float32)}


def adapter_size(config: PFNNConfig) -> int:
    """Parameters of one adapter: full ``4 H^2 + 4 H``, diagonal ``8 H``, cp ``2 r H + 4 r + H``."""
    h, r = config.hidden_size, config.rank
    return {"full": 4 * h * h + 4 * h, "diagonal": 8 * h, "cp": 2 * r * h + 4 * r + h}[config.adapter]


def adapter_bytes(config: PFNNConfig, num_bins: int | None = None, itemsize: int = 4) -> int:
    """Storage of one adapter: control points (``num_bins=None``) or discretised into ``num_bins``
    phase bins (:func:`discretise`), at ``itemsize`` bytes per value (float32)."""
    if num_bins is None:
        return adapter_size(config) * itemsize
    h, r = config.hidden_size, config.rank
    values = {"full": num_bins * (h * h + h), "diagonal": num_bins * 2 * h,
              "cp": 2 * r * h + num_bins * r + h}[config.adapter]
    return values * itemsize


def adapter_kind(adapter: dict) -> str:
    """``"full"``, ``"diagonal"`` or ``"cp"``, from the adapter's parameter names."""
    if "A" in adapter:
        return "cp"
    return "full" if "W" in adapter else "diagonal"


# --- the residual adapters (Mason et al. 2018, Eq. 4 and Eq. 6) --------------------------------

def full_residual(h_BxH: jax.Array, W_HxO: jax.Array, b_O: jax.Array) -> jax.Array:
    """``h W + b``: a full residual adapter at one phase, Mason et al. 2018, Eq. 4's
    ``W_res^(s) h + b_res^(s)`` (section 3.2, the feed-forward form of Eq. 2's ``h_1x1 * x``), one
    ``(H, O)`` matrix shared by the batch (a :func:`discretise` bin, or the phase-free adapter of the
    2022 LPN and MANN ``Resad`` baselines). A batch with per-sample phases uses :func:`pf_dense`,
    which is ``sum_k weights[:, k] full_residual(h, W_k, b_k)``: outputs blended, no per-sample
    matrix.
    """
    return h_BxH @ W_HxO + b_O


def diag_residual(h_BxH: jax.Array, d_BxH: jax.Array, b_BxH: jax.Array) -> jax.Array:
    """``d * h + b``: the diagonal residual adapter, Mason et al. 2018, Eq. 4 with
    ``W_res^(s)(p) = diag(d(p))`` (section 8.1 and Table 1's diagonal comparison). ``d_BxH`` and
    ``b_BxH`` are the diagonal and bias at each sample's phase (:func:`blend` of the control points,
    or one bin of :func:`discretise`); any shape broadcasting against ``(B, H)``, e.g. ``(H,)``
    shared by the batch.
    """
    return d_BxH * h_BxH + b_BxH


def cp_residual(h_BxH: jax.Array, A_RxH: jax.Array, d_BxR: jax.Array, B_HxR: jax.Array, b_H: jax.Array) -> jax.Array:
    """``B diag(d(p)) A h + b``: the CP-factored residual adapter, Mason et al. 2018, Eq. 6
    (``X_k = A D^(k) B^T``, one slice ``k`` per phase, section 7.1) applied to ``h`` factor by
    factor, never forming the ``H x H`` slice: ``A_RxH`` and ``B_HxR`` are phase-independent, the core
    ``d_BxR`` (the diagonal of ``D``) is at each sample's phase (:func:`blend` of its 4 control
    points, or one bin of :func:`discretise`; ``(R,)`` is shared by the batch), the bias ``b_H`` is
    phase-independent (the authors' code). In the paper's notation ``A`` is our ``B_HxR`` and
    ``B^T`` our ``A_RxH``.
    """
    return (d_BxR * (h_BxH @ A_RxH.T)) @ B_HxR.T + b_H


def _residual(adapter: dict, h_BxH: jax.Array, at: Callable, full: Callable) -> jax.Array:
    """An adapter's residual with its phase-functioned vectors evaluated by ``at`` and, for a full
    adapter, the residual itself given by ``full(adapter, h)``."""
    kind = adapter_kind(adapter)
    if kind == "full":
        return full(adapter, h_BxH)
    if kind == "diagonal":
        return diag_residual(h_BxH, at(adapter["d"]), at(adapter["b"]))
    return cp_residual(h_BxH, adapter["A"], at(adapter["d"]), adapter["B"], adapter["b"])


def apply_adapter(adapter: dict, h_BxH: jax.Array, weights_Bx4: jax.Array) -> jax.Array:
    """The residual ``R_s(h)`` added to the middle layer's pre-activation (Mason et al. 2018,
    Eq. 4), at the phases whose :func:`catmull_rom_weights` are ``weights_Bx4``:
    :func:`full_residual` (through :func:`pf_dense`), :func:`diag_residual` or :func:`cp_residual`."""
    return _residual(adapter, h_BxH, lambda v: blend(v, weights_Bx4),
                     lambda a, h: pf_dense(a, h, weights_Bx4))


def barycentric(weights_K, count: int, *, max_count: int | None = None, what: str = "style") -> np.ndarray:
    """``weights_K`` checked as barycentric weights of ``count`` items (one each, non-negative,
    summing to 1; at most ``max_count`` items): the weights of every style blend in jaxstyle."""
    w = np.asarray(weights_K, dtype=np.float64)
    limit = "" if max_count is None else f", at most {max_count}"
    if (w.shape != (count,) or (max_count is not None and not 1 <= count <= max_count) or (w < 0).any()
            or not np.isclose(w.sum(), 1.0)):
        raise ValueError(f"barycentric weights: give one non-negative weight per {what} ({count}{limit}), "
                         f"summing to 1; got {w.tolist()}")
    return w


def blend_trees(trees_K, weights_K, *, max_count: int | None = None, what: str = "style"):
    """``sum_k w_k tree_k`` of pytrees stacked on a leading axis, with :func:`barycentric` weights:
    the blend of anything linear in its parameters (FiLM vectors, one-hot rows, full and diagonal
    adapters)."""
    w = barycentric(weights_K, jax.tree.leaves(trees_K)[0].shape[0], max_count=max_count, what=what)
    return jax.tree.map(lambda v: jnp.tensordot(jnp.asarray(w, v.dtype), v, axes=1), trees_K)


def blend_adapters(adapters_K: dict, weights_K) -> dict:
    """One adapter whose residual is ``sum_k w_k R_k(h)``: a blend of ``K`` styles' adapters
    (stacked on a leading axis, e.g. ``jax.tree.map(lambda *v: jnp.stack(v), a, b)``) with
    barycentric weights (non-negative, summing to 1), for style interpolation at runtime.

    Full and diagonal adapters are linear in their parameters, so their blend is the weighted sum.
    The CP residual ``B (d(p) * (A h)) + b`` is not; its blend is exactly the CP adapter of rank
    ``K r`` with the ``A``, ``d`` stacked and each ``B_k`` scaled by ``w_k`` (no approximation, and
    it still works with :func:`discretise` and :func:`pfnn_apply_table`).
    """
    if adapter_kind(adapters_K) != "cp":
        return blend_trees(adapters_K, weights_K, what="adapter")
    k = jax.tree.leaves(adapters_K)[0].shape[0]
    wj = jnp.asarray(barycentric(weights_K, k, what="adapter"), jnp.float32)
    a, d, b = adapters_K["A"], adapters_K["d"], adapters_K["B"]
    rank = a.shape[1]
    return {"A": a.reshape(k * rank, -1),                                 # (K r, H)
            "d": jnp.moveaxis(d, 0, 1).reshape(d.shape[1], k * rank),   # (4, K r)
            "B": jnp.moveaxis(b * wj[:, None, None], 0, 1).reshape(b.shape[1], k * rank),  # (H, K r)
            "b": jnp.tensordot(wj, adapters_K["b"], axes=1)}


def pad_rank(adapter: dict, rank: int) -> dict:
    """A CP adapter widened to ``rank`` with zero components: the same residual, so adapters of
    different ranks (say, a blend from :func:`blend_adapters` and single styles) stack into one
    batch of characters. Full and diagonal adapters are returned as they are."""
    if adapter_kind(adapter) != "cp":
        return adapter
    extra = rank - adapter["A"].shape[0]
    if extra < 0:
        raise ValueError(f"cannot pad a rank-{adapter['A'].shape[0]} adapter down to rank {rank}")
    return {"A": jnp.pad(adapter["A"], ((0, extra), (0, 0))), "d": jnp.pad(adapter["d"], ((0, 0), (0, extra))),
            "B": jnp.pad(adapter["B"], ((0, 0), (0, extra))), "b": adapter["b"]}


def stack_adapters(adapters: Sequence[dict]) -> dict:
    """Adapters of one kind stacked on a new leading axis (one per style or character); CP adapters
    of different ranks are first padded to the largest (:func:`pad_rank`, which changes nothing
    they compute)."""
    adapters = list(adapters)
    if not adapters:
        raise ValueError("no adapters to stack")
    if adapter_kind(adapters[0]) == "cp":
        rank = max(a["A"].shape[0] for a in adapters)
        adapters = [pad_rank(a, rank) for a in adapters]
    return jax.tree.map(lambda *v: jnp.stack(v), *adapters)


# --- dropout, forward, loss ---------------------------------------------------------------------

DROPOUT_LEVELS = 256  # the mask's resolution: 8 random bits per unit


def dropout(key: jax.Array, x: jax.Array, rate: jax.Array | float) -> jax.Array:
    """Inverted dropout with ``rate`` as a (traced) array: ``vmap`` over rates works. Rate 0 is the
    identity; the 2018 code's dropout numbers are KEEP probabilities (0.7 keep = 0.3 rate).

    Each unit's mask uses 8 random bits (one 32-bit draw serves four units, a quarter of the
    random-number work of a float draw, which is a fifth of a fine-tuning step on CPU), so the
    rate is rounded to the nearest multiple of 1/256 (0.3 -> 77/256 = 0.3008); the kept units are
    scaled by the rounded keep probability, so the layer stays unbiased.
    """
    levels = jnp.round(jnp.clip(jnp.asarray(rate, jnp.float32), 0.0, 1.0) * DROPOUT_LEVELS)
    keep = 1.0 - levels / DROPOUT_LEVELS
    n = x.size
    words = jax.random.bits(key, (-(-n // 4),), jnp.uint32)
    bits = jax.lax.bitcast_convert_type(words, jnp.uint8).reshape(-1)[:n].reshape(x.shape)
    kept = bits.astype(jnp.int32) >= levels.astype(jnp.int32)
    return jnp.where(kept, x / jnp.maximum(keep, 1e-6).astype(x.dtype), jnp.zeros((), x.dtype))


def pfnn_apply(params: dict, x_BxI: jax.Array, phase_B: jax.Array, *, adapter: dict | None = None,
               key: jax.Array | None = None, dropout_rate: jax.Array | float = 0.0,
               adapter_dropout_rate: jax.Array | float | None = None) -> jax.Array:
    """Mason et al. 2018, Eq. 4: ``y = W2(p) drop(h2) + b2(p)``,
    ``h2 = ELU(W1(p) drop(h1) + b1(p) + R_s(drop'(h1)))``, ``h1 = ELU(W0(p) drop(x) + b0(p))``, every
    ``W(p), b(p)`` the phase function of Eq. 1a (:func:`pf_dense`) and ``R_s`` the adapter
    (:func:`apply_adapter`). ``adapter=None`` drops ``R_s`` (the average motion).

    ``key`` is needed when a dropout rate is non-zero; the adapter path gets its own mask (rate
    ``adapter_dropout_rate``, default ``dropout_rate``).
    """
    w = catmull_rom_weights(phase_B)
    if key is None:
        key = jax.random.PRNGKey(0)  # only used with zero rates, where masks keep everything
    k0, k1, k2, ka = jax.random.split(key, 4)
    ar = dropout_rate if adapter_dropout_rate is None else adapter_dropout_rate
    h1 = jax.nn.elu(pf_dense(params["l0"], dropout(k0, x_BxI, dropout_rate), w))
    pre = pf_dense(params["l1"], dropout(k1, h1, dropout_rate), w)
    if adapter is not None:
        pre = pre + apply_adapter(adapter, dropout(ka, h1, ar), w)
    h2 = jax.nn.elu(pre)
    return pf_dense(params["l2"], dropout(k2, h2, dropout_rate), w)


def l1_penalty(tree: dict) -> jax.Array:
    """Mean over weight tensors of ``mean |W|`` (biases, named ``b``, are free), as in the 2018 code."""
    leaves = [v for path, v in jax.tree_util.tree_leaves_with_path(tree)
              if getattr(path[-1], "key", None) != "b"]
    if not leaves:
        return jnp.zeros(())
    return jnp.mean(jnp.stack([jnp.mean(jnp.abs(v)) for v in leaves]))


def loss(params: dict, adapter: dict | None, x_BxI, y_BxO, phase_B, *, key=None, dropout_rate=0.0,
         lambda_ag: float = 0.01, lambda_s: float = 0.01) -> jax.Array:
    """Mason et al. 2018, Eq. 3 (with the authors' mean squared error for the paper's ``||.||_2``):
    MSE on normalised outputs + ``lambda_ag`` L1(base) + ``lambda_s`` L1(adapter)."""
    pred = pfnn_apply(params, x_BxI, phase_B, adapter=adapter, key=key, dropout_rate=dropout_rate)
    total = jnp.mean((pred - y_BxO) ** 2) + lambda_ag * l1_penalty(params)
    if adapter is not None:
        total = total + lambda_s * l1_penalty(adapter)
    return total


# --- runtime: discretised phase bins (Mason et al. 2018, section 7.1) ---------------------------------

def discretise(tree: dict, num_bins: int = 50) -> dict:
    """Every phase-functioned array of ``tree`` (``W``, ``d``, and 2-D ``b``, each ``(4, ...)``)
    evaluated at the bin centres ``(i + 0.5) / num_bins``, giving ``(num_bins, ...)``;
    phase-independent arrays (the CP adapter's ``A``, ``B`` and 1-D ``b``) are kept.

    The paper's runtime precomputes 50 bins and indexes them with ``floor(phase * 50)``. jaxstyle
    evaluates each bin at its centre rather than its start, which halves the largest error.
    """
    w = catmull_rom_weights((jnp.arange(num_bins) + 0.5) / num_bins)  # (bins, 4)

    def one(path, v):
        name = getattr(path[-1], "key", None)
        return blend(v, w) if name in ("W", "d") or (name == "b" and v.ndim == 2) else v

    return jax.tree_util.tree_map_with_path(one, tree)


def _table_dense(layer, h, i):
    return h @ layer["W"][i] + layer["b"][i]


def pfnn_apply_table(table: dict, x_BxI: jax.Array, phase: jax.Array | float, *,
                     adapter_table: dict | None = None) -> jax.Array:
    """Runtime forward with discretised parameters (:func:`discretise`) for inputs sharing one
    ``phase`` (the runtime runs batch 1), no dropout: bin ``floor(phase * bins)`` is used as is,
    so one matrix per layer is read, never one per sample."""
    bins = table["l0"]["W"].shape[0]
    i = jnp.clip(jnp.floor(jnp.mod(phase, 1.0) * bins).astype(jnp.int32), 0, bins - 1)
    h1 = jax.nn.elu(_table_dense(table["l0"], x_BxI, i))
    pre = _table_dense(table["l1"], h1, i)
    if adapter_table is not None:
        pre = pre + _residual(adapter_table, h1, lambda v: v[i], lambda a, h: full_residual(h, a["W"][i], a["b"][i]))
    return _table_dense(table["l2"], jax.nn.elu(pre), i)
