"""Closed-loop synthesis with the 2022 style models (Mason, Starke & Komura 2022, section 4.4), as
one jitted ``lax.scan`` over frames, batched over characters with ``vmap``.

The shared loop of :mod:`jaxstyle.control.loop` (which the PFNN's :mod:`jaxstyle.control.controller`
also runs) with this module's per-frame step on the LPN layout of :mod:`jaxstyle.data.lpn_features`.
Each frame:

* the input ``(48 + 12 B,)``: past trajectory from the character's own ground frames, future
  trajectory = the previous prediction blended with the user's path
  (:func:`jaxstyle.control.loop.trajectory_input`, Zhang et al. 2018's blend as the paper says),
  and the previous output's joint features (positions, velocities, forward and up vectors);
* the gating input: the carried local phases (LPN), or the end effectors' velocities of the
  normalised input (MANN);
* the style: a precomputed FiLM vector (the runtime never runs the generator; a blend of 2-3
  styles is :func:`jaxstyle.nn.film_generator.interpolate`), a one-hot row or an adapter
  (:func:`jaxstyle.nn.style_models.blend_styles` blends those);
* the output ``(342,)`` is relative to the current frame ``C_t``. Its first future trajectory
  sample is the next frame's ground frame, so the root moves there and turns to its direction;
  the predicted future trajectory and joint features are re-expressed in ``C_{t+1}`` for the next
  input;
* local phases: the network predicts both the next phases ``P~_{t+1}`` and the update ``dP``; the
  carried phases become their average, ``P_{t+1} = (P~_{t+1} + P_t + dP) / 2`` (Starke et al.
  2020's runtime blends the two estimates the same way, which keeps the phases from drifting).

Shapes: one character per call of :func:`rollout`; :func:`rollout_batch` takes ``C`` characters
(states, controls and styles stacked on a leading axis) and shares the network parameters.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import loop
from jaxstyle.control.loop import Controls, f32, initial_ground, normaliser_arrays, rotate_xz, trajectory_input
from jaxstyle.data.lpn_features import NUM_PHASE_FEATURES, LPNLayout
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import FUTURE_SAMPLES
from jaxstyle.nn import style_models
from jaxstyle.nn.style_models import StyleModelConfig


class LPNState(NamedTuple):
    """What the loop carries: ground frames of the last 61 frames ``hist_xz (61, 2)``, ``hist_yaw
    (61,)`` (global; the last is the current frame), the local ``phases (8,)``, the joint features
    ``joints (12 B,)`` of the current frame in its own ground frame, and the predicted future
    trajectory ``future (4, 6)`` (x, z, direction x, z at offsets 0 .. 50) in the current frame."""

    hist_xz: jax.Array
    hist_yaw: jax.Array
    phases: jax.Array
    joints: jax.Array
    future: jax.Array


class LPNRollout(NamedTuple):
    """Per generated frame: global ``positions (T, B, 3)`` of the LPN bones (the skeleton's joints
    first, then the hand end sites), ground ``origin (T, 2)`` (x, z), ``yaw (T,)``, local
    ``phases (T, 8)``, predicted foot ``contacts (T, 2)`` (left, right; the foot IK's input) and the
    de-normalised network ``outputs (T, O)`` (:func:`jaxstyle.decode_lpn` makes a Motion of them)."""

    positions: jax.Array
    origin: jax.Array
    yaw: jax.Array
    phases: jax.Array
    contacts: jax.Array
    outputs: jax.Array


def initial_state(x_row: np.ndarray, phases_row: np.ndarray, num_bones: int) -> LPNState:
    """The loop's start from one de-normalised LPN input row and its local phases (e.g. a frame of
    real data): the character stands at the global origin facing +Z with that row's pose."""
    layout = LPNLayout(num_bones)
    x = np.asarray(x_row, dtype=np.float64)
    p = np.asarray(phases_row, dtype=np.float64)
    if x.shape != (layout.input_size,):
        raise ValueError(f"x_row must have shape ({layout.input_size},) for {num_bones} bones, got {x.shape}")
    if p.shape != (NUM_PHASE_FEATURES,):
        raise ValueError(f"phases_row must have shape ({NUM_PHASE_FEATURES},), got {p.shape}")
    if not (np.isfinite(x).all() and np.isfinite(p).all()):
        raise ValueError("x_row and phases_row must be finite")
    hist_xz, hist_yaw, future = initial_ground(x, layout.input_groups)
    joints = x[layout.input_groups["joint_position"].start:]
    return LPNState(hist_xz, hist_yaw, f32(p), f32(joints), future)


