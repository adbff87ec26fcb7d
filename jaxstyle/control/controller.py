"""Closed-loop PFNN synthesis along a user path (Holden et al. 2017's runtime, as used by Mason
et al. 2018 section 7.1), as one jitted ``lax.scan`` over frames.

Each frame the input is assembled from the network's own previous output, exactly in the layout
of :mod:`jaxstyle.data.pfnn_features`:

* past trajectory (offsets -60 .. -10 frames): the character's own generated ground frames;
* future trajectory (offsets 0 .. 50): the network's previous prediction blended with the user's
  path, the user's weight growing with the offset, ``w_k = 1 - (1 - k / 5) ** blend_bias``
  (0 for the current sample, 1 for the farthest), as in the PFNN demo's trajectory blending;
* joint positions and velocities: the previous output, already in the new character frame.

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

from jaxstyle.control.paths import PathSignal
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import FUTURE_SAMPLES, PAST_SAMPLES, PFNNLayout
from jaxstyle.nn import pfnn

HISTORY = PAST_SAMPLES * 10 + 1  # ground frames t-60 .. t, at the 60 fps sample spacing of 10
SPACING = 10


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


class Controls(NamedTuple):
    """Per frame ``t``: the user's path ``offsets (T, 6, 2)``, the ground displacement from frame
    ``t`` to ``t + 10 k`` (k = 0 .. 5), global, and the desired facing yaw ``yaw (T, 6)`` there."""

    offsets: jax.Array
    yaw: jax.Array


class Rollout(NamedTuple):
    """Per generated frame: global joint ``positions (T, J, 3)``, ground ``origin (T, 2)`` (x, z),
    ``yaw (T,)``, ``phase (T,)`` and the de-normalised network ``outputs (T, O)`` (which
    :func:`jaxstyle.decode_pfnn` turns into a :class:`jaxstyle.Motion`)."""

    positions: jax.Array
    origin: jax.Array
    yaw: jax.Array
    phase: jax.Array
    outputs: jax.Array


def rotate_xz(x, z, a):
    """Ground vectors ``(x, z)`` rotated by yaw ``a`` (the convention of
    :func:`jaxstyle.motion.character_frame.rotate_yaw`)."""
    c, s = jnp.cos(a), jnp.sin(a)
    return x * c + z * s, -x * s + z * c


def path_controls(velocity_Tx2, yaw_T, fps: float = 60.0) -> Controls:
    """:class:`Controls` from a desired ground velocity (units per second, global x and z) and
    facing yaw (radians) per frame. Past the last frame the last values hold."""
    v = np.asarray(velocity_Tx2, dtype=np.float64)
    yaw = np.asarray(yaw_T, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 2 or yaw.shape != (len(v),):
        raise ValueError(f"velocity must be (T, 2) and yaw (T,), got {v.shape} and {yaw.shape}")
    if not (np.isfinite(v).all() and np.isfinite(yaw).all()):
        raise ValueError("path velocity and yaw must be finite")
    pad = FUTURE_SAMPLES * SPACING
    v = np.concatenate([v, np.repeat(v[-1:], pad, axis=0)])
    yaw = np.concatenate([yaw, np.repeat(yaw[-1:], pad)])
    disp = np.concatenate([np.zeros((1, 2)), np.cumsum(v / fps, axis=0)])  # displacement before frame i
    t = np.arange(len(velocity_Tx2))[:, None] + SPACING * np.arange(FUTURE_SAMPLES)[None]
    offsets = disp[t] - disp[t[:, :1]]
    return Controls(jnp.asarray(offsets, jnp.float32), jnp.asarray(yaw[t], jnp.float32))


def signal_controls(signal: PathSignal) -> Controls:
    """:class:`Controls` of a :class:`jaxstyle.control.paths.PathSignal` (velocity and facing per frame)."""
    return path_controls(signal.velocity, signal.yaw, signal.fps)


def turning_path(num_frames: int, speed: float, turn_rate: float, fps: float = 60.0,
                 start_yaw: float = 0.0) -> Controls:
    """Walk at ``speed`` (units/s) while turning at ``turn_rate`` (radians/s; 0 is a straight
    line), facing the direction of travel."""
    yaw = start_yaw + turn_rate * np.arange(num_frames) / fps
    velocity = speed * np.stack([np.sin(yaw), np.cos(yaw)], axis=-1)
    return path_controls(velocity, yaw, fps)


def start_row(x_NxI: np.ndarray, speed: float, *, units_per_meter: float, rows: np.ndarray | None = None,
              fps: float = 60.0) -> int:
    """The index of the de-normalised input row (PFNN or LPN layout: both start with the 48
    trajectory values) whose own trajectory moves closest to ``speed`` m/s in the straightest line:
    a start pose for :func:`initial_state` that suits a path at that speed (a walking pose for a
    walk, a standing one for ``speed=0``), among ``rows`` (default all)."""
    x = np.asarray(x_NxI, dtype=np.float64)
    idx = np.arange(len(x)) if rows is None else np.asarray(rows)
    if x.ndim != 2 or x.shape[1] < 48 or len(idx) == 0:
        raise ValueError(f"need (N, I >= 48) input rows and at least one candidate, got {x.shape} and {len(idx)} rows")
    n = PAST_SAMPLES + FUTURE_SAMPLES
    tx, tz = x[idx, :n], x[idx, n:2 * n]
    dx, dz = tx[:, -1] - tx[:, 0], tz[:, -1] - tz[:, 0]
    seconds = (n - 1) * SPACING / fps
    moved = np.hypot(dx, dz) / units_per_meter / seconds
    bend = np.abs(np.arctan2(dx, dz)) if speed > 0 else 0.0
    return int(idx[np.argmin(np.abs(moved - speed) + bend)])


def initial_ground(x_row: np.ndarray, groups: dict[str, slice]) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``hist_xz (61, 2)``, ``hist_yaw (61,)`` and ``future (4, 6)`` from the trajectory inputs of
    one de-normalised input row (the PFNN and LPN layouts share them, ``groups`` names their
    slices): the character stands at the global origin facing +Z, past frames between the
    10-frame samples interpolated linearly."""
    g, n = groups, PAST_SAMPLES + FUTURE_SAMPLES
    (tx, tz), (dx, dz) = (np.split(x_row[g[k]], 2) for k in ("trajectory_position", "trajectory_direction"))
    yaw = np.unwrap(np.arctan2(dx, dz))
    yaw -= yaw[PAST_SAMPLES]  # the current sample faces +Z exactly
    sample_t = np.arange(-PAST_SAMPLES, 1) * SPACING
    frames = np.arange(-(HISTORY - 1), 1)
    hist_xz = np.stack([np.interp(frames, sample_t, tx[:PAST_SAMPLES + 1]),
                        np.interp(frames, sample_t, tz[:PAST_SAMPLES + 1])], axis=-1)
    hist_xz -= hist_xz[-1]
    hist_yaw = np.interp(frames, sample_t, yaw[:PAST_SAMPLES + 1])
    f = slice(PAST_SAMPLES, n)
    future = np.stack([tx[f], tz[f], dx[f], dz[f]])
    return f32(hist_xz), f32(hist_yaw), f32(future)


