"""Closed-loop PFNN synthesis along a user path (Holden et al. 2017's runtime, as used by Mason
et al. 2018 section 7.1), as one jitted ``lax.scan`` over frames.

Each frame the input is assembled from the network's own previous output, exactly in the layout
of :mod:`jaxstyle.data.pfnn_features`:

* past trajectory (offsets -60 .. -10 frames): the character's own generated ground frames;
* future trajectory (offsets 0 .. 50): the network's previous prediction blended with the user's
  path, the user's weight growing with the offset, ``w_k = 1 - (1 - k / 5) ** blend_bias``
  (0 for the current sample, 1 for the farthest), as in the PFNN demo's trajectory blending;
* joint positions and velocities: the previous frame's, already in the new character frame. The
  positions are the PFNN demo's blend (Holden et al. 2017's runtime, ``extra_joint_smooth = 0.5``):
  ``p_{t+1} = s P_{t+1} + (1 - s) (p_t + V_{t+1})`` of the predicted position ``P`` and the previous
  position moved on by the predicted velocity ``V``, ``s =`` :data:`JOINT_SMOOTH`. Where the two
  predictions disagree the carried pose is their average, which damps the autoregressive loop
  through the joint inputs: fed its raw predicted positions (``s = 1``), the paper-size base of
  ``experiments/quality.py`` stood at a waypoint in its Chicken style while its head rose and went
  30 m behind it within half a second.

The root then moves by the predicted velocity and turn, the phase advances by the predicted
(non-negative) change. Everything is in file units; the user's path is given as a ground
velocity and a facing direction per frame (:func:`path_controls`, :func:`turning_path`), relative
to where the character stands, so the loop is closed: the user steers, the character follows.

Shapes: one character per call; ``jax.vmap`` over ``state``/``controls``/``adapter`` gives
many (the base parameters broadcast).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import loop
from jaxstyle.control.loop import (  # noqa: F401
    HISTORY,
    SPACING,
    Controls,
    f32,
    initial_ground,
    normaliser_arrays,
    path_controls,
    rotate_xz,
    signal_controls,
    start_row,
    trajectory_input,
    turning_path,
)
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import FUTURE_SAMPLES, PFNNLayout
from jaxstyle.nn import pfnn

JOINT_SMOOTH = loop.JOINT_SMOOTH  # the weight of the predicted joints (loop.JOINT_SMOOTH, the module docstring)


class RolloutState(NamedTuple):
    """What the loop carries: ground frames of the last 61 frames ``hist_xz (61, 2)``,
    ``hist_yaw (61,)`` (global, the last is the current frame), the ``phase``, joint positions
    and velocities ``(3J,)`` in the current frame, and the predicted future trajectory
    ``future (4, 6)`` (x, z, direction x, direction z at offsets 0 .. 50) in the current frame."""

    hist_xz: jax.Array
    hist_yaw: jax.Array
    phase: jax.Array
    joint_pos: jax.Array
    joint_vel: jax.Array
    future: jax.Array


class Rollout(NamedTuple):
    """Per generated frame: global joint ``positions (T, J, 3)``, ground ``origin (T, 2)`` (x, z),
    ``yaw (T,)``, ``phase (T,)`` and the de-normalised network ``outputs (T, O)`` (which
    :func:`jaxstyle.decode_pfnn` turns into a :class:`jaxstyle.Motion`)."""

    positions: jax.Array
    origin: jax.Array
    yaw: jax.Array
    phase: jax.Array
    outputs: jax.Array


def initial_state(x_row: np.ndarray, phase: float, num_joints: int) -> RolloutState:
    """The loop's start from one (de-normalised) PFNN input row, e.g. a frame of real data: the
    character stands at the global origin facing +Z, with that row's pose and its past and
    future trajectory (:func:`initial_ground`)."""
    layout = PFNNLayout(num_joints)
    x = np.asarray(x_row, dtype=np.float64)
    if x.shape != (layout.input_size,):
        raise ValueError(f"x_row must have shape ({layout.input_size},) for {num_joints} joints, got {x.shape}")
    g = layout.input_groups
    hist_xz, hist_yaw, future = initial_ground(x, g)
    return RolloutState(hist_xz, hist_yaw, f32(np.mod(phase, 1.0)), f32(x[g["joint_position"]]),
                        f32(x[g["joint_velocity"]]), future)


def assemble_input(state: RolloutState, controls_t: tuple[jax.Array, jax.Array], blend_bias: float = 1.5) -> jax.Array:
    """The de-normalised PFNN input ``(48 + 6J,)`` of the current frame from the carried state and
    the user's path at this frame (``(offsets (6, 2), yaw (6,))``, one row of :class:`Controls`)."""
    traj = trajectory_input(state.hist_xz, state.hist_yaw, state.future, controls_t, blend_bias)
    return jnp.concatenate([traj, state.joint_pos, state.joint_vel])


