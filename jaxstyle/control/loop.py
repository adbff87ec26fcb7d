"""The closed-loop synthesis loop both papers' controllers share (Holden et al. 2017's runtime, used
by Mason et al. 2018 section 7.1 and Mason, Starke & Komura 2022 section 4.4).

A controller is a per-model ``step(style, state, control) -> (state, frame)``: it assembles the
network's input from the carried ``state`` and one row of the user's :class:`Controls`, runs the
network with the per-character ``style`` (an adapter, a FiLM vector, ...) and moves the character.
This module holds what does not depend on the model:

* the user's path as :class:`Controls` (:func:`path_controls`, :func:`signal_controls`,
  :func:`turning_path`) and a start pose that suits it (:func:`start_row`);
* the 48 trajectory inputs both layouts share (:func:`trajectory_input`, :func:`initial_ground`);
* the loop itself: :func:`scan_frames` (one character, ``lax.scan`` over frames),
  :func:`scan_characters` (``vmap`` over characters, the network's parameters broadcast) and
  :func:`live_step` (one jitted frame for interactive use).

:mod:`jaxstyle.control.controller` (the PFNN's step) and :mod:`jaxstyle.control.lpn_controller`
(the 2022 style models' step) are the two users.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control.paths import PathSignal
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import FUTURE_SAMPLES, PAST_SAMPLES

HISTORY = PAST_SAMPLES * 10 + 1  # ground frames t-60 .. t, at the 60 fps sample spacing of 10
SPACING = 10

Step = Callable  # step(style, state, control) -> (state, frame)


FOLLOW_SECONDS = 0.25
"""Default time constant (s) of the path-following law: a position error is closed over this time
(:func:`follow_gains`)."""


FOLLOW_GAIN = 4.0
"""Default gain of the path-following law for the networks (:func:`path_controls`): each future
sample aims ``FOLLOW_GAIN`` times the share of the position error :func:`follow_gains` gives it.

Why not 1: a network does not move where its future trajectory points the way an ideal tracker
does. Its input blends the user's samples with its own previous prediction
(:func:`trajectory_input`, near samples weigh 0.28-0.75 with blend bias 1.5) and its speed is held by
the gait it has learnt, so it realises only part of a correction. Measured on the 2018 base of
``experiments/quality.py``: driven at the style's own speed with gain 1, the characters settle at
their path's speed but 0.2-0.7 m ahead of their ideal position, and the error stays (a proportional
law's steady offset; ``follow_seconds`` 0.1 instead of 0.25 changes it by under 0.05 m).