def f32(a) -> jax.Array:
    """``a`` as a float32 JAX array."""
    return jnp.asarray(a, jnp.float32)


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


def trajectory_input(hist_xz: jax.Array, hist_yaw: jax.Array, future_4xF: jax.Array,
                     controls_t: tuple[jax.Array, jax.Array], blend_bias: float = 1.5) -> jax.Array:
    """The 48 trajectory inputs shared by the PFNN and the LPN layouts: x (12) | z (12) | direction
    x (12) | z (12) at offsets -60 .. 50, in the current frame. Past samples come from the
    character's own ground frames ``hist_xz (61, 2)``/``hist_yaw (61,)``; future samples are the
    previous prediction ``future (4, 6)`` blended with the user's path at this frame
    (``(offsets (6, 2), yaw (6,))``, one row of :class:`Controls`)."""
    offsets, user_yaw = controls_t
    origin, yaw = hist_xz[-1], hist_yaw[-1]
    # past samples, in the current frame
    past = slice(0, HISTORY - 1, SPACING)
    px, pz = rotate_xz(hist_xz[past, 0] - origin[0], hist_xz[past, 1] - origin[1], -yaw)
    pdx, pdz = rotate_xz(jnp.sin(hist_yaw[past]), jnp.cos(hist_yaw[past]), -yaw)
    # future: the previous prediction blended with the user's path
    ux, uz = rotate_xz(offsets[:, 0], offsets[:, 1], -yaw)
    udx, udz = rotate_xz(jnp.sin(user_yaw), jnp.cos(user_yaw), -yaw)
    w = 1.0 - (1.0 - jnp.arange(FUTURE_SAMPLES) / (FUTURE_SAMPLES - 1)) ** blend_bias
    fx, fz, fdx, fdz = (future_4xF[i] + w * (u - future_4xF[i]) for i, u in enumerate((ux, uz, udx, udz)))
    norm = jnp.maximum(jnp.sqrt(fdx ** 2 + fdz ** 2), 1e-6)
    fdx, fdz = fdx / norm, fdz / norm
    return jnp.concatenate([px, fx, pz, fz, pdx, fdx, pdz, fdz])


