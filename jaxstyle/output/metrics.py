"""Plausibility measures of generated (or real) motion, from global joint positions.

* :func:`bone_length_errors`: relative error of every bone's length against the skeleton's
  (the PFNN predicts joint positions independently, so nothing holds them exactly);
* :func:`foot_stats`: how often a foot is on the floor and how fast feet slide while they are;
* :func:`reference_foot_stats`: the same figures for real PFNN rows, to compare a rollout with the
  motion it was learnt from;
* :func:`path_error`, :func:`path_distance`, :func:`jitter` and :func:`foot_skating`: how far the
  character strays from the user's path (Mason et al. 2018 section 7.1 steers along a path), how
  jerky the joints move and how much planted feet slide (the artefact Mason, Starke & Komura 2022
  section 4.4 removes with foot contact IK, :mod:`jaxstyle.output.footik`);
* :func:`motion_quality` gathers them into a :class:`MotionQuality`, and :func:`reference_quality`
  computes the same figures for real motion of the same style, the reference they are judged by.

Feet are the ankle and toe joints of :class:`jaxstyle.FootJoints`; a foot joint counts as on the
floor when it is within ``tolerance_m`` of its floor height (the 5th percentile of its height in
the reference motion, as in :mod:`jaxstyle.labels.contacts`). Speeds are in metres per second.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.labels.contacts import (
    FLOOR_PERCENTILE,
    HEIGHT_THRESHOLD_M,
    FootJoints,
    body_units_per_meter,
    estimate_units_per_meter,
    joint_contacts,
    runs,
)
from jaxstyle.motion import Motion
from jaxstyle.motion.kinematics import UP_AXIS, bone_lengths, global_positions
from jaxstyle.output import footlock


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


# --- Quality of generated motion against the user's path and the reference data ---------------------------------

GROUND_AXES = tuple(a for a in range(3) if a != UP_AXIS)
# The quality figures count a foot joint on the floor within d_max = 1 cm of its floor height (2022 section 4.1.2,
# as :mod:`jaxstyle.labels.contacts`); the 3 cm of foot_stats also counts toes and heels rolling off the floor, which
# makes the mean sliding speed of real walking 0.25-0.5 m/s instead of 0.01-0.15 m/s.
TOLERANCE_M = HEIGHT_THRESHOLD_M


def _points_2d(value, name: str, length: int | None = None) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (T, 2) (ground x, z per frame), got {arr.shape}")
    if length is not None and arr.shape[0] != length:
        raise ValueError(f"{name} has {arr.shape[0]} frames, expected {length}")
    return arr


def _positions(value, name: str = "positions_TxJx3", num_joints: int | None = None) -> np.ndarray:
    pos = np.asarray(value, dtype=np.float64)
    joints = "J" if num_joints is None else str(num_joints)
    if pos.ndim != 3 or pos.shape[-1] != 3 or (num_joints is not None and pos.shape[1] != num_joints):
        raise ValueError(f"{name} must have shape (T, {joints}, 3), got {pos.shape}")
    if not np.isfinite(pos).all():
        raise ValueError(f"{name} contains NaN or infinity")
    return pos


def _check_scale(units_per_meter: float, fps: float | None = None) -> None:
    if not np.isfinite(units_per_meter) or units_per_meter <= 0:
        raise ValueError(f"units_per_meter must be positive, got {units_per_meter}")
    if fps is not None and (not np.isfinite(fps) or fps <= 0):
        raise ValueError(f"fps must be positive, got {fps}")


def ground_positions(positions_TxJx3: np.ndarray, joint: int = 0) -> np.ndarray:
    """``(T, 2)`` ground (x, z) position of a joint (the root by default: the character's origin)."""
    return np.asarray(positions_TxJx3, dtype=np.float64)[:, joint][:, list(GROUND_AXES)]


def path_error(origin_Tx2: np.ndarray, path_Tx2: np.ndarray, *, units_per_meter: float) -> np.ndarray:
    """``(T,)`` ground distance in metres between the character's origin and where the user's path
    wanted it in the same frame (both in file units, ground ``(x, z)``)."""
    origin = _points_2d(origin_Tx2, "origin_Tx2")
    path = _points_2d(path_Tx2, "path_Tx2", len(origin))
    _check_scale(units_per_meter)
    return np.linalg.norm(origin - path, axis=-1) / units_per_meter


def path_distance(origin_Tx2: np.ndarray, polyline_Nx2: np.ndarray, *, units_per_meter: float,
                  chunk_elements: int = 1 << 22) -> np.ndarray:
    """``(T,)`` ground distance in metres from each origin to the nearest point of a polyline path
    (waypoints joined by straight segments; a single waypoint is a point).

    Vectorised over points and segments, in chunks of points of at most ``chunk_elements``
    point-segment pairs so that long paths do not need ``T x N`` memory at once.
    """
    origin = _points_2d(origin_Tx2, "origin_Tx2")
    line = np.asarray(polyline_Nx2, dtype=np.float64)
    if line.ndim != 2 or line.shape[1] != 2 or len(line) == 0:
        raise ValueError(f"polyline_Nx2 must have shape (N, 2) with N >= 1 waypoints, got {line.shape}")
    _check_scale(units_per_meter)
    if len(line) == 1:
        return np.linalg.norm(origin - line[0], axis=-1) / units_per_meter
    start, seg = line[:-1], np.diff(line, axis=0)  # (S, 2)
    seg_len2 = np.sum(seg * seg, axis=-1)
    safe_len2 = np.where(seg_len2 > 0, seg_len2, 1.0)  # repeated waypoints: a zero-length segment is a point
    out = np.empty(len(origin))
    step = max(1, chunk_elements // len(seg))
    for lo in range(0, len(origin), step):
        rel = origin[lo:lo + step, None, :] - start[None]  # (t, S, 2)
        along = np.clip(np.sum(rel * seg, axis=-1) / safe_len2, 0.0, 1.0)
        nearest = rel - along[..., None] * seg
        out[lo:lo + step] = np.sqrt(np.min(np.sum(nearest * nearest, axis=-1), axis=1))
    return out / units_per_meter


def jitter(positions_TxJx3: np.ndarray, fps: float, *, units_per_meter: float) -> float:
    """Mean joint jerk magnitude in m/s^3: the third finite difference of the positions times
    ``fps ** 3``, its norm averaged over joints and frames (NaN with fewer than 4 frames)."""
    pos = _positions(positions_TxJx3)
    _check_scale(units_per_meter, fps)
    if len(pos) < 4:
        return float("nan")
    jerk = np.diff(pos, n=3, axis=0) * (float(fps) ** 3 / units_per_meter)
    return float(np.mean(np.linalg.norm(jerk, axis=-1)))


def _foot_contact_flags(contacts_TxF, num_frames: int, num_foot_joints: int) -> np.ndarray:
    """``(T, F)`` booleans per foot joint from given labels: per foot joint (ankles then toes, the
    order of :class:`FootJoints`) or per foot (left, right; both joints of a foot share it).
    Values in ``[0, 1]`` (a network's contact output) are thresholded at 0.5."""
    c = np.asarray(contacts_TxF)
    per_foot = num_foot_joints // 2
    if c.ndim != 2 or c.shape[0] != num_frames or c.shape[1] not in (2, num_foot_joints):
        raise ValueError(f"contacts_TxF must have shape ({num_frames}, {num_foot_joints}) per foot joint "
                         f"or ({num_frames}, 2) per foot, got {c.shape}")
    if c.dtype != bool:
        c = c.astype(np.float64)
        if not np.isfinite(c).all():
            raise ValueError("contacts_TxF contains NaN or infinity")
        c = c >= 0.5
    return np.tile(c, (1, per_foot)) if c.shape[1] == 2 and num_foot_joints != 2 else c


def _height_contacts(foot_pos_TxFx3: np.ndarray, fps: float, units_per_meter: float, floor_F, tolerance_m: float
                     ) -> np.ndarray:
    floor = None
    if floor_F is not None:
        floor = np.asarray(floor_F, dtype=np.float64)
        if floor.shape != (foot_pos_TxFx3.shape[1],):
            raise ValueError(f"floor_F must have shape ({foot_pos_TxFx3.shape[1]},) (one height per foot joint), "
                             f"got {floor.shape}")
    # Height test only: a speed test would define away the sliding this measures.
    return joint_contacts(foot_pos_TxFx3, fps, units_per_meter=units_per_meter, height_threshold=tolerance_m,
                          speed_threshold=None, floor_J=floor)


def _feet_on_floor(pos_TxJx3: np.ndarray, skeleton: Motion, fps: float, units_per_meter: float, contacts_TxF,
                   floor_F, tolerance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Foot-joint positions ``(T, F, 3)`` and their contact flags ``(T, F)``, given or from heights."""
    feet = pos_TxJx3[:, _foot_joints(skeleton)]
    if contacts_TxF is not None:
        return feet, _foot_contact_flags(contacts_TxF, len(feet), feet.shape[1])
    return feet, _height_contacts(feet, fps, units_per_meter, floor_F, tolerance_m)


def _skating(foot_pos_TxFx3: np.ndarray, on_TxF: np.ndarray, fps: float, units_per_meter: float) -> float:
    """Mean horizontal speed (m/s) over the frame steps during which a foot joint stays on the floor."""
    step = np.diff(foot_pos_TxFx3[..., list(GROUND_AXES)], axis=0)
    speed = np.linalg.norm(step, axis=-1) * (fps / units_per_meter)
    planted = on_TxF[1:] & on_TxF[:-1]
    return float(np.mean(speed[planted])) if planted.any() else float("nan")


def foot_skating(positions_TxJx3: np.ndarray, skeleton: Motion, fps: float, *, units_per_meter: float,
                 contacts_TxF: np.ndarray | None = None, floor_F: np.ndarray | None = None,
                 tolerance_m: float = TOLERANCE_M) -> float:
    """Mean horizontal speed (m/s) of the foot joints (ankles and toes of :class:`FootJoints`) while
    they are on the floor; NaN when no foot joint stays on the floor for two consecutive frames.

    A step from frame ``t`` to ``t + 1`` counts when the joint is in contact in both frames.
    Contacts are ``contacts_TxF`` when given (e.g. a network's predicted labels, per foot joint or
    per foot, thresholded at 0.5), otherwise a joint is on the floor within ``tolerance_m`` (by default
    the paper's ``d_max``, 1 cm) of its floor height (``floor_F``, per foot joint; the clip's own 5th
    height percentile when omitted).
    """
    pos = _positions(positions_TxJx3, num_joints=skeleton.num_joints)
    _check_scale(units_per_meter, fps)
    feet, on = _feet_on_floor(pos, skeleton, fps, units_per_meter, contacts_TxF, floor_F, tolerance_m)
    return _skating(feet, on, fps, units_per_meter)


@dataclasses.dataclass(frozen=True)
class MotionQuality:
    """Plausibility and control figures of one motion (generated or real).

    ``foot_skating_m_s``: mean horizontal speed of foot joints on the floor (:func:`foot_skating`);
    ``contact_fraction``: frames with at least one foot joint on the floor;
    ``bone_error_mean`` / ``bone_error_max``: relative bone length error (:func:`bone_length_errors`);
    ``path_error_mean_m`` / ``path_error_final_m``: distance from the user's path (:func:`path_error`),
    NaN without a path; ``jitter_m_s3``: mean joint jerk (:func:`jitter`).
    """

    num_frames: int
    foot_skating_m_s: float
    contact_fraction: float
    bone_error_mean: float
    bone_error_max: float
    path_error_mean_m: float
    path_error_final_m: float
    jitter_m_s3: float

    def as_row(self) -> dict[str, float | int]:
        """The figures as a flat ``{column: value}`` dict, for CSV or Markdown tables."""
        return dataclasses.asdict(self)


def motion_quality(positions_TxJx3: np.ndarray, skeleton: Motion, fps: float, *, units_per_meter: float,
                   path_Tx2: np.ndarray | None = None, floor_F: np.ndarray | None = None,
                   contacts_TxF: np.ndarray | None = None, tolerance_m: float = TOLERANCE_M) -> MotionQuality:
    """:class:`MotionQuality` of global joint positions ``(T, J, 3)`` (file units) on ``skeleton``.

    Args:
      path_Tx2: where the user's path wanted the character's origin (the root on the ground) in
        each frame, file units; path errors are NaN without it.
      floor_F: floor height of each foot joint (ankles then toes), e.g. from the reference data;
        the clip's own when omitted.
      contacts_TxF: contact labels to use instead of heights (see :func:`foot_skating`).
    """
    pos = _positions(positions_TxJx3, num_joints=skeleton.num_joints)
    _check_scale(units_per_meter, fps)
    feet, on = _feet_on_floor(pos, skeleton, fps, units_per_meter, contacts_TxF, floor_F, tolerance_m)
    bones = bone_length_errors(pos, skeleton)
    nan = float("nan")
    path_mean = path_final = nan
    if path_Tx2 is not None:
        err = path_error(ground_positions(pos), _points_2d(path_Tx2, "path_Tx2", len(pos)),
                         units_per_meter=units_per_meter)
        if err.size:
            path_mean, path_final = float(np.mean(err)), float(err[-1])
    return MotionQuality(
        num_frames=len(pos),
        foot_skating_m_s=_skating(feet, on, fps, units_per_meter),
        contact_fraction=float(on.any(axis=1).mean()) if len(on) else nan,
        bone_error_mean=float(np.mean(bones)) if bones.size else nan,
        bone_error_max=float(np.max(bones)) if bones.size else nan,
        path_error_mean_m=path_mean,
        path_error_final_m=path_final,
        jitter_m_s3=jitter(pos, fps, units_per_meter=units_per_meter),
    )


def reference_quality(motion: Motion, *, units_per_meter: float | None = None,
                      tolerance_m: float = TOLERANCE_M) -> MotionQuality:
    """:class:`MotionQuality` of real motion: global positions by forward kinematics, the floor
    from the motion itself, no path (path errors NaN). ``units_per_meter`` is guessed from the
    skeleton (:func:`jaxstyle.estimate_units_per_meter`) when omitted."""
    upm = estimate_units_per_meter(motion) if units_per_meter is None else float(units_per_meter)
    return motion_quality(global_positions(motion), motion, motion.fps, units_per_meter=upm, tolerance_m=tolerance_m)


# --- Benchmark figures (experiments/quality.py, jaxstyle.output.quality) --------------------------------------------

def foot_jerk(positions_TxJx3: np.ndarray, skeleton: Motion, fps: float, *, units_per_meter: float) -> float:
    """Mean jerk (m/s^3) of the ankle joints: foot popping shows as a large value (a foot IK that
    snaps a foot back raises it; :func:`jitter` averages it away over all joints)."""
    pos = _positions(positions_TxJx3, num_joints=skeleton.num_joints)
    _check_scale(units_per_meter, fps)
    ankles = list(FootJoints.find(skeleton).ankles)
    if len(pos) < 4:
        return float("nan")
    jerk = np.diff(pos[:, ankles], n=3, axis=0) * (float(fps) ** 3 / units_per_meter)
    return float(np.mean(np.linalg.norm(jerk, axis=-1)))


def heading_error_deg(yaw_T: np.ndarray, path_yaw_T: np.ndarray) -> float:
    """Mean absolute difference (degrees) between the character's facing and the path's, wrapped."""
    a, b = np.asarray(yaw_T, dtype=np.float64), np.asarray(path_yaw_T, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"yaw_T and path_yaw_T differ in shape: {a.shape} and {b.shape}")
    return float(np.degrees(np.mean(np.abs(np.angle(np.exp(1j * (a - b)))))))


def ground_speed(origin_Tx2: np.ndarray, fps: float, *, units_per_meter: float) -> np.ndarray:
    """``(T,)`` root ground speed (m/s): the step into each frame (the first frame repeats the second)."""
    o = _points_2d(origin_Tx2, "origin_Tx2")
    step = np.linalg.norm(np.diff(o, axis=0), axis=-1) * fps / units_per_meter
    return np.concatenate([step[:1], step]) if len(step) else np.zeros(len(o))


def stop_times(origin_Tx2: np.ndarray, path_velocity_Tx2: np.ndarray, fps: float, *, units_per_meter: float,
               threshold_m_s: float = 0.1, window_s: float = 1.0 / 6.0) -> np.ndarray:
    """Seconds from each stop command (the path's velocity falls to zero after moving) until the
    root's ground speed, averaged over ``window_s``, falls below ``threshold_m_s``; NaN where it
    never does before the path moves again (or ends). The benchmark's target
    (:func:`jaxstyle.output.report.targets`): within 0.5 s."""
    v = np.linalg.norm(np.asarray(path_velocity_Tx2, dtype=np.float64), axis=1)
    moving = v > 1e-9
    stops = np.flatnonzero(moving[:-1] & ~moving[1:]) + 1
    speed = ground_speed(origin_Tx2, fps, units_per_meter=units_per_meter)
    n = max(int(round(window_s * fps)), 1)
    smooth = np.convolve(speed, np.ones(n) / n, mode="full")[:len(speed)]  # trailing mean
    out = []
    for s in stops:
        end = s + int(np.argmax(moving[s:])) if moving[s:].any() else len(v)
        below = np.flatnonzero(smooth[s:end] < threshold_m_s)
        out.append(below[0] / fps if len(below) else float("nan"))
    return np.asarray(out, dtype=np.float64)


def max_joint_difference_m(a_TxJx3: np.ndarray, b_TxJx3: np.ndarray, *, units_per_meter: float) -> float:
    """Largest distance (m) between the same joint in two motions, e.g. the network's predicted
    joints and the exported skeleton's (forward kinematics of the BVH)."""
    a, b = _positions(a_TxJx3, "a_TxJx3"), _positions(b_TxJx3, "b_TxJx3")
    if a.shape != b.shape:
        raise ValueError(f"a_TxJx3 and b_TxJx3 differ in shape: {a.shape} and {b.shape}")
    return float(np.max(np.linalg.norm(a - b, axis=-1))) / units_per_meter if a.size else float("nan")


# --- Stepping, sliding per contact and what foot locking did (jaxstyle.output.footlock) -----------------------------

@dataclasses.dataclass(frozen=True)
class StepFigures:
    """Figures of stepping that frozen or gliding feet cannot pass, from the contact rule of
    :func:`jaxstyle.output.footlock.contact_step` (height above the floor and horizontal speed, with
    hysteresis) on heel (ankle) and toe joints:

    ``steps_per_s``: contact onsets per second, both feet (a foot is in contact while its heel or
    toe is); ``lifted_steps_per_s``: the onsets that end a lift, per second: those after a gap in
    contact during which the foot's heel and toe were both, at some frame, higher above their floor
    than the rule's release height (``FootLockConfig.height_off_m``, 2 cm). A foot that slides out
    of contact on the floor (faster than the rule's release speed) and stops again adds an onset
    but not a lifted step; in the captures the lifted count is 0-14% lower (``docs/quality.md``,
    "Counting steps"); ``stance_fraction``: the fraction of frames a foot is in contact, mean of
    both feet (a walk ~0.6, a run ~0.35; a glide or frozen feet ~1, a hover 0);
    ``slide_per_contact_m``: the median horizontal distance a heel or toe travels during one of its
    contacts (NaN without contacts)."""

    steps_per_s: float
    stance_fraction: float
    slide_per_contact_m: float
    lifted_steps_per_s: float = float("nan")


def step_figures(positions_TxJx3: np.ndarray, skeleton: Motion, fps: float, *, floor_2x2: np.ndarray | None = None
                 ) -> StepFigures:
    """:class:`StepFigures` of global joint positions on ``skeleton`` (file units). ``floor_2x2``:
    planted heights ``[side, heel/toe]``, the clip's own 5th height percentiles when omitted. The
    thresholds are :class:`jaxstyle.output.footlock.FootLockConfig`'s, in the skeleton's body size
    (:func:`jaxstyle.labels.contacts.body_units_per_meter`)."""
    pos = _positions(positions_TxJx3, num_joints=skeleton.num_joints)
    _check_scale(1.0, fps)
    feet = FootJoints.find(skeleton)
    points = footlock.points_of(pos, feet)  # (T, 2, 2, 3)
    floor = (np.percentile(points[..., UP_AXIS], FLOOR_PERCENTILE, axis=0) if floor_2x2 is None
             else np.asarray(floor_2x2, dtype=np.float64))
    units = body_units_per_meter(skeleton, feet)
    contact = footlock.detect_contacts(points, units_per_meter=units, fps=fps, floor_2x2=floor)
    foot = contact.any(axis=2)  # (T, 2)
    # the rule decides nothing before it has seen min_on frames: those take the first decision
    first = min(len(foot) - 1, max(1, int(round(footlock.FootLockConfig().min_on_s * fps))))
    if first > 0:
        foot[:first] = foot[first]
    seconds = len(pos) / float(fps)
    onsets = int(np.sum(foot[1:] & ~foot[:-1])) if len(foot) > 1 else 0
    # an onset ends a lift when, during the gap before it, heel and toe both cleared the release height
    clear = (points[..., UP_AXIS] - floor).min(axis=2) > footlock.FootLockConfig().height_off_m * units  # (T, 2)
    lifted = 0
    for side in range(2):
        starts, ends = runs(~foot[:, side])
        lifted += sum(bool(clear[s:e, side].any()) for s, e in zip(starts, ends, strict=True) if e < len(foot))
    upm = estimate_units_per_meter(skeleton)
    slides = []
    ground = points[..., list(GROUND_AXES)]
    for side in range(2):
        for k in range(2):
            starts, ends = runs(contact[:, side, k])
            for s, e in zip(starts, ends, strict=True):
                if e - s >= 2:
                    step = np.linalg.norm(np.diff(ground[s:e, side, k], axis=0), axis=-1)
                    slides.append(float(np.sum(step)) / upm)
    return StepFigures(onsets / seconds if seconds > 0 else float("nan"),
                       float(foot.mean()) if len(foot) else float("nan"),
                       float(np.median(slides)) if slides else float("nan"),
                       lifted / seconds if seconds > 0 else float("nan"))


def foot_offset_max_m(before_TxJx3: np.ndarray, after_TxJx3: np.ndarray, skeleton: Motion, *,
                      units_per_meter: float) -> float:
    """The largest distance (m) between a foot joint (ankle or toe) after foot locking and the same
    joint before it: how far the post-process moved a foot from where the network put it."""
    joints = _foot_joints(skeleton)
    a, b = _positions(before_TxJx3, "before_TxJx3"), _positions(after_TxJx3, "after_TxJx3")
    if a.shape != b.shape:
        raise ValueError(f"before_TxJx3 and after_TxJx3 differ in shape: {a.shape} and {b.shape}")
    _check_scale(units_per_meter)
    return float(np.max(np.linalg.norm(a[:, joints] - b[:, joints], axis=-1))) / units_per_meter if len(a) else 0.0


def foot_below_floor_m(positions_TxJx3: np.ndarray, skeleton: Motion, floor_2x2: np.ndarray, *,
                       units_per_meter: float) -> float:
    """The deepest (m) any heel or toe goes below its planted height ``floor_2x2`` (``[side,
    heel/toe]``, e.g. :func:`jaxstyle.output.footlock.skeleton_floor` of the training skeleton); 0
    when none does."""
    pos = _positions(positions_TxJx3, num_joints=skeleton.num_joints)
    _check_scale(units_per_meter)
    heights = footlock.points_of(pos, FootJoints.find(skeleton))[..., UP_AXIS]
    depth = np.asarray(floor_2x2, dtype=np.float64)[None] - heights
    return max(0.0, float(np.max(depth))) / units_per_meter if len(pos) else 0.0
