"""The 2022 LPN input/output layout and style clips (Mason, Starke & Komura 2022, section 3.2).

Bones: the 100STYLE skeleton's 23 joints plus the two wrist end sites (the hands): 25, as the
paper's "25 joints ... excluding the toes and top of head joint in the original motion data" (the
toe and head end sites are left out; the paper's figure is not precise enough to tell whether it
meant the toe joints or the toe end sites; jaxstyle keeps the toe joints, which carry the foot
contacts). An end site takes its parent's rotation. Other skeletons: all joints plus their hand
end sites.

For frame ``t`` in the character frame ``C_t`` (:mod:`jaxstyle.motion.character_frame`), with ``B`` bones:

* joint features (``12 B``; 300): positions (3 B) | velocities (3 B, per frame) | forward (+Z)
  vectors (3 B) | up (+Y) vectors (3 B) of the bone rotations;
* input ``X_t`` (``48 + 12 B``; 348): trajectory x (12) | z (12) | direction x (12) | z (12) at
  ``t - 60 .. t + 50`` every 10 frames at 60 fps, then the joint features of frame ``t``;
* local phases ``P_t`` (8): the 4 Eq. 1 phase features of :func:`jaxstyle.local_phases`,
  (sin, cos) per bone, the gating network's input;
* global phase ``phi_t`` (1, in cycles): :func:`jaxstyle.labels.phase.global_phase` of the clip at
  frame ``t``, the expert blend of Table 2's PFNN-backbone models (Mason et al. 2018, Eq. 1);
* output ``Y_t`` (``24 + 12 B + 18``; 342): trajectory x | z | direction x | z at ``t + 1 + 0 ..
  50`` (6 samples), then the joint features of frame ``t + 1``, all in ``C_t`` ("relative to the
  character's position in the input frame"); the next local phases ``P_{t+1}`` (8), their update
  ``P_{t+1} - P_t`` (8), and the foot contacts of frame ``t + 1`` (left, right).

The first output trajectory sample is the next frame's own character frame, so decoding recovers
the root motion exactly. Style clips are 240 consecutive frames of joint features (each frame in
its own character frame), a new clip every 120 frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxstyle.data.pfnn_features import FUTURE_SAMPLES, PAST_SAMPLES, sample_step, valid_frames
from jaxstyle.errors import MotionDataError
from jaxstyle.labels.local_phase import LocalPhases, local_phases
from jaxstyle.labels.phase import global_phase as label_global_phase
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
)
from jaxstyle.motion.skeleton import find_feet_and_hands

CLIP_FRAMES = 240
CLIP_STRIDE = 120
NUM_PHASE_FEATURES = 8


@dataclass(frozen=True)
class LPNLayout:
    """Sizes and slices of the LPN vectors for ``num_bones`` bones (25 for 100STYLE)."""

    num_bones: int

    @classmethod
    def of_inputs(cls, input_size: int) -> "LPNLayout":
        """The layout whose input row has ``input_size`` values (``48 + 12 B``)."""
        bones, rest = divmod(int(input_size) - 4 * (PAST_SAMPLES + FUTURE_SAMPLES), 12)
        if rest or bones < 1:
            raise ValueError(f"{input_size} is not an LPN input size (48 + 12 x bones)")
        return cls(bones)

    @property
    def joint_size(self) -> int:
        return 12 * self.num_bones

    @property
    def input_size(self) -> int:
        return 4 * (PAST_SAMPLES + FUTURE_SAMPLES) + self.joint_size

    @property
    def output_size(self) -> int:
        return 4 * FUTURE_SAMPLES + self.joint_size + 2 * NUM_PHASE_FEATURES + 2

    def joint_groups(self, start: int = 0) -> dict[str, slice]:
        b3 = 3 * self.num_bones
        names = ("joint_position", "joint_velocity", "joint_forward", "joint_up")
        return {n: slice(start + i * b3, start + (i + 1) * b3) for i, n in enumerate(names)}

    @property
    def input_groups(self) -> dict[str, slice]:
        n = PAST_SAMPLES + FUTURE_SAMPLES
        return {"trajectory_position": slice(0, 2 * n), "trajectory_direction": slice(2 * n, 4 * n),
                **self.joint_groups(4 * n)}

    @property
    def output_groups(self) -> dict[str, slice]:
        f = FUTURE_SAMPLES
        o = 4 * f + self.joint_size
        return {"trajectory_position": slice(0, 2 * f), "trajectory_direction": slice(2 * f, 4 * f),
                **self.joint_groups(4 * f),
                "local_phase": slice(o, o + NUM_PHASE_FEATURES),
                "local_phase_update": slice(o + NUM_PHASE_FEATURES, o + 2 * NUM_PHASE_FEATURES),
                "foot_contact": slice(o + 2 * NUM_PHASE_FEATURES, o + 2 * NUM_PHASE_FEATURES + 2)}


def bone_points(motion: Motion) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``(B, 3)``-ready selection: joint indices of each bone's rotation, end-site indices used as
    extra points (into ``global_positions(end_sites=True)``), and the bone names."""
    hands = find_feet_and_hands(motion.names, motion.source, motion.joint_map)["hands"]
    hand_idx = set(motion.joint_indices(list(hands)))
    ends = [e for e, p in enumerate(motion.end_site_parents) if int(p) in hand_idx]
    names = list(motion.names) + [f"{motion.names[motion.end_site_parents[e]]}_End" for e in ends]
    point_idx = np.concatenate([np.arange(motion.num_joints), motion.num_joints + np.array(ends, dtype=int)])
    rot_idx = np.concatenate([np.arange(motion.num_joints), motion.end_site_parents[ends].astype(int)])
    return point_idx.astype(int), rot_idx.astype(int), names


