"""The 2018 PFNN input/output layout (Mason et al. 2018 section 5.1, after Holden et al. 2017).

For a frame ``t`` of a clip, with ``J`` joints and the character frame ``C_t``
(:mod:`jaxstyle.motion.character_frame`), the input ``X_t`` (``48 + 6 J``; 234 for the 31-joint CMU
skeleton) is::

    trajectory x (12) | trajectory z (12) | direction x (12) | direction z (12)   samples t-60 .. t+50, every 10
    joint positions (3 J) | joint velocities (3 J)                                 frame t, in C_t

and the output ``Y_t`` (``28 + 12 J``; 400 for 31 joints) describes frame ``t + 1``::

    root velocity x, z | root angular velocity | phase change                     C_t -> C_{t+1}, in C_t
    trajectory x (6) | trajectory z (6) | direction x (6) | direction z (6)       samples t+1 .. t+51, in C_{t+1}
    joint positions | velocities | rotation forward (+Z) | rotation up (+Y) vectors  (3 J each), frame t+1, in C_{t+1}

Optionally (``PFNNLayout(J, contacts=True)``, not in the paper) the output also carries four
foot contact labels of frame ``t + 1`` at its end, ``heel L, heel R, toe L, toe R`` (the ankle and
toe joints of :class:`jaxstyle.FootJoints`, labelled by :func:`jaxstyle.foot_contacts`, 2022
section 4.1.2), so the network predicts its own contacts for the foot IK as the 2022 networks do;
every other slice is unchanged, so the default layout (and caches of it) reads as before.

Trajectory samples are the character frame origins and facing directions. Velocities are per
frame (the difference to the previous frame), as in the reference code. The sample spacing is
10 frames at 60 fps, i.e. 1/6 s; at other frame rates it is scaled to stay 1/6 s. A frame has
features only when its whole trajectory window lies inside the clip: frames
``[6 s, T - 5 s - 1)`` with ``s`` the spacing.

:func:`decode_pfnn` turns a sequence of outputs back into a :class:`Motion` by integrating the
root motion and converting forward/up vectors to rotations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxstyle.errors import MotionDataError
from jaxstyle.labels.contacts import foot_contacts
from jaxstyle.motion import Motion, kinematics, quat
from jaxstyle.motion.character_frame import (
    CharacterFrames,
    character_frames,
    directions_to_local,
    from_local,
    rotate_yaw,
    rotations_from_local,
    rotations_to_local,
    to_local,
    trajectory_features,
    wrap_angle,
)

PAST_SAMPLES = 6
FUTURE_SAMPLES = 6  # including the current one: t, t+10, ..., t+50
SAMPLE_SECONDS = 10.0 / 60.0
NUM_CONTACTS = 4  # heel L, heel R, toe L, toe R


@dataclass(frozen=True)
class PFNNLayout:
    """Sizes and slices of the PFNN vectors for a skeleton with ``num_joints`` joints.

    ``input_groups`` / ``output_groups`` map a feature group name to its slice; normalisation
    shares one standard deviation within each group, as the reference code does.
    """

    num_joints: int
    contacts: bool = False

    @classmethod
    def from_output_size(cls, num_joints: int, output_size: int) -> "PFNNLayout":
        """The layout of ``num_joints`` whose outputs have ``output_size`` values (with or without
        the contact labels); a clear error for any other size."""
        for contacts in (False, True):
            layout = cls(num_joints, contacts)
            if layout.output_size == output_size:
                return layout
        raise ValueError(f"{output_size} outputs fit no PFNN layout of {num_joints} joints "
                         f"({cls(num_joints).output_size}, or {cls(num_joints, True).output_size} with contacts)")

    @property
    def input_size(self) -> int:
        return 4 * (PAST_SAMPLES + FUTURE_SAMPLES) + 6 * self.num_joints

    @property
    def output_size(self) -> int:
        return 4 + 4 * FUTURE_SAMPLES + 12 * self.num_joints + (NUM_CONTACTS if self.contacts else 0)

    @property
    def input_groups(self) -> dict[str, slice]:
        n, j3 = PAST_SAMPLES + FUTURE_SAMPLES, 3 * self.num_joints
        return {"trajectory_position": slice(0, 2 * n), "trajectory_direction": slice(2 * n, 4 * n),
                "joint_position": slice(4 * n, 4 * n + j3), "joint_velocity": slice(4 * n + j3, 4 * n + 2 * j3)}

    @property
    def output_groups(self) -> dict[str, slice]:
        f, j3 = FUTURE_SAMPLES, 3 * self.num_joints
        o = 4 + 4 * f
        groups = {"root_velocity": slice(0, 2), "root_angular_velocity": slice(2, 3), "phase_change": slice(3, 4),
                  "trajectory_position": slice(4, 4 + 2 * f), "trajectory_direction": slice(4 + 2 * f, o),
                  "joint_position": slice(o, o + j3), "joint_velocity": slice(o + j3, o + 2 * j3),
                  "joint_forward": slice(o + 2 * j3, o + 3 * j3), "joint_up": slice(o + 3 * j3, o + 4 * j3)}
        if self.contacts:
            groups["foot_contact"] = slice(o + 4 * j3, o + 4 * j3 + NUM_CONTACTS)
        return groups


def contact_labels(motion: Motion) -> np.ndarray:
    """``(T, 4)`` float foot contact labels ``heel L, heel R, toe L, toe R`` of a clip
    (:func:`jaxstyle.foot_contacts`, 2022 section 4.1.2), the optional outputs of the layout."""
    c = foot_contacts(motion)
    return np.concatenate([c.heel, c.toe], axis=1).astype(np.float64)


def sample_step(fps: float) -> int:
    """Frames between trajectory samples: 10 at 60 fps."""
    return max(int(round(SAMPLE_SECONDS * fps)), 1)


def valid_frames(num_frames: int, fps: float) -> np.ndarray:
    """Frames ``t`` whose input and output windows (``t - 6 s`` .. ``t + 1 + 5 s``) lie in the clip."""
    s = sample_step(fps)
    return np.arange(PAST_SAMPLES * s, num_frames - (FUTURE_SAMPLES - 1) * s - 1)


def encode_pfnn(motion: Motion, phase: np.ndarray, *, frames: CharacterFrames | None = None,
                contacts: np.ndarray | bool | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(X, Y, t)``: PFNN inputs ``(N, 48 + 6J)``, outputs ``(N, 28 + 12J)`` and their frames ``(N,)``.

    Args:
      motion: a clip (any skeleton; 60 fps gives the paper's 10-frame sample spacing).
      phase: ``(T,)`` global phase in cycles (e.g. :func:`jaxstyle.labels.phase.global_phase`).
      frames: character frames, computed with :func:`character_frames` when omitted.
      contacts: ``(T, 4)`` foot contact labels to append to the outputs (the layout's
        ``contacts=True`` option), or ``True`` to label them with :func:`contact_labels`.
    """
    phase = np.asarray(phase, dtype=np.float64)
    if phase.shape != (motion.num_frames,):
        raise ValueError(f"phase must have shape ({motion.num_frames},), got {phase.shape}")
    t = valid_frames(motion.num_frames, motion.fps)
    s = sample_step(motion.fps)
    if len(t) == 0:
        need = (PAST_SAMPLES + FUTURE_SAMPLES - 1) * s + 2
        raise MotionDataError(f"clip has {motion.num_frames} frames; the PFNN trajectory window needs at least {need}",
                              motion.source)
    g_rot, g_pos = kinematics.global_transforms(motion)
    frames = frames or character_frames(motion, positions_TxJx3=g_pos)
    n = len(t)
    t1 = t + 1

    past_future = np.arange(-PAST_SAMPLES, FUTURE_SAMPLES) * s
    pos_t = to_local(g_pos[t], frames, t).reshape(n, -1)
    vel_t = directions_to_local(g_pos[t] - g_pos[t - 1], frames, t).reshape(n, -1)
    x = np.concatenate([trajectory_features(frames, t, past_future), pos_t, vel_t], axis=1)

    root_vel = directions_to_local((frames.origin[t1] - frames.origin[t])[:, None], frames, t)[:, 0]
    ang_vel = wrap_angle(frames.yaw[t1] - frames.yaw[t])
    dphase = np.mod(phase[t1] - phase[t], 1.0)
    future = trajectory_features(frames, t1, np.arange(FUTURE_SAMPLES) * s)
    pos_1 = to_local(g_pos[t1], frames, t1).reshape(n, -1)
    vel_1 = directions_to_local(g_pos[t1] - g_pos[t], frames, t1).reshape(n, -1)
    rot_1 = rotations_to_local(g_rot[t1], frames, t1)
    y = np.concatenate([root_vel[:, [0, 2]], ang_vel[:, None], dphase[:, None], future, pos_1, vel_1,
                        quat.forward(rot_1).reshape(n, -1), quat.up(rot_1).reshape(n, -1)], axis=1)
    if contacts is not None and contacts is not False:
        labels = contact_labels(motion) if contacts is True else np.asarray(contacts, dtype=np.float64)
        if labels.shape != (motion.num_frames, NUM_CONTACTS):
            raise ValueError(f"contacts must have shape ({motion.num_frames}, {NUM_CONTACTS}), got {labels.shape}")
        y = np.concatenate([y, labels[t1]], axis=1)
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise MotionDataError("PFNN features contain NaN or infinity", motion.source)
    return x, y, t


