"""The character's ground frame: origin under the root, +Z along the facing direction, +Y up.

Both papers express features in this frame (Holden et al. 2017, which both follow): the origin is
the root joint projected on the floor and the heading is the facing direction of
:func:`jaxstyle.motion.kinematics.facing_directions`. A frame is stored as a ground position
``(T, 3)`` and a yaw angle ``(T,)`` in radians, the rotation about +Y taking +Z onto the facing.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxstyle.motion import Motion, kinematics, quat
from jaxstyle.motion.kinematics import UP_AXIS


class CharacterFrames(NamedTuple):
    """Per-frame ground origin ``(T, 3)`` (y = 0) and yaw ``(T,)`` (radians about +Y)."""

    origin: np.ndarray
    yaw: np.ndarray


def character_frames(motion: Motion, *, smooth_seconds: float = 1.0 / 3.0,
                     positions_TxJx3: np.ndarray | None = None) -> CharacterFrames:
    """Ground frames of a clip. Facing is smoothed with a Gaussian of ``smooth_seconds`` (the PFNN
    code's 20 frames at 60 fps) so the frame does not wobble with every step."""
    pos = kinematics.global_positions(motion) if positions_TxJx3 is None else positions_TxJx3
    origin = pos[:, 0].copy()
    origin[:, UP_AXIS] = 0.0
    facing = kinematics.facing_directions(motion, smooth_sigma=smooth_seconds * motion.fps, positions_TxJx3=pos)
    return CharacterFrames(origin, np.arctan2(facing[:, 0], facing[:, 2]))


def yaw_quaternion(yaw: np.ndarray) -> np.ndarray:
    """``(..., 4)`` rotation by ``yaw`` radians about +Y."""
    yaw = np.asarray(yaw, dtype=np.float64)
    return np.stack([np.cos(yaw / 2), np.zeros_like(yaw), np.sin(yaw / 2), np.zeros_like(yaw)], axis=-1)


def rotate_yaw(v: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Rotate vectors ``(..., 3)`` by ``yaw`` (broadcast over the leading axes) about +Y."""
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    x, y, z = v[..., 0:1], v[..., 1:2], v[..., 2:3]
    return np.concatenate([x * c + z * s, y, -x * s + z * c], axis=-1)


def to_local(points: np.ndarray, frames: CharacterFrames, index: np.ndarray | slice = slice(None)) -> np.ndarray:
    """Points ``(N, ..., 3)`` in the frames ``frames[index]`` (one frame per leading entry)."""
    origin, yaw = frames.origin[index], frames.yaw[index]
    shape = (-1,) + (1,) * (points.ndim - 2) + (3,)
    rel = points - origin.reshape(shape)
    return rotate_yaw(rel, -yaw.reshape(shape[:-1]))


def directions_to_local(vectors: np.ndarray, frames: CharacterFrames,
                        index: np.ndarray | slice = slice(None)) -> np.ndarray:
    """Directions ``(N, ..., 3)`` (no translation) in the frames ``frames[index]``."""
    yaw = frames.yaw[index]
    return rotate_yaw(vectors, -yaw.reshape((-1,) + (1,) * (vectors.ndim - 2)))


def rotations_to_local(rotations: np.ndarray, frames: CharacterFrames,
                       index: np.ndarray | slice = slice(None)) -> np.ndarray:
    """Global joint rotations ``(N, J, 4)`` relative to the frames ``frames[index]``."""
    inv = quat.inverse(yaw_quaternion(frames.yaw[index]))[:, None]
    return quat.mul(np.broadcast_to(inv, rotations.shape), rotations)


def from_local(points: np.ndarray, frames: CharacterFrames) -> np.ndarray:
    """Inverse of :func:`to_local`: points ``(N, ..., 3)`` given in frames ``N`` back to global."""
    shape = (-1,) + (1,) * (points.ndim - 2)
    return rotate_yaw(points, frames.yaw.reshape(shape)) + frames.origin.reshape(shape + (3,))


def rotations_from_local(forward: np.ndarray, up: np.ndarray, frames: CharacterFrames) -> np.ndarray:
    """Global rotations ``(N, J, 4)`` from forward/up vectors ``(N, J, 3)`` given in frames ``N``
    (inverse of :func:`rotations_to_local` followed by ``quat.forward``/``quat.up``)."""
    to_global = np.broadcast_to(yaw_quaternion(frames.yaw)[:, None], forward.shape[:2] + (4,))
    return quat.mul(to_global, quat.from_forward_up(forward, up))


def trajectory_features(frames: CharacterFrames, centre: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """``(N, 4 K)`` trajectory of frames ``centre + offsets``, each row in its centre frame:
    x (K) | z (K) of the frame origins, then x (K) | z (K) of their facing directions."""
    idx = centre[:, None] + offsets[None, :]  # (N, K)
    pos = to_local(frames.origin[idx], frames, centre)  # (N, K, 3)
    fwd = np.stack([np.sin(frames.yaw[idx]), np.zeros(idx.shape), np.cos(frames.yaw[idx])], -1)
    dirs = directions_to_local(fwd, frames, centre)
    return np.concatenate([pos[..., 0], pos[..., 2], dirs[..., 0], dirs[..., 2]], axis=-1)


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``[-pi, pi)``."""
    return np.mod(np.asarray(a) + np.pi, 2 * np.pi) - np.pi
