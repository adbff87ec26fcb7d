"""How much a generated character moves like its style's capture: the style distance.

Foot skating and path error say whether a character walks well; they do not say whether it walks
in its style (a few-shot character can walk cleanly at half its style's strength). Here a motion
is summarised by statistics of its pose in its own character frame (the root's ground point,
facing the way the hips and shoulders do, :func:`jaxstyle.motion.character_frame.character_frames`)
and of its gait (:class:`StyleStats`), and two motions are compared group by group
(:func:`style_distance`), all in metres:

* ``pose``: the root mean square, over joints, of the distance between the two motions' mean local
  joint positions (posture: a crouch, arms held forward);
* ``motion``: the same of the per-axis standard deviations of the local joint positions (how much
  each joint moves: arm swing, bounce);
* ``arms``: the difference in how far the wrists are held below the head, plus the difference in
  how far they move up and down (the 5th to 95th percentile range of wrist height relative to the
  head), the arm styles' signature;
* ``gait``: the difference in stride length (ground distance per two steps, at the speed walked).

``style_distance`` is their sum. The quality benchmark also reports ``wrist_range_ratio``, the
character's wrist range over its capture's (how much of an arm style's movement is kept). A style
*shows* when the distance of a character to its own capture is below half the distance of that
capture to Neutral's (:func:`shows`); the distance between the two halves of one capture
(:func:`halves_distance`) is the floor a capture itself sets. Cadence (steps per second) is reported
beside them, not summed (at a matched speed a cadence error is a stride error).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.motion import Motion
from jaxstyle.motion.character_frame import character_frames, to_local
from jaxstyle.motion.kinematics import UP_AXIS
from jaxstyle.motion.skeleton import find_feet_and_hands
from jaxstyle.output import metrics

STYLE_GROUPS = ("pose", "motion", "arms", "gait")
"""The groups :func:`style_distance` sums (see the module docstring)."""

MIN_FRAMES = 30
"""Fewer frames than this give NaN statistics (no stable mean, no step)."""


class StyleStats(NamedTuple):
    """Statistics of one motion, in metres and seconds: each joint's mean local position
    ``mean_Jx3`` and per-axis standard deviation ``std_Jx3`` in the character frame, how far the
    wrists are held below the head ``wrist_below_head_m`` and their up-and-down range
    ``wrist_range_m``, the ``stride_m`` (ground distance per two steps) and ``cadence`` (steps per
    second)."""

    mean_Jx3: np.ndarray
    std_Jx3: np.ndarray
    wrist_below_head_m: float
    wrist_range_m: float
    stride_m: float
    cadence: float


def _head(names) -> int:
    for candidate in ("Head", "head", "Neck", "neck"):
        for j, n in enumerate(names):
            if n == candidate or n.endswith(":" + candidate):
                return j
    raise ValueError(f"no head joint (Head or Neck) among {list(names)}")


def style_stats(positions_TxJx3: np.ndarray, skeleton: Motion, fps: float, *,
                units_per_meter: float | None = None, cadence: float | None = None) -> StyleStats:
    """:class:`StyleStats` of global joint positions ``(T, J, 3)`` (file units) on ``skeleton``
    (its joint names give the head, the wrists and the feet). ``cadence``: the steps per second of
    these same positions when already measured (:func:`jaxstyle.output.metrics.step_figures`),
    measured here otherwise. NaN statistics for fewer than :data:`MIN_FRAMES` frames or positions
    that are not finite."""
    pos = np.asarray(positions_TxJx3, dtype=np.float64)[:, :skeleton.num_joints]
    upm = float(units_per_meter or estimate_units_per_meter(skeleton))
    nan = float("nan")
    if len(pos) < MIN_FRAMES or not np.isfinite(pos).all():
        empty = np.full((skeleton.num_joints, 3), nan)
        return StyleStats(empty, empty, nan, nan, nan, nan)
    frames = character_frames(skeleton.replace(fps=float(fps)), positions_TxJx3=pos)
    local = to_local(pos, frames) / upm
    head = _head(skeleton.names)
    hand_names = find_feet_and_hands(skeleton.names, joint_map=skeleton.joint_map)["hands"]
    hands = [skeleton.names.index(n) for n in hand_names]
    below = local[:, head, UP_AXIS][:, None] - local[:, hands, UP_AXIS]  # (T, 2)
    lo, hi = np.percentile(below, [5, 95], axis=0)
    if cadence is None:
        cadence = metrics.step_figures(pos, skeleton, fps).steps_per_s
    cadence = float(cadence)
    ground = np.linalg.norm(np.diff(frames.origin[:, [0, 2]], axis=0), axis=1).sum() / upm
    seconds = (len(pos) - 1) / fps
    stride = 2.0 * ground / seconds / cadence if cadence > 0 else nan
    return StyleStats(local.mean(axis=0), local.std(axis=0), float(below.mean()), float(np.mean(hi - lo)),
                      float(stride), cadence)


def style_distance(a: StyleStats, b: StyleStats) -> dict[str, float]:
    """``{"style_distance", "style_pose_m", "style_motion_m", "style_arms_m", "style_gait_m",
    "cadence_difference"}`` between two motions' :class:`StyleStats` (see the module docstring;
    NaN when either is NaN). 0 for a motion against itself."""
    pose = float(np.sqrt(np.mean(np.sum((a.mean_Jx3 - b.mean_Jx3) ** 2, axis=-1))))
    motion = float(np.sqrt(np.mean(np.sum((a.std_Jx3 - b.std_Jx3) ** 2, axis=-1))))
    arms = abs(a.wrist_below_head_m - b.wrist_below_head_m) + abs(a.wrist_range_m - b.wrist_range_m)
    gait = abs(a.stride_m - b.stride_m)
    return {"style_distance": pose + motion + arms + gait, "style_pose_m": pose, "style_motion_m": motion,
            "style_arms_m": arms, "style_gait_m": gait, "cadence_difference": abs(a.cadence - b.cadence)}


def halves_distance(positions_TxJx3: np.ndarray, skeleton: Motion, fps: float, *,
                    units_per_meter: float | None = None) -> float:
    """The style distance between the first and the second half of one motion: how much a capture
    differs from itself, the floor of any character's distance to it."""
    pos = np.asarray(positions_TxJx3)
    half = len(pos) // 2
    first = style_stats(pos[:half], skeleton, fps, units_per_meter=units_per_meter)
    second = style_stats(pos[half:], skeleton, fps, units_per_meter=units_per_meter)
    return style_distance(first, second)["style_distance"]


def shows(distance_to_capture: float, capture_to_neutral: float) -> bool:
    """Whether a style shows: its distance to its own capture is below half its capture's distance
    to Neutral's (False when either is NaN)."""
    return bool(np.isfinite(distance_to_capture) and np.isfinite(capture_to_neutral)
                and distance_to_capture < 0.5 * capture_to_neutral)
