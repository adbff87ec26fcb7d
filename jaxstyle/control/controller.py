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
  position moved on by the predicted velocity ``V``, ``s =``
  :data:`jaxstyle.control.loop.JOINT_SMOOTH`. Where the two predictions disagree the carried pose
  is their average, which damps the autoregressive loop through the joint inputs: fed its raw
  predicted positions (``s = 1``), the paper-size base of ``experiments/quality.py`` diverges in
  its Chicken style when it stands at a waypoint (the head rises and drifts metres behind the body
  within half a second).

The root then moves by the predicted velocity and turn, the phase advances by the predicted
(non-negative) change. Everything is in file units; the user's path is given as a ground
velocity and a facing direction per frame (:func:`jaxstyle.control.loop.path_controls`), relative
to where the character stands, so the loop is closed: the user steers, the character follows.

:class:`PFNNModel` is this step as a :class:`jaxstyle.control.model.CharacterModel` (a character's
style conditioning is its residual adapter): :func:`jaxstyle.control.model.rollout` drives one
character, :func:`jaxstyle.control.model.rollout_batch` many (the base parameters broadcast).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxstyle.control import loop
from jaxstyle.control.loop import f32, initial_ground, normaliser_arrays, rotate_xz, trajectory_input
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import FUTURE_SAMPLES, PFNNLayout, decode_pfnn, output_contacts
from jaxstyle.nn import pfnn


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

    def decode(self, skeleton):
        """The :class:`jaxstyle.Motion` of one character's frames on ``skeleton``
        (:func:`jaxstyle.data.pfnn_features.decode_pfnn` of the outputs)."""
        return decode_pfnn(np.asarray(self.outputs, dtype=np.float64), skeleton)[0]

    def predicted_contacts(self, num_joints: int) -> np.ndarray | None:
        """The heel and toe labels ``(T, 4)`` of a PFNN with the 2018 layout's contact outputs
        (:func:`jaxstyle.data.pfnn_features.output_contacts`), ``None`` for the paper's layout."""
        return output_contacts(np.asarray(self.outputs), num_joints)

    def arrays(self) -> dict:
        """What :func:`jaxstyle.output.export.save_rollout` saves: the fields, the phase as ``phase``."""
        return {"positions": self.positions, "origin": self.origin, "yaw": self.yaw, "outputs": self.outputs,
                "phase": self.phase}


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
    the user's path at this frame (``(offsets (6, 2), yaw (6,))``, one row of
    :class:`jaxstyle.control.loop.Controls`)."""
    traj = trajectory_input(state.hist_xz, state.hist_yaw, state.future, controls_t, blend_bias)
    return jnp.concatenate([traj, state.joint_pos, state.joint_vel])


def advance(state: RolloutState, y: jax.Array, num_joints: int, stand=0.0, joint_smooth=loop.JOINT_SMOOTH
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


@struct.dataclass
class PFNNModel:
    """The 2018 PFNN with per-style residual adapters as a :class:`jaxstyle.control.model.CharacterModel`
    (Mason et al. 2018 section 7.1 on Holden et al. 2017's runtime): ``params`` the base network,
    ``x_norm``/``y_norm`` its ``(mean, std)`` statistics as float32 arrays (:meth:`create`), the
    style conditioning of a character its adapter (``None``: the base alone).

    ``table=True``: ``params`` and the adapters are :func:`jaxstyle.nn.pfnn.discretise` tables (the
    paper's runtime, 50 phase bins: one weight matrix per layer is read per frame). Use it for one
    character; for a batch use the continuous phase (the default), which blends the four control
    points' layer outputs instead of gathering a matrix per character."""

    params: dict
    x_norm: tuple
    y_norm: tuple
    num_joints: int = struct.field(pytree_node=False)
    blend_bias: float = struct.field(pytree_node=False, default=1.5)
    table: bool = struct.field(pytree_node=False, default=False)

    @classmethod
    def create(cls, params: dict, normalisers: tuple[Normaliser, Normaliser], num_joints: int, *,
               blend_bias: float = 1.5, table: bool = False) -> PFNNModel:
        """The model of a base ``params`` and its (input, output) :class:`Normaliser` s (or
        ``(mean, std)`` pairs) for a skeleton of ``num_joints``."""
        x_norm, y_norm = normalisers
        return cls(params, normaliser_arrays(x_norm), normaliser_arrays(y_norm), int(num_joints),
                   float(blend_bias), bool(table))

    def step(self, adapter, state: RolloutState, control) -> tuple[RolloutState, Rollout]:
        """One frame: :func:`assemble_input`, the PFNN at the carried phase with ``adapter``, then
        :func:`advance`."""
        x_n = ((assemble_input(state, control, self.blend_bias) - self.x_norm[0]) / self.x_norm[1])[None]
        if self.table:
            y_n = pfnn.pfnn_apply_table(self.params, x_n, state.phase, adapter_table=adapter)[0]
        else:
            y_n = pfnn.pfnn_apply(self.params, x_n, state.phase[None], adapter=adapter)[0]
        stand = control[2] if len(control) > 2 else 0.0
        return advance(state, y_n * self.y_norm[1] + self.y_norm[0], self.num_joints, stand)

    def initial_state(self, dataset, row: int, adapter=None) -> RolloutState:
        """:func:`initial_state` at PFNN ``row`` of ``dataset`` with that row's phase."""
        return initial_state(dataset.inputs[row], float(dataset.phases[row, 0]), self.num_joints)

    @staticmethod
    def own_speed(dataset, rows: np.ndarray, units_per_meter: float, fps: float = 60.0) -> float:
        """The median ground speed (m/s) over PFNN ``rows`` (their per-frame root motion)."""
        step = dataset.outputs[rows, :2]  # root velocity, units per frame, in the character frame
        return float(np.median(np.linalg.norm(step, axis=1)) * fps / units_per_meter)

    def stack_styles(self, adapters):
        """Adapters stacked per character (:func:`jaxstyle.nn.pfnn.stack_adapters`: CP adapters of
        different ranks padded to the largest, which changes nothing they compute)."""
        return pfnn.stack_adapters(list(adapters))

    def blend_styles(self, adapters, weights) -> dict:
        """The blend of adapters with ``weights`` (:func:`jaxstyle.nn.pfnn.blend_adapters`: exact
        for CP adapters, whose ranks add)."""
        return pfnn.blend_adapters(pfnn.stack_adapters(list(adapters)), np.asarray(weights, dtype=np.float64))
