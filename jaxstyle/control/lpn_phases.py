"""The 2022 runtime's phases (Mason, Starke & Komura 2022, section 4.4, on Starke et al. 2020's
local phases): how far the local phases advance (:func:`local_phase_advance`,
:func:`predicted_advance`), the floor on that advance (:func:`floored_phases`,
:func:`capture_phase_rate`), the global phase's rate (:func:`global_phase_ratio`,
:func:`phase_ratio`) and the expert blend's input per backbone (:func:`gate_input`). The per-frame
step that uses them is :mod:`jaxstyle.control.lpn_controller`.

The global phase's advance. The authors' PFNN baseline predicts 327 values, one of them the global
phase's change, as the 2018 PFNN does (:meth:`jaxstyle.nn.style_models.StyleModelConfig.paper`);
jaxstyle's seven Table 2 models all predict the same 342-value LPN row (comparable test MSE,
:func:`jaxstyle.mason2022.pipeline.model_config`), which has no global-phase change. The advance is
derived from what the row does have, the local phases: ``omega_t``, the amplitude-weighted
circular mean of the 4 local phases' advance from ``P_t`` to ``P_{t+1}`` (the angle of
``sum_b conj(z_b,t) z_b,t+1`` with ``z = cos + i sin`` of Eq. 1's feature; a still limb, whose
amplitude is near 0, weighs nothing), times the style's ratio ``kappa`` of global to local advance
over its training rows (:func:`global_phase_ratio`): ``phi_{t+1} = phi_t + kappa max(omega_t, 0)``
(mod 1; clipped at 0 as the 2018 controller clips its predicted change). The ratio is needed: the
local phases are fitted over 0.5 s windows (:func:`jaxstyle.local_phases`) and on 100STYLE turn
faster than the stride, whose cycle the global phase counts (Neutral_FW: 0.018 against 0.012
cycles per frame; Chicken_FR: 0.020 against 0.019), so ``kappa = 1`` would run a walk's phase
half as fast again as its data.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control.loop import normaliser_arrays
from jaxstyle.data.datasets import consecutive_rows, style_rows
from jaxstyle.data.lpn_features import NUM_PHASE_FEATURES, LPNLayout
from jaxstyle.data.normalise import Normaliser
from jaxstyle.nn import style_models
from jaxstyle.nn.style_models import StyleModelConfig


def local_phase_advance(p0_8: jax.Array, p1_8: jax.Array) -> jax.Array:
    """``omega`` (cycles, in ``(-0.5, 0.5]``): the amplitude-weighted circular mean of the 4 local
    phases' advance from ``p0`` to ``p1`` (each ``(8,)``: (sin, cos) per bone, Eq. 1's feature
    scaled by amplitude), the angle of ``sum_b conj(z0_b) z1_b`` with ``z = cos + i sin``. Works on
    numpy and JAX arrays (leading axes broadcast)."""
    xp = jnp if isinstance(p0_8, jax.Array) or isinstance(p1_8, jax.Array) else np
    cross, dot = _limb_products(p0_8, p1_8)
    return xp.arctan2(cross.sum(-1), dot.sum(-1)) / (2.0 * np.pi)


def _limb_products(p0_8, p1_8):
    """Per limb ``(..., 4)``: ``Im`` and ``Re`` of ``conj(z0) z1`` with ``z = cos + i sin`` of each
    limb's (sin, cos) pair of ``p0`` and ``p1`` (numpy or JAX, leading axes broadcast)."""
    a = p0_8.reshape(p0_8.shape[:-1] + (NUM_PHASE_FEATURES // 2, 2))
    b = p1_8.reshape(p1_8.shape[:-1] + (NUM_PHASE_FEATURES // 2, 2))
    return a[..., 1] * b[..., 0] - a[..., 0] * b[..., 1], a[..., 1] * b[..., 1] + a[..., 0] * b[..., 0]


def predicted_advance(y_O: jax.Array, num_bones: int) -> jax.Array:
    """``omega`` (cycles): the local phases' advance the network predicts in the de-normalised
    output ``y (..., O)``, from its previous phases ``P~_{t+1} - dP`` to its next ``P~_{t+1}``
    (:func:`local_phase_advance`; both read off the same output, so the estimate does not depend
    on how far the carried phases have drifted from the network's; see the module docstring)."""
    g = LPNLayout(num_bones).output_groups
    nxt = y_O[..., g["local_phase"]]
    return local_phase_advance(nxt - y_O[..., g["local_phase_update"]], nxt)


def floored_phases(p0_8: jax.Array, p1_8: jax.Array, floor) -> jax.Array:
    """The next local phases ``p1 (8,)`` with each limb's advance from ``p0`` at least ``floor``
    cycles: a limb whose phase (the angle of ``z = cos + i sin`` of its (sin, cos) pair) advanced
    less is ``p0``'s angle moved on by ``floor`` at ``p1``'s amplitude. A limb of ``p0`` without
    amplitude (no angle to move on) keeps ``p1``; ``floor = 0`` returns ``p1`` unchanged.

    Why: the runtime blend of Starke et al. 2020, ``(P~_{t+1} + P_t + dP) / 2``, has a fixed point
    wherever the network's predicted phase stops turning with a still pose, and an under-trained
    network's closed loop settles there (the phases stall, the gating stops cycling the experts,
    the character freezes and glides; docs/mason2022.md, "The closed loop: why it froze"). With a
    floor from the style's capture (:func:`capture_phase_rate`) the phases keep turning, so the
    experts keep cycling; the network still sets each limb's amplitude and any faster advance."""
    a = p0_8.reshape(NUM_PHASE_FEATURES // 2, 2)
    b = p1_8.reshape(NUM_PHASE_FEATURES // 2, 2)
    advance_b = jnp.arctan2(*_limb_products(p0_8, p1_8)) / (2.0 * np.pi)
    r0 = jnp.linalg.norm(a, axis=-1)
    r1 = jnp.linalg.norm(b, axis=-1)
    angle = jnp.arctan2(a[:, 0], a[:, 1]) + 2.0 * np.pi * floor
    moved = jnp.stack([r1 * jnp.sin(angle), r1 * jnp.cos(angle)], axis=-1)
    use = (floor > 0) & (advance_b < floor) & (r0 > 1e-6)
    return jnp.where(use[:, None], moved, b).reshape(-1)


def floored_amplitudes(p_8: jax.Array, floor_4: jax.Array) -> jax.Array:
    """The local phases ``p (8,)`` with each limb's amplitude (the length of its ``(sin, cos)``
    pair) at least ``floor_4 (4,)``, its angle kept; a limb without amplitude (no angle) keeps it.
    ``floor_4 = 0`` returns ``p`` unchanged.

    Why (not in the paper): the gating reads the phases scaled by their amplitudes, and the network
    predicts the amplitudes for its own fed-back poses; a style whose feet's amplitudes collapse in
    the closed loop (the 100STYLE Drunk to a fifth of its capture's, docs/mason2022.md, "Why Drunk
    glides") barely cycles the experts however fast the phases turn."""
    pairs = p_8.reshape(NUM_PHASE_FEATURES // 2, 2)
    r = jnp.linalg.norm(pairs, axis=-1)
    scale = jnp.where(r > 1e-6, jnp.maximum(r, floor_4) / jnp.maximum(r, 1e-6), 1.0)
    return (pairs * scale[:, None]).reshape(-1)


def phase_amplitudes(p_Nx8) -> np.ndarray:
    """``(N, 4)``: each limb's local-phase amplitude, the length of its ``(sin, cos)`` pair."""
    p = np.asarray(p_Nx8, np.float64)
    return np.linalg.norm(p.reshape(p.shape[:-1] + (NUM_PHASE_FEATURES // 2, 2)), axis=-1)


def capture_phase_amplitude(dataset, name: str) -> np.ndarray:
    """``(4,)``: the median amplitude of each limb's local phase over dataset style ``name``'s rows
    (0 for a style without rows)."""
    rows = style_rows(dataset, name)
    if not len(rows):
        return np.zeros(NUM_PHASE_FEATURES // 2)
    return np.median(phase_amplitudes(dataset.phases[rows]), axis=0)


def capture_phase_rate(dataset, name: str) -> float:
    """The median advance per frame (cycles) of the local phases of dataset style ``name``'s rows
    (:func:`local_phase_advance` between each row and the next frame of its clip): the rate a
    character of that style's capture steps at. 0 for a style without consecutive rows."""
    rows = style_rows(dataset, name)
    a, b = consecutive_rows(dataset.clip[rows], dataset.frame[rows])
    if not len(a):
        return 0.0
    p = np.asarray(dataset.phases[rows], np.float64)
    return float(np.median(local_phase_advance(p[a], p[b])))


def global_phase_ratio(global_phase_N: np.ndarray, omega_N: np.ndarray, clip_N: np.ndarray,
                       frame_N: np.ndarray) -> float:
    """``kappa``: the global phase's advance over the predicted local one, ``sum dphi / sum
    max(omega, 0)`` over the consecutive frames of some rows (a row and the next one of the same
    clip, one frame later): ``dphi`` from the rows' ``global_phase``, ``omega`` the local advance
    predicted at each row (:func:`predicted_advance` of the network's output, or of the real
    output row). The one-parameter read-out ``dphi = kappa omega`` that makes
    the derived advance match the data on those rows. 1 when the rows have no consecutive pair or
    no positive advance."""
    g, w = np.asarray(global_phase_N, np.float64), np.asarray(omega_N, np.float64)
    clip, frame = np.asarray(clip_N), np.asarray(frame_N)
    if not (g.shape == w.shape == clip.shape == frame.shape) or g.ndim != 1:
        raise ValueError(f"need (N,) global phases, advances, clips and frames; got {g.shape}, {w.shape}, "
                         f"{clip.shape}, {frame.shape}")
    a, b = consecutive_rows(clip, frame)
    dg = np.mod(g[b] - g[a], 1.0)
    dl = np.maximum(w[a], 0.0)
    if not len(a) or not dl.sum() > 0 or not np.isfinite(dg.sum() / dl.sum()):
        return 1.0
    return float(dg.sum() / dl.sum())


def phase_ratio(params: dict, config: StyleModelConfig, style, normalisers: tuple[Normaliser, Normaliser], dataset,
                rows: np.ndarray, *, gate_columns=None, max_rows: int = 2048) -> float:
    """:func:`global_phase_ratio` of the network's own predicted local advance on the LPN
    ``dataset``'s ``rows`` (one style's training rows; the first ``max_rows`` in clip and frame
    order), each evaluated at its real input and gate (the row's global phase for the PFNN
    backbone) with the character's runtime ``style`` and the network's (input, output)
    ``normalisers``: the ratio that turns this network's predicted local advance into the style's
    global-phase rate (see the module docstring)."""
    rows = np.asarray(rows)
    rows = rows[np.lexsort((dataset.frame[rows], dataset.clip[rows]))][:max_rows]
    if len(dataset.global_phase) != len(dataset.inputs) or len(rows) < 2:
        return 1.0
    (xm, xs), (ym, ys) = (normaliser_arrays(n) for n in normalisers)
    x_n = (jnp.asarray(dataset.inputs[rows], jnp.float32) - xm) / xs
    gate = gate_input(config, jnp.asarray(dataset.phases[rows], jnp.float32),
                      jnp.asarray(dataset.global_phase[rows], jnp.float32), x_n,
                      check_gate_columns(config, gate_columns))
    y = style_models.model_apply(params, config, x_n, gate, style) * ys + ym
    omega = np.asarray(predicted_advance(y, LPNLayout.of_inputs(x_n.shape[1]).num_bones))
    return global_phase_ratio(dataset.global_phase[rows], omega, dataset.clip[rows], dataset.frame[rows])


def gate_input(config: StyleModelConfig, phases_Nx8: jax.Array, global_phase_N: jax.Array, x_n_NxD: jax.Array,
          gate_columns) -> jax.Array:
    """The expert blend's input for ``N`` rows: the local phases (LPN), the global phase (PFNN,
    ``(N, 1)`` in cycles) or the end effectors' normalised velocities (MANN, the ``gate_columns``
    of the normalised input)."""
    if config.backbone == "lpn":
        return phases_Nx8
    if config.backbone == "pfnn":
        return jnp.reshape(global_phase_N, (-1, 1))
    return x_n_NxD[:, jnp.asarray(gate_columns)]


def check_gate_columns(config: StyleModelConfig, gate_columns):
    if config.backbone == "mann" and gate_columns is None:
        raise ValueError("the MANN backbone gates on end-effector velocities: give StyleNetModel.create the "
                         "training skeleton (its gate_columns, jaxstyle.data.lpn_features.end_effector_columns)")
    return None if gate_columns is None else tuple(int(c) for c in gate_columns)
