"""Plausibility measures of generated (or real) motion, from global joint positions.

* :func:`bone_length_errors`: relative error of every bone's length against the skeleton's
  (the PFNN predicts joint positions independently, so nothing holds them exactly);
* :func:`foot_stats`: how often a foot is on the floor and how fast feet slide while they are;
* :func:`reference_foot_stats`: the same figures for real PFNN rows, to compare a rollout with the
  motion it was learnt from.

Feet are the ankle and toe joints of :class:`jaxstyle.FootJoints`; a foot joint counts as on the
floor when it is within ``tolerance_m`` of its floor height (the 5th percentile of its height in
the reference motion, as in :mod:`jaxstyle.contacts`). Speeds are in metres per second.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxstyle.contacts import FLOOR_PERCENTILE, FootJoints
from jaxstyle.kinematics import UP_AXIS, bone_lengths
from jaxstyle.motion import Motion
from jaxstyle.pfnn_features import PFNNLayout


def bone_length_errors(positions_TxJx3: np.ndarray, skeleton: Motion, min_length: float = 1e-6) -> np.ndarray:
    """``(T, B)`` relative length error ``| |p_j - p_parent| - L_j | / L_j`` of every bone with a
    reference length ``L_j > min_length`` (file units)."""
    pos = np.asarray(positions_TxJx3, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[1:] != (skeleton.num_joints, 3):
        raise ValueError(f"positions must be (T, {skeleton.num_joints}, 3), got {pos.shape}")
    ref = bone_lengths(skeleton)
    bones = np.flatnonzero((skeleton.parents >= 0) & (ref > min_length))
    length = np.linalg.norm(pos[:, bones] - pos[:, skeleton.parents[bones]], axis=-1)
    return np.abs(length - ref[bones]) / ref[bones]


@dataclasses.dataclass(frozen=True)
class FootStats:
    """``contact_fraction``: frames with at least one foot joint on the floor; ``skating``: the
    median horizontal speed (m/s) of foot joints while on the floor (NaN if never)."""

    contact_fraction: float
    skating: float


def foot_stats(heights_TxF: np.ndarray, speeds_TxF: np.ndarray, floor_F: np.ndarray, *, units_per_meter: float,
               tolerance_m: float = 0.03) -> FootStats:
    """:class:`FootStats` from foot-joint heights and horizontal speeds (file units, per second)."""
    on = np.asarray(heights_TxF) <= np.asarray(floor_F) + tolerance_m * units_per_meter
    speeds = np.asarray(speeds_TxF)[on] / units_per_meter
    return FootStats(float(on.any(axis=1).mean()) if len(on) else float("nan"),
                     float(np.median(speeds)) if speeds.size else float("nan"))


def _foot_joints(skeleton: Motion) -> list[int]:
    feet = FootJoints.find(skeleton)
    return list(feet.ankles) + list(feet.toes)


def reference_foot_stats(outputs_NxO: np.ndarray, skeleton: Motion, fps: float, *, units_per_meter: float,
                         tolerance_m: float = 0.03) -> tuple[FootStats, np.ndarray]:
    """Foot statistics of real (de-normalised) PFNN output rows, and the per-foot-joint floor
    heights ``(F,)`` they define. In the PFNN layout a row's joint positions are in the ground
    frame, so their height is the height above the floor, and their velocities are the per-frame
    displacements (their horizontal norm does not depend on the frame)."""
    y = np.asarray(outputs_NxO, dtype=np.float64)
    g = PFNNLayout(skeleton.num_joints).output_groups
    n = len(y)
    pos = y[:, g["joint_position"]].reshape(n, -1, 3)
    vel = y[:, g["joint_velocity"]].reshape(n, -1, 3)
    joints = _foot_joints(skeleton)
    heights = pos[:, joints, UP_AXIS]
    speeds = np.linalg.norm(np.delete(vel[:, joints], UP_AXIS, axis=-1), axis=-1) * fps
    floor = np.percentile(heights, FLOOR_PERCENTILE, axis=0)
    return foot_stats(heights, speeds, floor, units_per_meter=units_per_meter, tolerance_m=tolerance_m), floor


def positions_foot_stats(positions_TxJx3: np.ndarray, skeleton: Motion, fps: float, floor_F: np.ndarray, *,
                         units_per_meter: float, tolerance_m: float = 0.03) -> FootStats:
    """Foot statistics of global joint positions (e.g. a rollout), against given floor heights."""
    pos = np.asarray(positions_TxJx3, dtype=np.float64)[:, _foot_joints(skeleton)]
    heights = pos[:, :, UP_AXIS]
    step = np.diff(pos, axis=0, prepend=pos[:1])
    speeds = np.linalg.norm(np.delete(step, UP_AXIS, axis=-1), axis=-1) * fps
    return foot_stats(heights[1:], speeds[1:], floor_F, units_per_meter=units_per_meter, tolerance_m=tolerance_m)