def _yaw_rotate(v_Nx3: jax.Array, a) -> jax.Array:
    x, z = rotate_xz(v_Nx3[:, 0], v_Nx3[:, 2], a)
    return jnp.stack([x, v_Nx3[:, 1], z], axis=-1)


def advance(state: LPNState, y: jax.Array, num_bones: int) -> tuple[LPNState, LPNRollout]:
    """Move the character by one de-normalised output ``y (24 + 12 B + 18,)``: the next state and
    the generated frame (see the module docstring)."""
    g = LPNLayout(num_bones).output_groups
    origin, yaw = state.hist_xz[-1], state.hist_yaw[-1]
    traj = y[g["trajectory_position"].start:g["trajectory_direction"].stop]
    tx, tz, tdx, tdz = traj.reshape(4, FUTURE_SAMPLES)
    gx, gz = rotate_xz(tx[0], tz[0], yaw)
    new_origin = origin + jnp.stack([gx, gz])
    turn = jnp.arctan2(tdx[0], tdz[0])
    new_yaw = yaw + turn
    # future trajectory samples t+1+0..50, from C_t into C_{t+1}
    fx, fz = rotate_xz(tx - tx[0], tz - tz[0], -turn)
    fdx, fdz = rotate_xz(tdx, tdz, -turn)
    feats = y[g["joint_position"].start:g["joint_up"].stop].reshape(4, num_bones, 3)  # pos, vel, fwd, up in C_t
    pos = feats[0]
    gpx, gpz = rotate_xz(pos[:, 0], pos[:, 2], yaw)
    positions = jnp.stack([gpx + origin[0], pos[:, 1], gpz + origin[1]], axis=-1)
    shift = jnp.stack([tx[0], 0.0, tz[0]])
    next_feats = jnp.stack([_yaw_rotate(pos - shift, -turn)] + [_yaw_rotate(v, -turn) for v in feats[1:]])
    phases = 0.5 * (y[g["local_phase"]] + state.phases + y[g["local_phase_update"]])
    contacts = y[g["foot_contact"]]
    new_state = LPNState(jnp.concatenate([state.hist_xz[1:], new_origin[None]]),
                         jnp.concatenate([state.hist_yaw[1:], new_yaw[None]]), phases,
                         next_feats.reshape(-1), jnp.stack([fx, fz, fdx, fdz]))
    return new_state, LPNRollout(positions, new_origin, new_yaw, phases, contacts, y)


def _step(params, config, style, x_norm, y_norm, gate_columns, num_bones, blend_bias, state: LPNState, control):
    x = jnp.concatenate([trajectory_input(state.hist_xz, state.hist_yaw, state.future, control, blend_bias),
                         state.joints])
    x_n = ((x - x_norm[0]) / x_norm[1])[None]
    gate = state.phases[None] if config.backbone == "lpn" else x_n[:, jnp.asarray(gate_columns)]
    y_n = style_models.model_apply(params, config, x_n, gate, style)[0]
    return advance(state, y_n * y_norm[1] + y_norm[0], num_bones)


def _check(config: StyleModelConfig, gate_columns):
    if config.backbone == "pfnn":
        raise ValueError("the LPN controller runs the lpn and mann backbones; "
                         "the PFNN one is jaxstyle.control.controller")
    if config.backbone == "mann" and gate_columns is None:
        raise ValueError("the MANN backbone gates on end-effector velocities: pass gate_columns="
                         "jaxstyle.data.lpn_features.end_effector_columns(skeleton)")
    return None if gate_columns is None else tuple(int(c) for c in gate_columns)


