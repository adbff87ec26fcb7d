"""The local phase network's pieces (Mason, Starke & Komura 2022, section 4), as pure functions.

* :func:`init_gating` / :func:`gating_apply`: the gating network ``Omega`` (section 4.3: local
  phases ``8 -> 32 -> 32 -> 8``, ELU, dropout, softmax) giving the blend ``alpha (B, K)`` of the
  ``K = 8`` experts.
* :func:`init_experts` / :func:`expert_dense`: a layer with ``K`` sets of expert weights,
  ``W = sum_k alpha_k W_k`` (section 4.1). The blend is linear, so the ``K`` experts' OUTPUTS are
  blended (the same output blend as the PFNN's phase function, :func:`jaxstyle.nn.pfnn.pf_dense`):
  no weight matrix is ever built per sample.
* :func:`layer_norm` and :func:`film`: the conditional normalisation of Mason, Starke & Komura
  2022, Eq. 3, ``gamma * (F - mu) / sigma + beta``, LayerNorm without learned affine (as the
  authors' code); :func:`split_film` splits Eq. 2's four FiLM vectors.
* :func:`synthesis_apply`: the animation synthesis network ``Phi`` (2022, Eq. 3-4), ``348 -> 512
  -> 512 -> 342``: per layer dropout -> expert layer -> (hidden layers) LayerNorm -> FiLM -> ELU.
  The same function serves the PFNN and MANN backbones and the one-hot and residual-adapter style
  modulations of Table 2 (:mod:`jaxstyle.nn.style_models` chooses).
* :func:`bone_length_loss`: 2022, Eq. 6, mean over bones of the absolute bone-length difference.

Shapes: ``x_BxI`` inputs, ``alpha_BxK`` expert blend, ``film_Bx4H`` (or ``film_4H`` shared by the
batch) the FiLM parameters ``[gamma1 | beta1 | gamma2 | beta2]``. Every function takes a batch;
give one example as a batch of one.
"""

from __future__ import annotations

from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.nn import pfnn

LAYER_NORM_EPS = 1e-5
glorot = jax.nn.initializers.glorot_uniform()  # TensorFlow's default, as in the authors' code


def _dense(key, n_in, n_out) -> dict:
    return {"W": glorot(key, (n_in, n_out), jnp.float32), "b": jnp.zeros((n_out,), jnp.float32)}


# --- gating network Omega (section 4.1, 4.3) ----------------------------------------------------

def init_gating(key: jax.Array, sizes: Sequence[int] = (8, 32, 32, 8)) -> list[dict]:
    """Dense layers ``sizes[0] -> ... -> sizes[-1]`` (paper: 8 -> 32 -> 32 -> 8)."""
    keys = jax.random.split(key, len(sizes) - 1)
    return [_dense(k, a, b) for k, a, b in zip(keys, sizes[:-1], sizes[1:], strict=True)]


def gating_apply(params: list[dict], g_BxG: jax.Array, *, key: jax.Array | None = None,
                 dropout_rate: jax.Array | float = 0.0) -> jax.Array:
    """``alpha (B, K)``: softmax blend of the experts from the gating input (local phases)."""
    keys = jax.random.split(jax.random.PRNGKey(0) if key is None else key, len(params))
    h = g_BxG
    for i, (layer, k) in enumerate(zip(params, keys, strict=True)):
        h = pfnn.dropout(k, h, dropout_rate) @ layer["W"] + layer["b"]
        if i < len(params) - 1:
            h = jax.nn.elu(h)
    return jax.nn.softmax(h, axis=-1)


# --- gated expert layers ------------------------------------------------------------------------

def init_experts(key: jax.Array, num_experts: int, n_in: int, n_out: int) -> dict:
    """``{"W": (K, I, O), "b": (K, O)}``, each expert Glorot-uniform, biases zero."""
    w = jax.vmap(lambda k: glorot(k, (n_in, n_out), jnp.float32))(jax.random.split(key, num_experts))
    return {"W": w, "b": jnp.zeros((num_experts, n_out), jnp.float32)}


def expert_dense(layer: dict, h_BxI: jax.Array, alpha_BxK: jax.Array) -> jax.Array:
    """``(sum_k alpha_k W_k) h + sum_k alpha_k b_k``, computed as the blend of the experts' outputs."""
    return pfnn.pf_dense(layer, h_BxI, alpha_BxK)


def blended_weights(layer: dict, alpha_K: jax.Array) -> dict:
    """The explicitly blended ``{"W": (I, O), "b": (O,)}`` of one sample's ``alpha``: the paper's
    formulation, kept as the reference :func:`expert_dense` is tested against (and for runtimes
    that blend once per frame)."""
    return {"W": jnp.tensordot(alpha_K, layer["W"], axes=1), "b": alpha_K @ layer["b"]}


# --- conditional normalisation (Mason, Starke & Komura 2022, Eq. 3) -----------------------------

def layer_norm(f_BxH: jax.Array, eps: float = LAYER_NORM_EPS) -> jax.Array:
    """``(F - mu) / sigma`` over the features of each example, no learned affine (Ba et al. 2016):
    the bracket of Mason, Starke & Komura 2022, Eq. 3, with ``mu``, ``sigma`` the mean and standard
    deviation of ``F_j`` over its ``H`` features (``sigma = sqrt(var + eps)``, the biased variance)."""
    mu = jnp.mean(f_BxH, axis=-1, keepdims=True)
    var = jnp.mean(jnp.square(f_BxH - mu), axis=-1, keepdims=True)
    return (f_BxH - mu) * jax.lax.rsqrt(var + eps)


