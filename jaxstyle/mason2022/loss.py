"""The training objective of the 2022 style models (Mason, Starke & Komura 2022, section 4.3,
Eq. 5-7): :func:`batch_loss` is the MSE on the normalised outputs plus ``bone_loss_weight`` times
the bone-length loss on the de-normalised joint positions in metres (the authors' data is in
metres; 100STYLE files are in centimetres, so positions are divided by the skeleton's units per
metre); a FiLM model's style comes from one training clip of the batch's style per step.

Not in the paper, options evaluated against the closed loop's freezing and sliding
(docs/mason2022.md): :func:`noisy_inputs` (noise on the normalised inputs), :func:`rollout_loss`
(windows of frames fed the network's own outputs through the runtime's feed-back) and
:func:`contact_loss` (a foot the capture plants does not move).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxstyle.data.lpn_features import LPNLayout
from jaxstyle.mason2022.styledata import BonePositions, FootContacts
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


def _group(rows_BxD, group) -> jax.Array:
    start, scale, offset = group
    return rows_BxD[:, start:start + len(scale)] * scale + offset


def contact_loss(x_BxD, pred_BxO, y_BxO, bones: BonePositions) -> jax.Array:
    """Not in the paper: the mean over rows and foot joints (ankles and toes) of
    ``c (|P - p| + |V|)`` in metres per frame, where ``c`` is the captured next frame's contact
    label of the joint's foot, ``p`` the joint's position in the input (frame ``t``, in ``C_t``),
    ``P`` and ``V`` the predicted next position (in ``C_t``) and velocity. A planted foot does not
    move in the world, and ``P - p`` and ``V`` are its two predicted world displacements (the
    runtime carries ``s P + (1 - s)(p + V)``, :func:`jaxstyle.control.lpn_controller.feed_back`).

    Why: the MSE of Eq. 5 weighs a foot's position like any of the other 341 normalised outputs,
    and with one standard deviation per feature group (about 0.3 m for positions) a 3 cm error
    costs 0.01; on its test rows the demo-size model has this loss at 0.017-0.020 m per frame
    against the capture's 0.0015, and its feet slide 3-8x the captures' in the closed loop.
    Measured (docs/mason2022.md, "Feet that slide"): weight 10 lowers it by a quarter to a third
    and steps on more rows, but the closed loop's planted feet slide as fast as without it. Foot
    contact losses of this kind are common in motion synthesis (e.g. Shi et al. 2020,
    "MotioNet"; Tevet et al. 2023, "Human Motion Diffusion Model")."""
    c: FootContacts = bones.contact
    n = len(c.x_position[1]) // 3
    feet, side = jnp.asarray(c.feet), jnp.asarray(c.side)
    p = _group(x_BxD, c.x_position).reshape(len(x_BxD), n, 3)[:, feet]
    big_p = positions_m(pred_BxO, bones)[:, feet]
    v = _group(pred_BxO, c.y_velocity).reshape(len(x_BxD), n, 3)[:, feet]
    on = jnp.clip(_group(y_BxO, c.y_contact), 0.0, 1.0)[:, side]
    return jnp.mean(on * (_norm(big_p - p) + _norm(v)))


def _norm(v_Bx3: jax.Array) -> jax.Array:
    """Euclidean norm over the last axis with a finite gradient at 0."""
    return jnp.sqrt(jnp.sum(jnp.square(v_Bx3), axis=-1) + 1e-12)


class Batch(NamedTuple):
    """One minibatch: rows ``idx_B`` of style ``style``; a FiLM model's style comes from training
    clip ``clip`` (scalars or traced arrays)."""

    idx_B: Any
    style: Any
    clip: Any


class LossWeights(NamedTuple):
    """The objective's settings, traced (arrays, so sweeps vmap over them): ``rate``, the dropout
    rate; ``bone_loss_weight``, Eq. 6's weight of the bone-length loss; ``input_noise``, the standard
    deviation of :func:`noisy_inputs`; ``contact_weight``, the weight of :func:`contact_loss`
    (0 for both: the paper's recipe)."""

    rate: Any
    bone_loss_weight: Any
    input_noise: Any = 0.0
    contact_weight: Any = 0.0


def _style(params, config: StyleModelConfig, clips, style, clip, key, rate):
    if config.modulation == "film":
        return film.generator_apply(params["style"]["generator"], clips[clip][None], key=key, dropout_rate=rate)
    return style_models.style_runtime(params, config, style)


def batch_loss(params, config: StyleModelConfig, arrays, batch: Batch, key, weights: LossWeights,
               bones: BonePositions) -> tuple[jax.Array, tuple[jax.Array, jax.Array]]:
    """``MSE + w BLL`` of one minibatch (:class:`Batch`: rows of one style, a FiLM model's
    parameters from one clip) with the dropout rate, bone-length weight and input noise of
    ``weights`` (:class:`LossWeights`; noise 0 gives the same value as the paper's recipe), plus
    ``contact_weight`` times :func:`contact_loss` when the bones carry the feet; returns the total
    and ``(mse, bll)``."""
    x, y, gate, clips = arrays
    idx_B, style, clip = batch
    rate = weights.rate
    k_style, k_model = jax.random.split(key)
    st = _style(params, config, clips, style, clip, k_style, rate)
    x_B = noisy_inputs(x[idx_B], jax.random.fold_in(key, 1), weights.input_noise)
    pred = style_models.model_apply(params, config, x_B, gate[idx_B], st, key=k_model, dropout_rate=rate)
    mse, bll = losses(pred, y[idx_B], bones)
    return mse + weights.bone_loss_weight * bll + _contact_term(x[idx_B], pred, y[idx_B], bones, weights), (mse, bll)


def _contact_term(x_BxD, pred_BxO, y_BxO, bones: BonePositions, weights: LossWeights):
    """``contact_weight * contact_loss``; 0, not computed, for bones without feet or a weight of
    ``None`` or a Python 0 (the paper's recipe and the fine-tuning sweeps pay nothing for it)."""
    w = weights.contact_weight
    if bones.contact is None or w is None or (isinstance(w, (int, float)) and w == 0):
        return 0.0
    return weights.contact_weight * contact_loss(x_BxD, pred_BxO, y_BxO, bones)


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
    rate, bone_loss_weight, input_noise = weights.rate, weights.bone_loss_weight, weights.input_noise
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
        step = mse + bone_loss_weight * bll + _contact_term(x_B, pred, y[rows], bones, weights)
        total, mse_sum, bll_sum = total + step, mse_sum + mse, bll_sum + bll
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