def foot_bones(skeleton: Motion) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The LPN bone indices of the ankles then the toes (found by name,
    :func:`jaxstyle.motion.skeleton.find_feet_and_hands`), and each one's foot (0 left, 1 right)."""
    names = bone_points(skeleton)[2]
    found = find_feet_and_hands(skeleton.names, skeleton.source, skeleton.joint_map)
    feet, side = [], []
    for group in ("ankles", "toes"):
        for s, name in enumerate(found[group]):  # (left, right)
            feet.append(names.index(name))
            side.append(s)
    return tuple(feet), tuple(side)


def bone_parents(motion: Motion) -> np.ndarray:
    """``(B,)`` parent of each LPN bone in the bone order of :func:`bone_points` (-1 for the root;
    a hand end site's parent is its wrist): the bones of the 2022 bone-length loss (Eq. 6)."""
    points, rot_idx, _ = bone_points(motion)
    parents = np.asarray(motion.parents)
    out = np.full(len(points), -1, dtype=np.int64)
    for i, (p, r) in enumerate(zip(points, rot_idx, strict=True)):
        if p < motion.num_joints:
            out[i] = parents[p]  # joint indices are the first num_joints bones, in order
        else:
            out[i] = r  # an end site hangs from the joint whose rotation it takes
    return out


def end_effector_columns(motion: Motion) -> np.ndarray:
    """``(12,)`` input columns of the velocities of the hands and feet (the local-phase bones:
    right hand, left hand, right foot, left foot): the MANN backbone's gating input (Zhang et al.
    2018, via the 2022 paper's MANN FiLM)."""
    from jaxstyle.labels.local_phase import default_bones

    names = bone_points(motion)[2]
    vel = LPNLayout(len(names)).input_groups["joint_velocity"].start
    return np.concatenate([vel + 3 * names.index(n) + np.arange(3) for n in default_bones(motion)])


def _joint_features(pos, prev, rot, frames: CharacterFrames, index) -> np.ndarray:
    n = len(pos)
    local_rot = rotations_to_local(rot, frames, index)
    return np.concatenate([to_local(pos, frames, index).reshape(n, -1),
                           directions_to_local(pos - prev, frames, index).reshape(n, -1),
                           quat.forward(local_rot).reshape(n, -1), quat.up(local_rot).reshape(n, -1)], axis=1)


@dataclass(frozen=True)
class LPNFeatures:
    """LPN arrays of one clip: ``inputs (N, 348)``, ``phases (N, 8)``, ``outputs (N, 342)``,
    ``frames (N,)`` (the clip frame of each row), ``clips (C, 240, 300)``, ``clip_starts (C,)`` and
    ``global_phase (N,)`` (the PFNN phase of each row's frame, in cycles)."""

    inputs: np.ndarray
    phases: np.ndarray
    outputs: np.ndarray
    frames: np.ndarray
    clips: np.ndarray
    clip_starts: np.ndarray
    bones: tuple[str, ...]
    global_phase: np.ndarray