How 4 was chosen, on models other than the one the quality benchmark reports: the closed-loop
final error on 8 s straight, circle and zigzag paths of the procedural ``jaxstyle demo`` model
(4 base styles, 4 few-shot sets: paths within 0.3 m for gains 1, 2, 3, 4, 6: 10, 15, 16, 17, 16 of
24) and of ``experiments/quality.py --small`` (21 paths: 13, 19, 21, 21, 21). For an ideal tracker
(``tests/test_path_following.py``) a gain above 1 over-aims, so the kinematic tests use 1; a
tracker that realises a quarter of a correction needs 4 to close the error."""


JOINT_SMOOTH = 0.5
"""Both controllers' weight ``s`` of the predicted joint positions against the previous ones
moved on by the predicted velocities, ``p_{t+1} = s P_{t+1} + (1 - s) (p_t + V_{t+1})``, the
pose carried to the next frame's input, drawn and recorded (1: the raw prediction). The runtimes
the papers reuse do this: the PFNN demo (Holden et al. 2017; Mason et al. 2018) mixes with its
``extra_joint_smooth = 0.5``, and Starke et al.'s local-motion-phase runtime (Mason et al. 2022)
lerps its bone positions the same way. Where the two predictions disagree the carried pose is
their average, which damps the autoregressive loop through the joint inputs
(:mod:`jaxstyle.control.controller`, :mod:`jaxstyle.control.lpn_controller`)."""


class Controls(NamedTuple):
    """Per frame ``t``: the user's path ``offsets (T, 6, 2)``, the ground displacement from frame
    ``t`` to ``t + 10 k`` (k = 0 .. 5), global, and the desired facing yaw ``yaw (T, 6)`` there.

    Path following (optional): ``target (T, 2)`` is where the path wants the character's origin at
    the start of frame ``t`` (global, file units) and ``gain (T, 6)`` how much of the position
    error ``target - origin`` each future sample corrects (:func:`follow_gains`). Inside the loop
    (:func:`steer`) sample ``k`` then aims at ``offsets[k] + gain[k] * (target - origin)``: the
    character steers back toward where the path wants it. ``None`` (or zero gains): open loop, the
    offsets are taken as they are, relative to wherever the character stands.

    ``stand (T,)`` in ``[0, 1]``: how much the user asks the character to stand still (the PFNN
    demo's ``gait_stand``; :func:`stand_amount`), which a controller may use to damp the root
    motion and the phase (:func:`jaxstyle.control.controller.advance`)."""

    offsets: jax.Array
    yaw: jax.Array
    target: jax.Array | None = None
    gain: jax.Array | None = None
    stand: jax.Array | None = None


def follow_gains(follow_seconds: float | None) -> np.ndarray:
    """``(6,)`` gains of the path-following law for the future samples ``k = 0 .. 5`` (``k / 6`` s
    ahead, the 10-frame spacing at the networks' 60 fps): ``g_k = min(1, (k / 6) / follow_seconds)``.

    The law is a time-indexed pursuit of the path's ideal positions (the runtimes of Holden et al.
    2017 and of both papers only feed the user's velocity, which lets any error accumulate: 1-3 m
    of drift in 8 s): the future trajectory handed to the network is the path's own displacement
    plus a share of the current position error that grows linearly with the look-ahead time and
    reaches the whole error ``follow_seconds`` ahead (the farthest samples then aim exactly at
    the path's ideal positions, pure pursuit). For a character that tracks its future trajectory
    this is a proportional controller on position with time constant ``follow_seconds``: the
    error decays like ``exp(-t / follow_seconds)`` without overshoot
    (``tests/test_path_following.py`` checks this on unicycle and point models). ``None`` or 0:
    no correction (the open-loop behaviour)."""
    if follow_seconds is None or follow_seconds == 0:
        return np.zeros(FUTURE_SAMPLES)
    if not np.isfinite(follow_seconds) or follow_seconds < 0:
        raise ValueError(f"follow_seconds must be positive (or None for open loop), got {follow_seconds}")
    return np.minimum(1.0, SPACING * np.arange(FUTURE_SAMPLES) / 60.0 / follow_seconds)


def steer(origin_2: jax.Array, control) -> tuple[jax.Array, jax.Array, jax.Array]:
    """One frame's ``(offsets (6, 2), yaw (6,), stand ())`` for a character whose origin is
    ``origin_2``: ``control`` is one row of :class:`Controls` (``(offsets, yaw)`` or all five
    fields); with a target, each sample ``k`` adds ``gain[k]`` times the position error.
    ``stand`` is 0 (walking) when the row has none."""
    offsets, yaw = control[0], control[1]
    stand = control[4] if len(control) > 4 and control[4] is not None else jnp.zeros((), offsets.dtype)
    if len(control) >= 4 and control[2] is not None:
        offsets = offsets + control[3][:, None] * (control[2] - origin_2)[None]
    return offsets, yaw, stand


STAND_LOOKAHEAD = 10
"""Frames ahead over which :func:`stand_amount` averages the user's standing (1/6 s at 60 fps)."""


def stand_amount(velocity_Tx2, fps: float = 60.0, *, relative: float = 0.1) -> np.ndarray:
    """``(T,)`` in ``[0, 1]``: the share of the next :data:`STAND_LOOKAHEAD` frames (scaled to ``fps``)
    in which the user's path stands still (speed below ``relative`` times the path's top speed;
    a path that never moves stands throughout). The PFNN demo's ``gait_stand`` input (Holden et
    al. 2017), which the 2018 feature layout has no gait inputs for, so it is read off the path."""
    v = np.asarray(velocity_Tx2, dtype=np.float64)
    speed = np.linalg.norm(v, axis=1)
    top = speed.max() if len(speed) else 0.0
    still = (speed <= relative * top).astype(np.float64)
    n = max(int(round(STAND_LOOKAHEAD * fps / 60.0)), 1)
    padded = np.concatenate([still, np.repeat(still[-1:], n)])
    c = np.concatenate([[0.0], np.cumsum(padded)])
    return (c[n:n + len(v)] - c[:len(v)]) / n


def stand_damping(stand) -> tuple[jax.Array, jax.Array]:
    """``(move, phase_scale)`` for a standing amount ``stand`` in ``[0, 1]`` (:func:`stand_amount`),
    as the PFNN demo applies its ``gait_stand`` (Holden et al. 2017's runtime, reused by Mason et
    al. 2018): the root's translation and turn are scaled by ``move = (1 - stand) ** 0.25`` and the
    phase advance by ``phase_scale = 0.1 + 0.9 move``. Both controllers use it
    (:func:`jaxstyle.control.controller.advance`, :func:`jaxstyle.control.lpn_controller.advance`):
    networks whose training data have few clean stops drift on at a few cm/s after a stop command
    otherwise. ``stand = 0``: ``(1, 1)``, nothing damped."""
    move = jnp.power(jnp.clip(1.0 - jnp.asarray(stand, jnp.float32), 0.0, 1.0), 0.25)
    return move, 0.1 + 0.9 * move


def rotate_xz(x, z, a):
    """Ground vectors ``(x, z)`` rotated by yaw ``a`` (the convention of
    :func:`jaxstyle.motion.character_frame.rotate_yaw`)."""
    c, s = jnp.cos(a), jnp.sin(a)
    return x * c + z * s, -x * s + z * c


def path_controls(velocity_Tx2, yaw_T, fps: float = 60.0, *, follow_seconds: float | None = FOLLOW_SECONDS,
                  follow_gain: float = FOLLOW_GAIN) -> Controls:
    """:class:`Controls` from a desired ground velocity (units per second, global x and z) and
    facing yaw (radians) per frame. Past the last frame the last values hold. The path's ideal
    positions (the integrated velocity from the origin) are the targets of the path-following law
    with time constant ``follow_seconds`` (:func:`follow_gains`; ``None``: open loop), scaled by
    ``follow_gain`` (:data:`FOLLOW_GAIN`, for the networks; 1 for an ideal tracker)."""
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
    n = len(velocity_Tx2)
    if not np.isfinite(follow_gain) or follow_gain < 0:
        raise ValueError(f"follow_gain must be >= 0, got {follow_gain}")
    gain = np.broadcast_to(follow_gain * follow_gains(follow_seconds), (n, FUTURE_SAMPLES))
    return Controls(jnp.asarray(offsets, jnp.float32), jnp.asarray(yaw[t], jnp.float32),
                    jnp.asarray(disp[:n], jnp.float32), jnp.asarray(gain, jnp.float32),
                    jnp.asarray(stand_amount(velocity_Tx2, fps), jnp.float32))


def signal_controls(signal: PathSignal, *, follow_seconds: float | None = FOLLOW_SECONDS,
                    follow_gain: float = FOLLOW_GAIN) -> Controls:
    """:class:`Controls` of a :class:`jaxstyle.control.paths.PathSignal` (velocity and facing per
    frame), following its positions (:func:`follow_gains`, :data:`FOLLOW_GAIN`; ``None``: open loop)."""
    return path_controls(signal.velocity, signal.yaw, signal.fps, follow_seconds=follow_seconds,
                         follow_gain=follow_gain)


def turning_path(num_frames: int, speed: float, turn_rate: float, fps: float = 60.0,
                 start_yaw: float = 0.0, *, follow_seconds: float | None = FOLLOW_SECONDS) -> Controls:
    """Walk at ``speed`` (units/s) while turning at ``turn_rate`` (radians/s; 0 is a straight
    line), facing the direction of travel (followed as :func:`path_controls`)."""
    yaw = start_yaw + turn_rate * np.arange(num_frames) / fps
    velocity = speed * np.stack([np.sin(yaw), np.cos(yaw)], axis=-1)
    return path_controls(velocity, yaw, fps, follow_seconds=follow_seconds)


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


def trajectory_input(hist_xz: jax.Array, hist_yaw: jax.Array, future_4xF: jax.Array,
                     controls_t: tuple[jax.Array, jax.Array], blend_bias: float = 1.5) -> jax.Array:
    """The 48 trajectory inputs shared by the PFNN and the LPN layouts: x (12) | z (12) | direction
    x (12) | z (12) at offsets -60 .. 50, in the current frame. Past samples come from the
    character's own ground frames ``hist_xz (61, 2)``/``hist_yaw (61,)``; future samples are the
    previous prediction ``future (4, 6)`` blended with the user's path at this frame
    (``(offsets (6, 2), yaw (6,), ...)``, a row of :class:`Controls` after :func:`steer`)."""
    offsets, user_yaw = controls_t[0], controls_t[1]
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


def stack_trees(items):
    """Pytrees of the same structure stacked leaf by leaf on a new leading axis (NumPy or JAX
    leaves: the batched rollouts' states, controls and style conditionings)."""
    return jax.tree.map(lambda *v: jnp.stack([jnp.asarray(x) for x in v]), *items)


def normaliser_arrays(norm: Normaliser | tuple) -> tuple[jax.Array, jax.Array]:
    """``(mean, std)`` as float32 arrays, from a :class:`Normaliser` or a ``(mean, std)`` pair."""
    mean, std = (norm.mean, norm.std) if isinstance(norm, Normaliser) else norm
    return jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32)


def scan_frames(step: Step, style, state, controls: Controls):
    """Run ``step(style, state, control)`` over the ``T`` rows of ``controls`` (``lax.scan``); the
    generated frames, stacked over ``T``. Call it inside ``jit``. ``state`` is any carry with the
    ground history ``hist_xz`` of both controllers' states: each frame's control is steered from
    the character's current origin toward the path (:func:`steer`) before ``step`` sees it."""
    rows = tuple(controls)
    _, frames = jax.lax.scan(lambda s, c: step(style, s, steer(s.hist_xz[-1], c)), state, rows)
    return frames


def scan_characters(step: Step, styles, states, controls: Controls, *, shared_style: bool = False):
    """:func:`scan_frames` for ``C`` characters: ``states`` and ``controls`` stacked on a leading
    axis; ``styles`` too, or one style for all with ``shared_style`` (broadcast, e.g. ``None`` for
    the PFNN base). Whatever ``step`` closes over (the network's weights) is shared."""
    style_axis = None if shared_style else 0
    return jax.vmap(lambda st, s, c: scan_frames(step, st, s, c), in_axes=(style_axis, 0, 0))(styles, states, controls)


def live_step(step: Step, default_style):
    """A jitted ``f(state, control, style=default_style) -> (state, frame)`` for ONE frame, the
    runtime's call per displayed frame when a user steers live (``control`` is one row of
    :class:`Controls`: ``(offsets, yaw)``, or all its fields to follow a path). ``step`` closes
    over the weights, which are compiled in as constants, as a
    game runtime loads them once; the style stays an argument so it can be switched or blended live."""
    jitted = jax.jit(lambda state, control, style: step(style, state, steer(state.hist_xz[-1], tuple(control))))
    return lambda state, control, style=default_style: jitted(state, control, style)