def advance(state: RolloutState, y: jax.Array, num_joints: int, stand=0.0, joint_smooth=JOINT_SMOOTH
            ) -> tuple[RolloutState, Rollout]:
    """Move the character by one de-normalised output ``y (28 + 12J,)``: the next state and the
    generated frame.

    ``stand`` in ``[0, 1]`` (:func:`jaxstyle.control.loop.stand_amount`): how much the user asks
    to stand still. As in the PFNN demo (Holden et al. 2017's runtime, which the 2018 paper
    reuses), the root's translation and turn are scaled by ``m = (1 - stand) ** 0.25`` and the
    phase advance by ``0.1 + 0.9 m`` (:func:`jaxstyle.control.loop.stand_damping`, shared with the
    2022 controller): a network whose training data have few clean stops drifts
    on at a few cm/s after a stop command otherwise. The frame's recorded ``outputs`` hold the
    root motion and phase change as applied (scaled, the phase change clipped at 0)."""
    origin, yaw = state.hist_xz[-1], state.hist_yaw[-1]
    move, phase_scale = loop.stand_damping(stand)
    gx, gz = rotate_xz(move * y[0], move * y[1], yaw)
    new_origin = origin + jnp.stack([gx, gz])
    new_yaw = yaw + move * y[2]
    dphase = phase_scale * jnp.maximum(y[3], 0.0)
    new_phase = jnp.mod(state.phase + dphase, 1.0)
    g = PFNNLayout(num_joints).output_groups
    # the previous frame's joints (in C_t) seen from C_{t+1}: the root moved by (dx, dz) and turned
    prev = state.joint_pos.reshape(num_joints, 3)
    px, pz = rotate_xz(prev[:, 0] - move * y[0], prev[:, 2] - move * y[1], -move * y[2])
    carried = jnp.stack([px, prev[:, 1], pz], axis=-1) + y[g["joint_velocity"]].reshape(num_joints, 3)
    s = jnp.asarray(joint_smooth, y.dtype)
    local = s * y[g["joint_position"]].reshape(num_joints, 3) + (1.0 - s) * carried
    wx, wz = rotate_xz(local[:, 0], local[:, 2], new_yaw)
    positions = jnp.stack([wx + new_origin[0], local[:, 1], wz + new_origin[1]], axis=-1)
    traj = y[g["trajectory_position"].start:g["trajectory_direction"].stop].reshape(4, FUTURE_SAMPLES)
    new_state = RolloutState(jnp.concatenate([state.hist_xz[1:], new_origin[None]]),
                             jnp.concatenate([state.hist_yaw[1:], new_yaw[None]]), new_phase,
                             local.reshape(-1), y[g["joint_velocity"]], traj)
    # the recorded outputs carry the root motion, phase change and joint positions actually
    # applied, so that decode_pfnn (the BVH export) reproduces this rollout's root path exactly
    applied = jnp.concatenate([move * y[:3], dphase[None], y[4:]]).at[g["joint_position"]].set(local.reshape(-1))
    return new_state, Rollout(positions, new_origin, new_yaw, new_phase, applied)


def _step(params, adapter, x_norm, y_norm, num_joints, blend_bias, table, state: RolloutState, control):
    x_n = ((assemble_input(state, control, blend_bias) - x_norm[0]) / x_norm[1])[None]
    if table:
        y_n = pfnn.pfnn_apply_table(params, x_n, state.phase, adapter_table=adapter)[0]
    else:
        y_n = pfnn.pfnn_apply(params, x_n, state.phase[None], adapter=adapter)[0]
    stand = control[2] if len(control) > 2 else 0.0
    return advance(state, y_n * y_norm[1] + y_norm[0], num_joints, stand)