def film(h_BxH: jax.Array, gamma_BxH: jax.Array, beta_BxH: jax.Array) -> jax.Array:
    """Feature-wise linear modulation ``gamma o h + beta``: Mason, Starke & Komura 2022, Eq. 3
    (applied to the :func:`layer_norm` of the features, before the ELU), raw ``gamma`` as the
    authors' code. ``gamma_BxH``, ``beta_BxH`` are one layer's FiLM vectors of Eq. 2, per example
    or ``(H,)`` shared by the batch. Eq. 8 (section 5.3.1) writes it as ``diag(gamma) h + beta``."""
    return gamma_BxH * h_BxH + beta_BxH


def split_film(film_x4H: jax.Array, hidden: int) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """``gamma1, beta1, gamma2, beta2`` (Mason, Starke & Komura 2022, Eq. 2) from ``(..., 4 H)``
    FiLM parameters."""
    if film_x4H.shape[-1] != 4 * hidden:
        raise ValueError(f"FiLM parameters must have {4 * hidden} values (4 x {hidden}), got {film_x4H.shape[-1]}")
    return tuple(film_x4H[..., i * hidden:(i + 1) * hidden] for i in range(4))


# --- animation synthesis network Phi (Mason, Starke & Komura 2022, Eq. 3, 4) -------------------

def init_synthesis(key: jax.Array, num_experts: int, sizes: Sequence[int] = (348, 512, 512, 342)) -> dict:
    """Three expert layers ``l0, l1, l2`` of ``sizes`` (paper: 348 -> 512 -> 512 -> 342, 8 experts)."""
    keys = jax.random.split(key, 3)
    layers = zip(keys, sizes[:-1], sizes[1:], strict=True)
    return {f"l{i}": init_experts(k, num_experts, a, b) for i, (k, a, b) in enumerate(layers)}


def synthesis_apply(params: dict, x_BxI: jax.Array, alpha_BxK: jax.Array, *, film_params: jax.Array | None = None,
                    shift_BxH: jax.Array | None = None,
                    residual: Callable[[jax.Array], jax.Array] | None = None, normalise: bool = True,
                    key: jax.Array | None = None, dropout_rate: jax.Array | float = 0.0) -> jax.Array:
    """``z (B, O)`` from ``x (B, I)`` and the expert blend ``alpha (B, K)``: Mason, Starke & Komura
    2022, Eq. 4.

    Layer ``i`` of the hidden layers: ``h_i = ELU(FiLM_i(LN(F_i)))`` with ``F_i`` the expert layer's
    output on the dropped-out ``h_{i-1}`` (2022, Eq. 3). Options for the Table 2 variants:

    * ``film_params (B, 4H)`` or ``(4H,)``: FiLM on both hidden layers; ``None`` skips FiLM;
    * ``shift_BxH``: a style-dependent shift added to the first layer's features (one-hot);
    * ``residual``: a function of the dropped-out ``h_1`` added to the second layer's features
      (residual adapter), with its own dropout mask;
    * ``normalise``: LayerNorm (no affine) on the hidden layers.
    """
    k0, k1, k2, ka = jax.random.split(jax.random.PRNGKey(0) if key is None else key, 4)
    hidden = params["l0"]["W"].shape[-1]
    gammas = betas = (None, None)
    if film_params is not None:
        g1, b1, g2, b2 = split_film(film_params, hidden)
        gammas, betas = (g1, g2), (b1, b2)

    def modulate(f, i):
        f = layer_norm(f) if normalise else f
        return f if gammas[i] is None else film(f, gammas[i], betas[i])

    f1 = expert_dense(params["l0"], pfnn.dropout(k0, x_BxI, dropout_rate), alpha_BxK)
    if shift_BxH is not None:
        f1 = f1 + shift_BxH
    h1 = jax.nn.elu(modulate(f1, 0))
    f2 = expert_dense(params["l1"], pfnn.dropout(k1, h1, dropout_rate), alpha_BxK)
    if residual is not None:
        f2 = f2 + residual(pfnn.dropout(ka, h1, dropout_rate))
    h2 = jax.nn.elu(modulate(f2, 1))
    return expert_dense(params["l2"], pfnn.dropout(k2, h2, dropout_rate), alpha_BxK)


# --- bone-length loss (Mason, Starke & Komura 2022, Eq. 6) --------------------------------------

def bone_length_loss(pred_BxJx3: jax.Array, true_BxJx3: jax.Array, parents_J: Sequence[int]) -> jax.Array:
    """Mason, Starke & Komura 2022, Eq. 6 averaged over the batch (Eq. 7 per style): mean over
    bones ``b`` (joints with a parent) of ``| |z_bp - z_b| - |z^_bp - z^_b| |``, on de-normalised
    positions; ``parents_J`` (-1 for the root) is static."""
    parents = np.asarray(parents_J)
    child = np.flatnonzero(parents >= 0)
    par = parents[child]

    def lengths(p):  # a safe norm: finite gradients for zero-length bones
        d = p[:, child] - p[:, par]
        return jnp.sqrt(jnp.sum(d * d, axis=-1) + 1e-12)

    return jnp.mean(jnp.abs(lengths(true_BxJx3) - lengths(pred_BxJx3)))
