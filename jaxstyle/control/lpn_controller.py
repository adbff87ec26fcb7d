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
  2020's runtime blends the two estimates the same way, which keeps the phases from drifting;
  :func:`feed_back`), then each limb's advance is floored at the character's ``phase_floor``
  (:func:`jaxstyle.control.lpn_phases.floored_phases`: by default 0.75 of its style's capture
  rate, so the loop cannot settle on a still pose; 0 is the paper's runtime);
* the global phase ``phi`` (cycles), the expert blend of Table 2's PFNN-backbone models (PFNN
  One-hot, PFNN Resad, PFNN FiLM: the network is evaluated at ``phi``), advances by the local
  phases' predicted advance times the style's ratio (:mod:`jaxstyle.control.lpn_phases`); the LPN
  and MANN backbones carry it too but do not read it;
* bone positions: the PFNN demo's and Starke et al.'s blend of the predicted positions with the
  current ones moved on by the predicted velocities (:data:`jaxstyle.control.loop.JOINT_SMOOTH`),
  as in the 2018 controller;
* standing: the user's standing amount (:func:`jaxstyle.control.loop.stand_damping`, the PFNN
  demo's ``gait_stand``) damps the root's translation and turn and the phases' advance exactly as
  in the 2018 controller (:func:`jaxstyle.control.controller.advance`); with ``stand = 0`` (no
  stand in the controls) nothing changes.