def model_step(params, x_norm, y_norm, num_joints: int, blend_bias: float = 1.5, table: bool = False):
    """The PFNN's per-frame ``step(adapter, state, control) -> (state, frame)`` for the shared loop
    of :mod:`jaxstyle.control.loop`, closing over the base weights and the (mean, std) arrays."""
    return functools.partial(_per_style_step, params, x_norm, y_norm, num_joints, blend_bias, table)


def _per_style_step(params, x_norm, y_norm, num_joints, blend_bias, table, adapter, state, control):
    return _step(params, adapter, x_norm, y_norm, num_joints, blend_bias, table, state, control)


def rollout(params: dict, adapter: dict | None, x_norm: Normaliser, y_norm: Normaliser, state: RolloutState,
            controls: Controls, *, blend_bias: float = 1.5, table: bool = False) -> Rollout:
    """Generate ``T = len(controls.offsets)`` frames closed-loop (jitted; ``vmap`` it, or use
    :func:`rollout_batch`, for many characters or adapters). ``x_norm``/``y_norm`` are the base
    model's statistics. A blend of styles is one adapter (:func:`jaxstyle.nn.pfnn.blend_adapters`).

    ``table=True``: ``params`` and ``adapter`` are :func:`jaxstyle.nn.pfnn.discretise` tables (the
    paper's runtime, 50 phase bins: one weight matrix per layer is read per frame). Use it for one
    character; for a batch of characters use the continuous phase (the default), which blends the
    four control points' layer outputs instead of gathering a matrix per character."""
    num_joints = state.joint_pos.shape[-1] // 3
    return _rollout(params, adapter, normaliser_arrays(x_norm), normaliser_arrays(y_norm), state, controls,
                    num_joints=num_joints, blend_bias=float(blend_bias), table=bool(table))


def step_fn(params: dict, adapter: dict | None, x_norm: Normaliser, y_norm: Normaliser, num_joints: int, *,
            blend_bias: float = 1.5, table: bool = False):
    """A jitted ``f(state, control, adapter=adapter) -> (state, frame)`` that generates ONE frame:
    the runtime's call per displayed frame when a user steers live (``control`` is one row of
    :class:`Controls`, ``(offsets (6, 2), yaw (6,))``). ``table`` as in :func:`rollout`.

    The base weights and statistics are compiled into the step as constants, as a game runtime
    loads them once: that halves the per-frame cost at batch 1 against passing ~20 weight arrays
    every call (``benchmarks/runtime.py``). The style stays an argument, so a user can switch or
    blend styles live (an adapter of the same kind and rank compiles once)."""
    step = model_step(params, normaliser_arrays(x_norm), normaliser_arrays(y_norm), int(num_joints),
                      float(blend_bias), bool(table))
    return loop.live_step(step, adapter)


def rollout_batch(params: dict, adapters: dict | None, x_norm: Normaliser, y_norm: Normaliser,
                  states: RolloutState, controls: Controls, *, blend_bias: float = 1.5) -> Rollout:
    """:func:`rollout` for ``C`` characters at once: ``states`` and ``controls`` stacked on a
    leading axis (``jax.tree.map(lambda *v: jnp.stack(v), *items)``), ``adapters`` stacked the same
    way (one style per character) or ``None`` (the base); the base parameters are shared
    (broadcast). Returns every field with a leading ``C`` axis."""
    num_joints = states.joint_pos.shape[-1] // 3
    return _rollout_batch(params, adapters, normaliser_arrays(x_norm), normaliser_arrays(y_norm), states, controls,
                          num_joints=num_joints, blend_bias=float(blend_bias))


@functools.partial(jax.jit, static_argnames=("num_joints", "blend_bias", "table"))
def _rollout(params, adapter, x_norm, y_norm, state, controls, *, num_joints, blend_bias, table):
    return loop.scan_frames(model_step(params, x_norm, y_norm, num_joints, blend_bias, table), adapter, state, controls)


@functools.partial(jax.jit, static_argnames=("num_joints", "blend_bias"))
def _rollout_batch(params, adapters, x_norm, y_norm, states, controls, *, num_joints, blend_bias):
    return loop.scan_characters(model_step(params, x_norm, y_norm, num_joints, blend_bias), adapters, states, controls,
                                shared_style=adapters is None)