def decode_pfnn(outputs: np.ndarray, skeleton: Motion, *, origin: np.ndarray | None = None, yaw: float = 0.0,
                phase: float = 0.0) -> tuple[Motion, np.ndarray]:
    """A :class:`Motion` (and its ``(N,)`` phase) from a sequence of PFNN outputs ``(N, 28 + 12J)``
    (or ``(N, 32 + 12J)`` with the contact labels, which the motion does not need: see
    :func:`output_contacts`).

    Output ``i`` describes frame ``i + 1`` relative to frame ``i``; the character starts at ground
    position ``origin`` with heading ``yaw`` (frame 0, which has no output, is not returned).
    Joint rotations come from the forward/up vectors; the root joint's position from the
    predicted joint positions; other joints keep the skeleton's offsets.
    """
    y = np.asarray(outputs, dtype=np.float64)
    num_joints = skeleton.num_joints
    layout = PFNNLayout(num_joints)
    if y.ndim != 2 or y.shape[1] not in (layout.output_size, PFNNLayout(num_joints, True).output_size):
        raise ValueError(f"outputs must have shape (N, {layout.output_size}) for {num_joints} joints "
                         f"(or {PFNNLayout(num_joints, True).output_size} with contacts), got {y.shape}")
    g = layout.output_groups
    n = len(y)
    root_vel = np.zeros((n, 3))
    root_vel[:, 0], root_vel[:, 2] = y[:, 0], y[:, 1]
    yaws = yaw + np.cumsum(y[:, 2])  # heading of frames 1..N
    prev_yaw = np.concatenate([[yaw], yaws[:-1]])
    steps = rotate_yaw(root_vel, prev_yaw)
    start = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64)
    origins = start + np.cumsum(steps, axis=0)
    frames = CharacterFrames(origins, yaws)
    local_pos = y[:, g["joint_position"]].reshape(n, num_joints, 3)
    g_pos = from_local(local_pos, frames)
    fwd = y[:, g["joint_forward"]].reshape(n, num_joints, 3)
    up = y[:, g["joint_up"]].reshape(n, num_joints, 3)
    g_rot = rotations_from_local(fwd, up, frames)
    phases = np.mod(phase + np.cumsum(y[:, 3]), 1.0)
    return kinematics.motion_from_global(skeleton, g_rot, g_pos[:, skeleton.parents < 0]), phases



def contact_columns(num_joints: int, output_size: int) -> np.ndarray | None:
    """The columns of the heel and toe contact outputs (heel L, heel R, toe L, toe R) among
    ``output_size`` PFNN outputs of the layout's contact option, ``None`` for the paper's layout."""
    layout = PFNNLayout.from_output_size(num_joints, output_size)
    return np.arange(output_size)[layout.output_groups["foot_contact"]] if layout.contacts else None


def output_contacts(outputs: np.ndarray, num_joints: int) -> np.ndarray | None:
    """``(N, 4)`` predicted contact labels (heel L, heel R, toe L, toe R) of PFNN outputs with the
    layout's contact option, ``None`` for the paper's layout."""
    y = np.asarray(outputs)
    columns = contact_columns(num_joints, y.shape[-1])
    return None if columns is None else y[..., columns]