def model_step(params, config: StyleModelConfig, x_norm, y_norm, gate_columns, num_bones: int, blend_bias: float = 1.5):
    """The style model's per-frame ``step(style, state, control) -> (state, frame)`` for the shared
    loop of :mod:`jaxstyle.control.loop`, closing over the network's weights and statistics."""
    return functools.partial(_per_style_step, params, config, x_norm, y_norm, gate_columns, num_bones, blend_bias)


def _per_style_step(params, config, x_norm, y_norm, gate_columns, num_bones, blend_bias, style, state, control):
    return _step(params, config, style, x_norm, y_norm, gate_columns, num_bones, blend_bias, state, control)


_STATIC = ("config", "gate_columns", "num_bones", "blend_bias")


@functools.partial(jax.jit, static_argnames=_STATIC)
def _rollout(params, style, x_norm, y_norm, state, controls, *, config, gate_columns, num_bones, blend_bias):
    step = model_step(params, config, x_norm, y_norm, gate_columns, num_bones, blend_bias)
    return loop.scan_frames(step, style, state, controls)


@functools.partial(jax.jit, static_argnames=_STATIC)
def _rollout_batch(params, styles, x_norm, y_norm, states, controls, *, config, gate_columns, num_bones,
                   blend_bias):
    step = model_step(params, config, x_norm, y_norm, gate_columns, num_bones, blend_bias)
    return loop.scan_characters(step, styles, states, controls)


def rollout(params: dict, config: StyleModelConfig, style, x_norm: Normaliser, y_norm: Normaliser,
            state: LPNState, controls: Controls, *, gate_columns=None, blend_bias: float = 1.5) -> LPNRollout:
    """Generate ``T = len(controls.offsets)`` frames closed-loop with a style model (jitted).

    ``style``: the per-style runtime parameter of :func:`jaxstyle.nn.style_models.model_apply` (a FiLM
    vector ``(4 H,)``, precomputed). ``x_norm``/``y_norm``: the training data's statistics.
    ``gate_columns``: the MANN backbone's gating columns of the normalised input."""
    cols = _check(config, gate_columns)
    return _rollout(params, style, normaliser_arrays(x_norm), normaliser_arrays(y_norm), state, controls,
                    config=config, gate_columns=cols, num_bones=state.joints.shape[-1] // 12,
                    blend_bias=float(blend_bias))


def step_fn(params: dict, config: StyleModelConfig, style, x_norm: Normaliser, y_norm: Normaliser, num_bones: int, *,
            gate_columns=None, blend_bias: float = 1.5):
    """A jitted ``f(state, control, style=style) -> (state, frame)`` that generates ONE frame (the
    runtime's call per displayed frame when a user steers live); arguments as :func:`rollout`.
    The network's weights are compiled in as constants (see :func:`jaxstyle.control.controller.step_fn`);
    the style (a FiLM vector, e.g. a live barycentric blend) stays an argument."""
    cols = _check(config, gate_columns)
    step = model_step(params, config, normaliser_arrays(x_norm), normaliser_arrays(y_norm), cols, int(num_bones),
                      float(blend_bias))
    return loop.live_step(step, style)


def rollout_batch(params: dict, config: StyleModelConfig, styles, x_norm: Normaliser, y_norm: Normaliser,
                  states: LPNState, controls: Controls, *, gate_columns=None, blend_bias: float = 1.5) -> LPNRollout:
    """:func:`rollout` for ``C`` characters at once: ``styles``, ``states`` and ``controls`` stacked
    on a leading axis (one style per character; repeat a style to share it); the network's
    parameters are shared. Every field of the result has a leading ``C`` axis."""
    cols = _check(config, gate_columns)
    return _rollout_batch(params, styles, normaliser_arrays(x_norm), normaliser_arrays(y_norm), states, controls,
                          config=config, gate_columns=cols, num_bones=states.joints.shape[-1] // 12,
                          blend_bias=float(blend_bias))