def assemble_input(state: RolloutState, controls_t: tuple[jax.Array, jax.Array], blend_bias: float = 1.5) -> jax.Array:
    """The de-normalised PFNN input ``(48 + 6J,)`` of the current frame from the carried state and
    the user's path at this frame (``(offsets (6, 2), yaw (6,))``, one row of :class:`Controls`)."""
    traj = trajectory_input(state.hist_xz, state.hist_yaw, state.future, controls_t, blend_bias)
    return jnp.concatenate([traj, state.joint_pos, state.joint_vel])


def advance(state: RolloutState, y: jax.Array, num_joints: int) -> tuple[RolloutState, Rollout]:
    """Move the character by one de-normalised output ``y (28 + 12J,)``: the next state and the
    generated frame."""
    origin, yaw = state.hist_xz[-1], state.hist_yaw[-1]
    gx, gz = rotate_xz(y[0], y[1], yaw)
    new_origin = origin + jnp.stack([gx, gz])
    new_yaw = yaw + y[2]
    new_phase = jnp.mod(state.phase + jnp.maximum(y[3], 0.0), 1.0)
    g = PFNNLayout(num_joints).output_groups
    local = y[g["joint_position"]].reshape(num_joints, 3)
    wx, wz = rotate_xz(local[:, 0], local[:, 2], new_yaw)
    positions = jnp.stack([wx + new_origin[0], local[:, 1], wz + new_origin[1]], axis=-1)
    traj = y[g["trajectory_position"].start:g["trajectory_direction"].stop].reshape(4, FUTURE_SAMPLES)
    new_state = RolloutState(jnp.concatenate([state.hist_xz[1:], new_origin[None]]),
                             jnp.concatenate([state.hist_yaw[1:], new_yaw[None]]), new_phase,
                             y[g["joint_position"]], y[g["joint_velocity"]], traj)
    return new_state, Rollout(positions, new_origin, new_yaw, new_phase, y)


def _step(params, adapter, x_norm, y_norm, num_joints, blend_bias, table, state: RolloutState, control):
    x_n = ((assemble_input(state, control, blend_bias) - x_norm[0]) / x_norm[1])[None]
    if table:
        y_n = pfnn.pfnn_apply_table(params, x_n, state.phase, adapter_table=adapter)[0]
    else:
        y_n = pfnn.pfnn_apply(params, x_n, state.phase[None], adapter=adapter)[0]
    return advance(state, y_n * y_norm[1] + y_norm[0], num_joints)


def normaliser_arrays(norm: Normaliser | tuple) -> tuple[jax.Array, jax.Array]:
    """``(mean, std)`` as float32 arrays, from a :class:`Normaliser` or a ``(mean, std)`` pair."""
    mean, std = (norm.mean, norm.std) if isinstance(norm, Normaliser) else norm
    return jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32)


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
    xn, yn = normaliser_arrays(x_norm), normaliser_arrays(y_norm)
    step = jax.jit(lambda state, control, a: _step(params, a, xn, yn, int(num_joints), float(blend_bias),
                                                   bool(table), state, control))
    return lambda state, control, a=adapter: step(state, control, a)


def rollout_batch(params: dict, adapters: dict | None, x_norm: Normaliser, y_norm: Normaliser,
                  states: RolloutState, controls: Controls, *, blend_bias: float = 1.5) -> Rollout:
    """:func:`rollout` for ``C`` characters at once: ``states`` and ``controls`` stacked on a
    leading axis (``jax.tree.map(lambda *v: jnp.stack(v), *items)``), ``adapters`` stacked the same
    way (one style per character) or ``None`` (the base); the base parameters are shared
    (broadcast). Returns every field with a leading ``C`` axis."""
    num_joints = states.joint_pos.shape[-1] // 3
    return _rollout_batch(params, adapters, normaliser_arrays(x_norm), normaliser_arrays(y_norm), states, controls,
                          num_joints=num_joints, blend_bias=float(blend_bias))


def _scan(params, adapter, x_norm, y_norm, state, controls, num_joints, blend_bias, table):
    def step(s, c):
        return _step(params, adapter, x_norm, y_norm, num_joints, blend_bias, table, s, c)

    _, out = jax.lax.scan(step, state, (controls.offsets, controls.yaw))
    return out


@functools.partial(jax.jit, static_argnames=("num_joints", "blend_bias", "table"))
def _rollout(params, adapter, x_norm, y_norm, state, controls, *, num_joints, blend_bias, table):
    return _scan(params, adapter, x_norm, y_norm, state, controls, num_joints, blend_bias, table)


@functools.partial(jax.jit, static_argnames=("num_joints", "blend_bias"))
def _rollout_batch(params, adapters, x_norm, y_norm, states, controls, *, num_joints, blend_bias):
    one = functools.partial(_scan, num_joints=num_joints, blend_bias=blend_bias, table=False)
    adapter_axis = None if adapters is None else 0
    return jax.vmap(lambda a, s, c: one(params, a, x_norm, y_norm, s, c),
                    in_axes=(adapter_axis, 0, 0))(adapters, states, controls)
