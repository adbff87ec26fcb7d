"""The training objective of the 2022 style models (Mason, Starke & Komura 2022, section 4.3,
Eq. 5-7): :func:`batch_loss` is the MSE on the normalised outputs plus ``bone_loss_weight`` times
the bone-length loss on the de-normalised joint positions in metres (the authors' data is in
metres; 100STYLE files are in centimetres, so positions are divided by the skeleton's units per
metre); a FiLM model's style comes from one training clip of the batch's style per step.

Not in the paper, options evaluated against the closed loop's freezing (docs/mason2022.md):
:func:`noisy_inputs` (noise on the normalised inputs) and :func:`rollout_loss` (windows of frames
fed the network's own outputs through the runtime's feed-back).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxstyle.data.lpn_features import LPNLayout
from jaxstyle.mason2022.styledata import BonePositions
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import lpn, style_models
from jaxstyle.nn.style_models import StyleModelConfig


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


class Batch(NamedTuple):
    """One minibatch: rows ``idx_B`` of style ``style``; a FiLM model's style comes from training
    clip ``clip`` (scalars or traced arrays)."""

    idx_B: Any
    style: Any
    clip: Any


class LossWeights(NamedTuple):
    """The objective's settings, traced (arrays, so sweeps vmap over them): ``rate``, the dropout
    rate; ``bone_loss_weight``, Eq. 6's weight of the bone-length loss; ``input_noise``, the standard
    deviation of :func:`noisy_inputs` (0: the paper's recipe)."""

    rate: Any
    bone_loss_weight: Any
    input_noise: Any = 0.0


def _style(params, config: StyleModelConfig, clips, style, clip, key, rate):
    if config.modulation == "film":
        return film.generator_apply(params["style"]["generator"], clips[clip][None], key=key, dropout_rate=rate)
    return style_models.style_runtime(params, config, style)


def batch_loss(params, config: StyleModelConfig, arrays, batch: Batch, key, weights: LossWeights,
               bones: BonePositions) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """``MSE + w BLL`` of one minibatch (:class:`Batch`: rows of one style, a FiLM model's
    parameters from one clip) with the dropout rate, bone-length weight and input noise of
    ``weights`` (:class:`LossWeights`; noise 0 gives the same value as the paper's recipe);
    returns the total and ``(mse, bll)``."""
    x, y, gate, clips = arrays
    idx_B, style, clip = batch
    rate = weights.rate
    k_style, k_model = jax.random.split(key)
    st = _style(params, config, clips, style, clip, k_style, rate)
    x_B = noisy_inputs(x[idx_B], jax.random.fold_in(key, 1), weights.input_noise)
    pred = style_models.model_apply(params, config, x_B, gate[idx_B], st, key=k_model, dropout_rate=rate)
    mse, bll = losses(pred, y[idx_B], bones)
    return mse + weights.bone_loss_weight * bll, (mse, bll)


def noisy_inputs(x_BxD: jax.Array, key: jax.Array, std) -> jax.Array:
    """``x + std * N(0, 1)`` (normalised inputs; ``std = 0`` returns ``x``). Not in the paper: at
    runtime the network reads its own previous output (pose, velocities, predicted trajectory),
    never exactly a captured row, and trained only on clean rows it learns to copy the input
    pose forward; the closed loop then settles on a still pose (docs/mason2022.md, "The closed loop:
    why it froze"). Noise on the inputs, with the clean next frame as the target, is the
    standard remedy for a model fed its own outputs (a denoising objective). An array, so sweeps
    vmap over it."""
    return x_BxD + std * jax.random.normal(key, x_BxD.shape, x_BxD.dtype)


def rollout_loss(params, config: StyleModelConfig, arrays, feedback, batch: Batch, key, weights: LossWeights,
                 bones: BonePositions, *, steps: int) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """Rollout training (not in the paper): the mean of :func:`batch_loss`'s ``MSE + w BLL`` over
    windows of ``1 + steps`` consecutive frames starting at the batch's rows
    (:func:`jaxstyle.mason2022.styledata.rollout_starts`). The first frame reads the captured input;
    each later frame reads the captured trajectory (the user's control at runtime) with the joint features the network
    predicted one frame before, re-expressed in the frame it predicted
    (:func:`jaxstyle.control.lpn_controller.feed_back`, what the runtime feeds back), and, for the
    LPN, the local phases the runtime would carry; every frame's target is the captured next
    frame. Gradients flow through the fed-back inputs (back-propagation through time).

    Why: the network trained only on captured inputs (the paper's recipe) learns to carry the
    input pose forward, and its closed loop stalls on a still pose (docs/mason2022.md, "The closed loop:
    why it froze"); exposed to its own outputs, it learns to step from them (the remedy
    of scheduled sampling, Bengio et al. 2015, and of the rollout losses of later character
    controllers). ``feedback``: ``(next_row, x_mean, x_std, y_mean, y_std)`` of
    :class:`jaxstyle.mason2022.styledata.StyleData`."""
    from jaxstyle.control.lpn_controller import feed_back

    x, y, gate, clips = arrays
    next_row, x_mean, x_std, y_mean, y_std = feedback
    idx_B, style, clip = batch
    rate, bone_loss_weight, input_noise = weights
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