:class:`StyleNetModel` is this step as a :class:`jaxstyle.control.model.CharacterModel` (a
character's style conditioning is its runtime style): :func:`jaxstyle.control.model.rollout` drives
one character, :func:`jaxstyle.control.model.rollout_batch` ``C`` characters (states, controls and
styles stacked on a leading axis), sharing the network parameters.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxstyle.control import loop
from jaxstyle.control.loop import f32, initial_ground, normaliser_arrays, rotate_xz, trajectory_input
from jaxstyle.control.lpn_phases import (
    capture_phase_amplitude,
    capture_phase_rate,
    check_gate_columns,
    floored_amplitudes,
    floored_phases,
    gate_input,
    phase_ratio,
    predicted_advance,
)
from jaxstyle.data.datasets import style_rows
from jaxstyle.data.lpn_features import NUM_PHASE_FEATURES, LPNLayout, decode_lpn, end_effector_columns, foot_bones
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import FUTURE_SAMPLES
from jaxstyle.nn import style_models
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.train.defaults import PHASE_FLOOR


class LPNState(NamedTuple):
    """What the loop carries: ground frames of the last 61 frames ``hist_xz (61, 2)``, ``hist_yaw
    (61,)`` (global; the last is the current frame), the local ``phases (8,)``, the joint features
    ``joints (12 B,)`` of the current frame in its own ground frame, the predicted future
    trajectory ``future (4, 6)`` (x, z, direction x, z at offsets 0 .. 50) in the current frame,
    the ``global_phase ()`` in cycles, ``[0, 1)`` (the PFNN backbone's expert blend), and
    ``phase_ratio ()``, the style's ratio of global to local phase advance
    (:func:`jaxstyle.control.lpn_phases.global_phase_ratio`; constant over a rollout), and
    ``phase_floor ()``, the least advance of each limb's local phase per frame, in cycles
    (:func:`jaxstyle.control.lpn_phases.floored_phases`; 0: none, the paper's runtime), and
    ``amplitude_floor (4,)``, the least amplitude of each limb's local phase
    (:func:`jaxstyle.control.lpn_phases.floored_amplitudes`; 0: none, the paper's runtime)."""

    hist_xz: jax.Array
    hist_yaw: jax.Array
    phases: jax.Array
    joints: jax.Array
    future: jax.Array
    global_phase: jax.Array
    phase_ratio: jax.Array
    phase_floor: jax.Array = np.float32(0.0)
    amplitude_floor: jax.Array = np.zeros(NUM_PHASE_FEATURES // 2, np.float32)


class LPNRollout(NamedTuple):
    """Per generated frame: global ``positions (T, B, 3)`` of the LPN bones (the skeleton's joints
    first, then the hand end sites), ground ``origin (T, 2)`` (x, z), ``yaw (T,)``, local
    ``phases (T, 8)``, predicted foot ``contacts (T, 2)`` (left, right; the foot IK's input), the
    de-normalised network ``outputs (T, O)`` as applied (:func:`jaxstyle.decode_lpn` makes a Motion
    of them; the root motion and the poses damped by standing, see :func:`damp_output`) and the
    ``global_phase (T,)`` after each frame."""

    positions: jax.Array
    origin: jax.Array
    yaw: jax.Array
    phases: jax.Array
    contacts: jax.Array
    outputs: jax.Array
    global_phase: jax.Array

    def decode(self, skeleton):
        """The :class:`jaxstyle.Motion` of one character's frames on ``skeleton``
        (:func:`jaxstyle.data.lpn_features.decode_lpn` of the outputs)."""
        return decode_lpn(np.asarray(self.outputs, dtype=np.float64), skeleton)

    def predicted_contacts(self, num_joints: int) -> np.ndarray:
        """The network's two foot contact labels ``(T, 2)`` (left, right)."""
        return np.asarray(self.contacts, dtype=np.float64)

    def arrays(self) -> dict:
        """What :func:`jaxstyle.output.export.save_rollout` saves: the fields, the local phases as
        ``phase``."""
        return {"positions": self.positions, "origin": self.origin, "yaw": self.yaw, "outputs": self.outputs,
                "phase": self.phases, "contacts": self.contacts}


def initial_state(x_row: np.ndarray, phases_row: np.ndarray, num_bones: int, global_phase: float = 0.0,
                  phase_ratio: float = 1.0, phase_floor: float = 0.0, amplitude_floor=None) -> LPNState:
    """The loop's start from one de-normalised LPN input row, its local phases and its global phase
    (cycles; e.g. a frame of real data: ``dataset.global_phase[row]``), with the style's
    ``phase_ratio`` (:func:`jaxstyle.control.lpn_phases.global_phase_ratio`) and ``phase_floor``
    (cycles per frame, :func:`jaxstyle.control.lpn_phases.floored_phases`; 0: the paper's runtime)
    and ``amplitude_floor`` (``(4,)`` per limb, :func:`jaxstyle.control.lpn_phases.floored_amplitudes`;
    ``None``: none, the paper's runtime): the character stands at the global origin facing +Z with
    that row's pose."""
    layout = LPNLayout(num_bones)
    x = np.asarray(x_row, dtype=np.float64)
    p = np.asarray(phases_row, dtype=np.float64)
    if x.shape != (layout.input_size,):
        raise ValueError(f"x_row must have shape ({layout.input_size},) for {num_bones} bones, got {x.shape}")
    if p.shape != (NUM_PHASE_FEATURES,):
        raise ValueError(f"phases_row must have shape ({NUM_PHASE_FEATURES},), got {p.shape}")
    if not (np.isfinite(x).all() and np.isfinite(p).all() and np.isfinite(global_phase)
            and np.isfinite(phase_ratio) and np.isfinite(phase_floor)):
        raise ValueError("x_row, phases_row, global_phase, phase_ratio and phase_floor must be finite")
    if phase_ratio < 0 or phase_floor < 0:
        raise ValueError(f"phase_ratio and phase_floor must be non-negative, got {phase_ratio}, {phase_floor}")
    amp = np.zeros(NUM_PHASE_FEATURES // 2) if amplitude_floor is None else np.asarray(amplitude_floor, np.float64)
    if amp.shape != (NUM_PHASE_FEATURES // 2,) or not (np.isfinite(amp).all() and (amp >= 0).all()):
        raise ValueError(f"amplitude_floor must be {NUM_PHASE_FEATURES // 2} finite non-negative amplitudes, "
                         f"got {amplitude_floor}")
    hist_xz, hist_yaw, future = initial_ground(x, layout.input_groups)
    joints = x[layout.input_groups["joint_position"].start:]
    return LPNState(hist_xz, hist_yaw, f32(p), f32(joints), future, f32(np.mod(float(global_phase), 1.0)),
                    f32(phase_ratio), f32(phase_floor), f32(amp))


def _yaw_rotate(v_Nx3: jax.Array, a) -> jax.Array:
    x, z = rotate_xz(v_Nx3[:, 0], v_Nx3[:, 2], a)
    return jnp.stack([x, v_Nx3[:, 1], z], axis=-1)


def damp_output(y: jax.Array, move, num_bones: int) -> jax.Array:
    """The de-normalised output ``y`` with its root motion scaled by ``move`` in ``[0, 1]``
    (:func:`jaxstyle.control.loop.stand_damping`): the next ground frame ``C_{t+1}`` moves ``move``
    times the predicted step and turns ``move`` times the predicted turn, and everything the row
    gives in ``C_t`` (trajectory, joint positions; directions rotated only) moves rigidly with it,
    so the body stays on the damped root, as the 2018 controller's poses (given in ``C_{t+1}``) do.
    ``move = 1`` returns ``y`` unchanged (to rounding)."""
    g = LPNLayout(num_bones).output_groups
    f = FUTURE_SAMPLES
    tx, tz, tdx, tdz = y[g["trajectory_position"].start:g["trajectory_direction"].stop].reshape(4, f)
    turn = jnp.arctan2(tdx[0], tdz[0])
    delta = (move - 1.0) * turn  # applied turn minus predicted turn (rotate_xz by a adds a to atan2(x, z))
    sx, sz = tx[0], tz[0]

    def point(px, pz):  # C_t coordinates of a point fixed in the predicted C_{t+1}, in the damped one
        qx, qz = rotate_xz(px - sx, pz - sz, delta)
        return qx + move * sx, qz + move * sz

    ptx, ptz = point(tx, tz)
    dtx, dtz = rotate_xz(tdx, tdz, delta)
    feats = y[g["joint_position"].start:g["joint_up"].stop].reshape(4, num_bones, 3)
    jx, jz = point(feats[0, :, 0], feats[0, :, 2])
    pos = jnp.stack([jx, feats[0, :, 1], jz], axis=-1)
    joints = jnp.stack([pos] + [_yaw_rotate(v, delta) for v in feats[1:]])
    return jnp.concatenate([ptx, ptz, dtx, dtz, joints.reshape(-1), y[g["joint_up"].stop:]])


def feed_back(joints: jax.Array, phases: jax.Array, y: jax.Array, num_bones: int, joint_smooth=loop.JOINT_SMOOTH
              ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """What the next frame's input reads of the de-normalised output ``y`` given the current
    joint features ``joints (12 B,)`` (in ``C_t``) and local ``phases (8,)``: returns ``y`` with the
    smoothed bone positions (``joint_smooth``, see :func:`advance`), the next joint features
    ``(12 B,)`` re-expressed in ``C_{t+1}`` (the ground frame the output's first trajectory sample
    gives) and the blended local phases ``(P~_{t+1} + P_t + dP) / 2``. The runtime
    (:func:`advance`) and rollout training (:func:`jaxstyle.mason2022.loss.rollout_loss`, under
    ``vmap``) share it, so training feeds the network exactly what the closed loop will."""
    g = LPNLayout(num_bones).output_groups
    s = jnp.asarray(joint_smooth, y.dtype)
    now = joints.reshape(4, num_bones, 3)
    predicted = y[g["joint_position"]].reshape(num_bones, 3)
    moved_on = now[0] + y[g["joint_velocity"]].reshape(num_bones, 3)
    y = y.at[g["joint_position"]].set((s * predicted + (1.0 - s) * moved_on).reshape(-1))
    tx, tz, tdx, tdz = y[g["trajectory_position"].start:g["trajectory_direction"].stop].reshape(4, FUTURE_SAMPLES)
    turn = jnp.arctan2(tdx[0], tdz[0])
    feats = y[g["joint_position"].start:g["joint_up"].stop].reshape(4, num_bones, 3)  # pos, vel, fwd, up in C_t
    shift = jnp.stack([tx[0], jnp.zeros_like(tx[0]), tz[0]])
    next_feats = jnp.stack([_yaw_rotate(feats[0] - shift, -turn)] + [_yaw_rotate(v, -turn) for v in feats[1:]])
    blended = 0.5 * (y[g["local_phase"]] + phases + y[g["local_phase_update"]])
    return y, next_feats.reshape(-1), blended


def advance(state: LPNState, y: jax.Array, num_bones: int, stand=0.0, joint_smooth=loop.JOINT_SMOOTH
            ) -> tuple[LPNState, LPNRollout]:
    """Move the character by one de-normalised output ``y (24 + 12 B + 18,)``: the next state and
    the generated frame (see the module docstring). ``stand`` in ``[0, 1]``: how much the user asks
    to stand still (:func:`jaxstyle.control.loop.stand_damping`: the root motion is scaled by
    ``m``, :func:`damp_output`, the local and global phases' advance by ``0.1 + 0.9 m``).
    ``joint_smooth``: :data:`jaxstyle.control.loop.JOINT_SMOOTH`, the carried bone positions are
    ``s P + (1 - s) (p + V)`` of the predicted positions ``P`` and the current ones ``p`` moved on
    by the predicted velocities ``V`` (both in ``C_t``); the recorded ``outputs`` hold them."""
    move, phase_scale = loop.stand_damping(stand)
    y = damp_output(y, move, num_bones)
    g = LPNLayout(num_bones).output_groups
    y, next_joints, blended = feed_back(state.joints, state.phases, y, num_bones, joint_smooth)
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
    pos = y[g["joint_position"]].reshape(num_bones, 3)  # in C_t
    gpx, gpz = rotate_xz(pos[:, 0], pos[:, 2], yaw)
    positions = jnp.stack([gpx + origin[0], pos[:, 1], gpz + origin[1]], axis=-1)
    phases = state.phases + phase_scale * (blended - state.phases)
    phases = floored_phases(state.phases, phases, phase_scale * state.phase_floor)
    phases = floored_amplitudes(phases, phase_scale * state.amplitude_floor)
    dphi = phase_scale * state.phase_ratio * jnp.maximum(predicted_advance(y, num_bones), 0.0)
    global_phase = jnp.mod(state.global_phase + dphi, 1.0)
    contacts = y[g["foot_contact"]]
    new_state = LPNState(jnp.concatenate([state.hist_xz[1:], new_origin[None]]),
                         jnp.concatenate([state.hist_yaw[1:], new_yaw[None]]), phases,
                         next_joints, jnp.stack([fx, fz, fdx, fdz]), global_phase, state.phase_ratio,
                         state.phase_floor, state.amplitude_floor)
    return new_state, LPNRollout(positions, new_origin, new_yaw, phases, contacts, y, global_phase)


@jax.jit
def partly_forced(model: StyleNetModel, style, state: LPNState, inputs_TxD: jax.Array, phases_Tx8: jax.Array,
                  capture_2: jax.Array) -> tuple[jax.Array, LPNRollout]:
    """A diagnostic loop along a captured clip: frame ``t`` reads the trajectory of the
    de-normalised input row ``inputs_TxD[t]``, and the joint features and gating local phases
    of that row and ``phases_Tx8[t]`` where ``capture_2 = (joints, phases)`` says so (booleans),
    else those the loop carries (:func:`advance`, with ``model``'s runtime). ``(True, True)`` is
    the network teacher-forced on the clip, ``(False, False)`` its closed loop driven by the
    clip's trajectory. Returns the de-normalised network outputs ``(T, O)`` (before the
    runtime's blends) and the :class:`LPNRollout`."""
    start = inputs_TxD.shape[1] - state.joints.shape[0]

    def step(st, rows):
        x_cap, p_cap = rows
        joints = jnp.where(capture_2[0], x_cap[start:], st.joints)
        phases = jnp.where(capture_2[1], p_cap, st.phases)
        x_n = ((jnp.concatenate([x_cap[:start], joints]) - model.x_norm[0]) / model.x_norm[1])[None]
        gate = gate_input(model.config, phases[None], st.global_phase[None], x_n, model.gate_columns)
        y_n = style_models.model_apply(model.params, model.config, x_n, gate, style)[0]
        y = y_n * model.y_norm[1] + model.y_norm[0]
        new, frame = advance(st._replace(joints=joints, phases=phases), y, model.num_bones, 0.0, model.joint_smooth())
        return new, (y, frame)

    return jax.lax.scan(step, state, (jnp.asarray(inputs_TxD, jnp.float32), jnp.asarray(phases_Tx8, jnp.float32)))[1]


@struct.dataclass
class StyleNetModel:
    """A 2022 style model (LPN, MANN or PFNN backbone with FiLM, one-hot or residual-adapter
    conditioning; :mod:`jaxstyle.nn.style_models`) as a
    :class:`jaxstyle.control.model.CharacterModel` (Mason, Starke & Komura 2022 section 4.4; see
    the module docstring): ``params`` and ``config`` the trained network, ``x_norm``/``y_norm`` its
    training data's ``(mean, std)`` as float32 arrays (:meth:`create`). A character's style
    conditioning is its runtime style: a precomputed FiLM vector ``(4 H,)``, a one-hot row or an
    adapter (what :func:`jaxstyle.nn.style_models.model_apply` takes). ``gate_columns``: the MANN
    backbone's gating columns of the normalised input. ``bone_smooth``: ``None`` (every bone
    :data:`jaxstyle.control.loop.JOINT_SMOOTH`) or each bone's blend weight (:meth:`create`'s
    ``foot_smooth`` on the feet and ``body_smooth`` on the other bones, :meth:`joint_smooth`)."""

    params: dict
    x_norm: tuple
    y_norm: tuple
    config: StyleModelConfig = struct.field(pytree_node=False)
    num_bones: int = struct.field(pytree_node=False)
    gate_columns: tuple | None = struct.field(pytree_node=False, default=None)
    blend_bias: float = struct.field(pytree_node=False, default=1.5)
    phase_floor: float = struct.field(pytree_node=False, default=PHASE_FLOOR)
    bone_smooth: tuple[float, ...] | None = struct.field(pytree_node=False, default=None)
    amplitude_floor: float = struct.field(pytree_node=False, default=0.0)

    @classmethod
    def create(cls, params: dict, config: StyleModelConfig, normalisers: tuple[Normaliser, Normaliser],
               skeleton=None, *, blend_bias: float = 1.5, phase_floor: float = PHASE_FLOOR,
               foot_smooth: float | None = None, amplitude_floor: float = 0.0,
               body_smooth: float | None = None) -> StyleNetModel:
        """The model of a trained ``params``/``config`` with its training data's (input, output)
        :class:`Normaliser` s (or ``(mean, std)`` pairs); ``skeleton``, a clip of the training
        skeleton, gives the MANN backbone's gating columns (the other backbones need none) and
        the feet of ``foot_smooth``.

        ``foot_smooth`` (not in the paper; ``None``: the paper's runtime, here as in a model built
        without a skeleton; the reloaded models of :class:`jaxstyle.mason2022.synthesis.Loaded` and
        the commands use :data:`jaxstyle.train.defaults.FOOT_SMOOTH`): the ankles' and toes' own
        weight ``s`` of the predicted positions in the carried ``s P + (1 - s)(p + V)``
        (:func:`advance`; the other joints carry ``body_smooth``). Why:
        given the captured frame, the velocity head predicts a planted foot's motion far better
        than the position head (docs/mason2022.md, "Feet that slide"), so a low weight lets the
        feet follow their predicted velocity.

        ``body_smooth`` (not in the paper; ``None``: :data:`jaxstyle.control.loop.JOINT_SMOOTH`,
        the paper's 0.5; the reloaded models use :data:`jaxstyle.train.defaults.BODY_SMOOTH`): the
        same weight for every other bone (every bone without ``foot_smooth``). Why: fed its own
        poses along captured Drunk clips (with the clips' trajectory and local phases), the
        paper-size network stills the pose (its ankles move a quarter to a third as much as in the
        clips) with the paper's blend; a low weight lets the body follow the predicted velocities
        (docs/mason2022.md, "Why Drunk glides").

        ``amplitude_floor`` (not in the paper; 0: none, the paper's runtime): each limb's local-phase
        amplitude is kept at least this fraction of its style's captured median
        (:meth:`amplitude_per_limb`, :func:`jaxstyle.control.lpn_phases.floored_amplitudes`)."""
        x_norm, y_norm = (normaliser_arrays(n) for n in normalisers)
        num_bones = (len(x_norm[0]) - 48) // 12
        if LPNLayout(num_bones).input_size != config.input_size:
            raise ValueError(f"the normalisers have {len(x_norm[0])} inputs, the model {config.input_size}")
        cols = end_effector_columns(skeleton) if config.backbone == "mann" and skeleton is not None else None
        if not phase_floor >= 0:
            raise ValueError(f"phase_floor must be a non-negative fraction of the capture's rate, got {phase_floor}")
        if not (amplitude_floor >= 0 and np.isfinite(amplitude_floor)):
            raise ValueError(f"amplitude_floor must be a non-negative fraction of the capture's amplitude, "
                             f"got {amplitude_floor}")
        body = loop.JOINT_SMOOTH if body_smooth is None else body_smooth
        if not 0.0 <= body <= 1.0:
            raise ValueError(f"body_smooth must be in [0, 1], got {body_smooth}")
        bone_smooth = None if body == loop.JOINT_SMOOTH else (float(body),) * int(num_bones)
        if foot_smooth is not None:
            if skeleton is None or not 0.0 <= foot_smooth <= 1.0:
                raise ValueError(f"foot_smooth must be in [0, 1] and needs the skeleton's feet, got {foot_smooth}")
            feet = set(foot_bones(skeleton)[0])
            bone_smooth = tuple(float(foot_smooth) if b in feet else float(body) for b in range(num_bones))
        return cls(params, x_norm, y_norm, config, int(num_bones), check_gate_columns(config, cols), float(blend_bias),
                   float(phase_floor), bone_smooth, float(amplitude_floor))

    def joint_smooth(self):
        """The ``joint_smooth`` of :func:`advance`: :data:`jaxstyle.control.loop.JOINT_SMOOTH`, or
        ``bone_smooth`` as a ``(B, 1)`` array."""
        if self.bone_smooth is None:
            return loop.JOINT_SMOOTH
        return np.asarray(self.bone_smooth, np.float32)[:, None]

    def step(self, style, state: LPNState, control) -> tuple[LPNState, LPNRollout]:
        """One frame: the LPN-layout input from the carried state, the network with ``style`` and
        its gate (:func:`jaxstyle.control.lpn_phases.gate_input`), then :func:`advance`."""
        x = jnp.concatenate([trajectory_input(state.hist_xz, state.hist_yaw, state.future, control, self.blend_bias),
                             state.joints])
        x_n = ((x - self.x_norm[0]) / self.x_norm[1])[None]
        gate = gate_input(self.config, state.phases[None], state.global_phase[None], x_n, self.gate_columns)
        y_n = style_models.model_apply(self.params, self.config, x_n, gate, style)[0]
        stand = control[2] if len(control) > 2 else 0.0
        return advance(state, y_n * self.y_norm[1] + self.y_norm[0], self.num_bones, stand, self.joint_smooth())

    def phase_ratio(self, style, dataset, name: str) -> float:
        """The global-phase rate a character of ``style`` (runtime style) starts with: for Table
        2's PFNN backbone :func:`jaxstyle.control.lpn_phases.phase_ratio` on the training rows of
        the dataset style ``name`` (:func:`jaxstyle.data.datasets.style_rows`); 1 for the LPN and
        MANN backbones, which do not read the global phase."""
        if self.config.backbone != "pfnn":
            return 1.0
        return float(phase_ratio(self.params, self.config, style, (self.x_norm, self.y_norm), dataset,
                                 style_rows(dataset, name), gate_columns=self.gate_columns))

    def initial_state(self, dataset, row: int, style=None) -> LPNState:
        """The start at LPN ``row`` of ``dataset``: its input, local phases and global phase, with
        the global phase's rate for ``style`` on the row's dataset style (:meth:`phase_ratio`;
        ``style=None``: rate 1). A dataset without global phases starts at phase 0, which only the
        PFNN backbone reads."""
        name = dataset.styles[int(dataset.style[row])]
        ratio = 1.0 if style is None else self.phase_ratio(style, dataset, name)
        phase = float(dataset.global_phase[row]) if len(dataset.global_phase) == len(dataset.inputs) else 0.0
        return initial_state(dataset.inputs[row], dataset.phases[row], self.num_bones, phase, ratio,
                             self.floor_per_frame(dataset, name), self.amplitude_per_limb(dataset, name))

    def amplitude_per_limb(self, dataset, name: str) -> np.ndarray:
        """``(4,)``: the least amplitude of each limb's local phase for a character of dataset style
        ``name``: ``amplitude_floor`` times the style's captured median
        (:func:`jaxstyle.control.lpn_phases.capture_phase_amplitude`); zeros without a floor."""
        if self.amplitude_floor > 0:
            return self.amplitude_floor * capture_phase_amplitude(dataset, name)
        return np.zeros(NUM_PHASE_FEATURES // 2)

    def floor_per_frame(self, dataset, name: str) -> float:
        """The least advance per frame (cycles) of each limb's local phase for a character of
        dataset style ``name``: ``phase_floor`` times the style's capture rate
        (:func:`jaxstyle.control.lpn_phases.capture_phase_rate`); 0 without a floor (the paper's runtime)."""
        return self.phase_floor * capture_phase_rate(dataset, name) if self.phase_floor > 0 else 0.0

    @staticmethod
    def own_speed(dataset, rows: np.ndarray, units_per_meter: float, fps: float = 60.0) -> float:
        """The median ground speed (m/s) over LPN ``rows``: the first output trajectory sample is
        the next frame's ground position in the current frame (:mod:`jaxstyle.data.lpn_features`)."""
        y = dataset.outputs[rows]
        return float(np.median(np.hypot(y[:, 0], y[:, FUTURE_SAMPLES])) * fps / units_per_meter)

    def stack_styles(self, styles):
        """Runtime styles stacked per character (one kind and shape, :func:`jaxstyle.control.loop.stack_trees`)."""
        return loop.stack_trees(styles)

    def blend_styles(self, styles, weights):
        """The blend of runtime styles with barycentric ``weights`` (section 4.4:
        :func:`jaxstyle.nn.style_models.blend_styles`, for FiLM the weighted sum of the FiLM
        vectors). Weights ``(1, 0, ...)`` give the first style exactly."""
        return style_models.blend_styles(self.config, self.stack_styles(styles), jnp.asarray(weights, jnp.float32))