def encode_lpn(motion: Motion, *, phases: LocalPhases | None = None, frames: CharacterFrames | None = None,
               clip_frames: int = CLIP_FRAMES, clip_stride: int = CLIP_STRIDE,
               global_phase_T: np.ndarray | None = None) -> LPNFeatures:
    """LPN inputs, local phases, outputs and style clips of a clip (see the module docstring).

    ``phases`` defaults to :func:`jaxstyle.local_phases` with its defaults; ``global_phase_T``
    (``(T,)`` in cycles) to :func:`jaxstyle.labels.phase.global_phase` with its defaults (the
    labeller of the 2018 datasets, so a PFNN backbone sees the same phase on both layouts); a
    clip shorter than ``clip_frames`` has no style clip (``clips`` is empty).
    """
    t = valid_frames(motion.num_frames, motion.fps)
    if len(t) == 0:
        need = (PAST_SAMPLES + FUTURE_SAMPLES - 1) * sample_step(motion.fps) + 2
        raise MotionDataError(f"clip has {motion.num_frames} frames; the LPN trajectory window needs at least {need}",
                              motion.source)
    g_rot, g_pos = kinematics.global_transforms(motion)
    phases = phases or local_phases(motion, positions_TxJx3=g_pos)
    points, rot_idx, names = bone_points(motion)
    all_pos = np.concatenate([g_pos, kinematics.end_site_positions(motion, g_rot, g_pos)], axis=1)[:, points]
    all_rot = g_rot[:, rot_idx]
    frames = frames or character_frames(motion, positions_TxJx3=g_pos)
    phi = label_global_phase(motion) if global_phase_T is None else np.asarray(global_phase_T, np.float64)
    if phi.shape != (motion.num_frames,):
        raise ValueError(f"global_phase_T must have shape ({motion.num_frames},), got {phi.shape}")
    s, t1 = sample_step(motion.fps), t + 1
    x = np.concatenate([trajectory_features(frames, t, np.arange(-PAST_SAMPLES, FUTURE_SAMPLES) * s),
                        _joint_features(all_pos[t], all_pos[t - 1], all_rot[t], frames, t)], axis=1)
    p = phases.features.reshape(motion.num_frames, -1)
    if p.shape[1] != NUM_PHASE_FEATURES:
        raise ValueError(f"expected 4 local-phase bones (8 values), got {p.shape[1]} values")
    future = trajectory_features(frames, t, 1 + np.arange(FUTURE_SAMPLES) * s)
    y = np.concatenate([future, _joint_features(all_pos[t1], all_pos[t], all_rot[t1], frames, t),
                        p[t1], p[t1] - p[t], phases.contacts[t1].astype(np.float64)], axis=1)
    # style clips: joint features of every frame in its own character frame
    every = np.arange(1, motion.num_frames)
    per_frame = _joint_features(all_pos[every], all_pos[every - 1], all_rot[every], frames, every)
    starts = np.arange(0, len(per_frame) - clip_frames + 1, clip_stride)
    clips = (np.stack([per_frame[a:a + clip_frames] for a in starts]) if len(starts)
             else np.zeros((0, clip_frames, per_frame.shape[1])))
    for name, arr in (("inputs", x), ("outputs", y), ("local phases", p), ("style clips", clips),
                      ("global phases", phi)):
        if not np.isfinite(arr).all():
            raise MotionDataError(f"LPN {name} contain NaN or infinity", motion.source)
    return LPNFeatures(x, p[t], y, t, clips, starts + 1, tuple(names), phi[t])


def decode_lpn(outputs: np.ndarray, skeleton: Motion, *, origin: np.ndarray | None = None,
               yaw: float = 0.0) -> Motion:
    """A :class:`Motion` from a sequence of LPN outputs ``(N, 342)``: output ``i`` gives frame
    ``i + 1`` relative to frame ``i``, which starts at ``origin``/``yaw``. Rotations come from the
    forward/up vectors of the skeleton's joints (the hand end sites are not needed)."""
    y = np.asarray(outputs, dtype=np.float64)
    num_joints = skeleton.num_joints
    layout = LPNLayout(len(bone_points(skeleton)[0]))
    if y.ndim != 2 or y.shape[1] != layout.output_size:
        raise ValueError(f"outputs must have shape (N, {layout.output_size}), got {y.shape}")
    g = layout.output_groups
    n, f = len(y), FUTURE_SAMPLES
    # next frame in the current frame: the first future trajectory sample
    step_local = np.stack([y[:, 0], np.zeros(n), y[:, f]], axis=-1)
    dir_local = np.stack([y[:, 2 * f], np.zeros(n), y[:, 3 * f]], axis=-1)
    origins = np.zeros((n + 1, 3))
    origins[0] = np.zeros(3) if origin is None else origin
    yaws = np.zeros(n + 1)
    yaws[0] = yaw
    for i in range(n):  # sequential by nature: each step is relative to the previous frame
        origins[i + 1] = origins[i] + rotate_yaw(step_local[i], yaws[i])
        yaws[i + 1] = yaws[i] + np.arctan2(dir_local[i, 0], dir_local[i, 2])
    cur = CharacterFrames(origins[:-1], yaws[:-1])
    local_pos = y[:, g["joint_position"]].reshape(n, -1, 3)[:, :num_joints]
    g_pos = from_local(local_pos, cur)
    fwd = y[:, g["joint_forward"]].reshape(n, -1, 3)[:, :num_joints]
    up = y[:, g["joint_up"]].reshape(n, -1, 3)[:, :num_joints]
    g_rot = rotations_from_local(fwd, up, cur)
    return kinematics.motion_from_global(skeleton, g_rot, g_pos[:, skeleton.parents < 0])
