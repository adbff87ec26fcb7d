"""What the quality benchmark measures of one generated character: its rollout as the user gets it
(:func:`exported`: the network's joints, the exported BVH skeleton before and after foot locking,
and for comparison the plain contact IK), and the figures of it along its path (:func:`measure`) or
of real capture (:func:`capture_figures`): foot skating of the network's joints, of the BVH and
after locking; stepping (:data:`LOCK_FIGURES`); how far the lock moved a foot and how deep a foot
goes below the floor; bone error; the largest network-to-BVH joint distance; path and heading
error; time to stop; jitter and ankle jerk; where the remaining sliding happens
(:func:`sliding_sources`). :mod:`jaxstyle.output.quality` runs the benchmark over many characters,
:mod:`jaxstyle.output.synthesis` writes the same figures beside its files.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import numpy as np

from jaxstyle.control import paths
from jaxstyle.control.model import Frames
from jaxstyle.labels.contacts import (
    ContactConfig,
    FootJoints,
    body_units_per_meter,
    estimate_units_per_meter,
    foot_contacts,
)
from jaxstyle.motion import Motion
from jaxstyle.motion.kinematics import global_positions
from jaxstyle.output import export, footlock, metrics


class Exported(NamedTuple):
    """A rollout as the user gets it: the network's joints ``net``, the exported skeleton's joints
    before (``bvh``) and after foot locking (``locked``, what the BVH file holds), the lock's
    :class:`jaxstyle.output.footlock.LockedMotion` (``None`` when the outputs are not finite), and
    for comparison ``pinned``: the skeleton after the plain contact IK of the 2022 paper's section
    4.4 (:func:`pinned_feet`); ``floor_2x2``, the training skeleton's planted heights the lock and
    the floor figures use."""

    net: np.ndarray
    bvh: np.ndarray | None
    locked: np.ndarray | None
    lock: Any
    pinned: np.ndarray | None
    floor_2x2: np.ndarray


def raised_to_floor(positions_TxJx3: np.ndarray, skeleton: Motion, floor_2x2: np.ndarray) -> np.ndarray:
    """The positions with every heel and toe below its planted height ``floor_2x2`` (``[side,
    heel/toe]``, e.g. :func:`jaxstyle.output.footlock.skeleton_floor` of the training skeleton)
    raised onto it, nothing else changed: what the floor alone does to the skating figure (feet
    that glide through the floor glide on it)."""
    out = np.array(positions_TxJx3, dtype=np.float64, copy=True)
    feet, floor = FootJoints.find(skeleton), np.asarray(floor_2x2, dtype=np.float64)
    for side in range(2):
        for k, j in enumerate((feet.ankles[side], feet.toes[side])):
            out[:, j, 1] = np.maximum(out[:, j, 1], floor[side, k])
    return out


def pinned_feet(motion: Motion, rollout) -> Motion:
    """The baseline post-process: heels and toes pinned while the network's predicted contact
    labels are on (:func:`jaxstyle.output.footik.fix_foot_sliding`, 5 blend frames), or, for a model
    without contact outputs, while within 1 cm of the floor for at least 0.1 s; no speed test,
    no reach limit."""
    from jaxstyle.output import footik

    contacts = export.network_contacts(rollout, motion.num_joints)
    if contacts is None:
        c = foot_contacts(motion, ContactConfig(speed_threshold=None, min_duration=0.1))
        contacts = np.concatenate([c.heel, c.toe], axis=1)
    return footik.fix_foot_sliding(motion, contacts, blend_frames=5, pin_toes=True)


def exported(rollout: Frames, skeleton: Motion,
             floor_2x2: np.ndarray | None = None) -> Exported:
    """:class:`Exported` of one character's rollout of any model (the network's joints are the
    skeleton's: an LPN rollout's extra hand points are left out). ``floor_2x2``: the skeleton's
    planted heights (:func:`jaxstyle.output.footlock.skeleton_floor`, computed when omitted; pass
    it to measure many rollouts on one skeleton)."""
    floor = footlock.skeleton_floor(skeleton) if floor_2x2 is None else np.asarray(floor_2x2)
    net = np.asarray(rollout.positions, dtype=np.float64)[:, :skeleton.num_joints]
    if not np.isfinite(np.asarray(rollout.outputs)).all():
        return Exported(net, None, None, None, None, floor)
    motion = export.rollout_motion(rollout, skeleton)
    lock = export.lock_feet(motion, rollout, floor_2x2=floor)
    return Exported(net, global_positions(motion), global_positions(lock.motion), lock,
                    global_positions(pinned_feet(motion, rollout)), floor)


LOCK_FIGURES = ("steps_per_s", "stance_fraction", "slide_per_contact_m", "lifted_steps_per_s", "steps_per_s_bvh",
                "ik_foot_offset_max_m", "foot_below_floor_m")
"""The stepping and foot-lock columns of :func:`measure` (``steps_per_s``, ``stance_fraction``,
``slide_per_contact_m`` and ``lifted_steps_per_s`` of the locked skeleton,
:func:`jaxstyle.output.metrics.step_figures`; ``steps_per_s_bvh`` before locking)."""


def measure(rollout: Frames, skeleton: Motion, signal: paths.PathSignal, *,
            units_per_meter: float, out: Exported | None = None) -> dict:
    """The figures of one character's rollout along ``signal`` (see the module docstring), of any
    model: the network's joints, the exported skeleton (the BVH's,
    :func:`jaxstyle.output.export.rollout_motion` decodes both models' outputs) and the same after
    foot locking (:func:`jaxstyle.output.export.lock_feet`, the network's own contacts starting
    locks when it predicts them): skating of all three, stepping of the locked skeleton
    (:data:`LOCK_FIGURES`), how far the lock moved a foot and how deep a foot goes below the
    training skeleton's floor; and for comparison the same of the plain contact IK
    (:func:`pinned_feet`, ``*_pinned`` columns). ``out``: :func:`exported` of the rollout, if already
    computed."""
    upm, fps = float(units_per_meter), float(signal.fps)
    e = exported(rollout, skeleton) if out is None else out
    net = e.net
    nan = float("nan")
    row = {"foot_skating_m_s": nan, "foot_skating_bvh_m_s": nan, "foot_skating_locked_m_s": nan}
    if e.bvh is None:
        return {**row, "finite": False}
    bvh, after = e.bvh, e.locked
    bones = metrics.bone_length_errors(net, skeleton)
    err = np.linalg.norm(np.asarray(rollout.origin) - signal.positions, axis=-1) / upm
    length = float(np.sum(np.linalg.norm(signal.velocity, axis=1)) / fps / upm)
    stops = metrics.stop_times(rollout.origin, signal.velocity, fps, units_per_meter=upm)
    q = metrics.motion_quality(net, skeleton, fps, units_per_meter=upm)
    steps = metrics.step_figures(after, skeleton, fps)
    return {
        "finite": True,
        "foot_skating_m_s": metrics.foot_skating(net, skeleton, fps, units_per_meter=upm),
        "foot_skating_bvh_m_s": metrics.foot_skating(bvh, skeleton, fps, units_per_meter=upm),
        "foot_skating_locked_m_s": metrics.foot_skating(after, skeleton, fps, units_per_meter=upm),
        "contact_fraction": q.contact_fraction,
        **dataclasses.asdict(steps),
        "steps_per_s_bvh": metrics.step_figures(bvh, skeleton, fps).steps_per_s,
        "ik_foot_offset_max_m": metrics.foot_offset_max_m(bvh, after, skeleton, units_per_meter=upm),
        "foot_below_floor_m": metrics.foot_below_floor_m(after, skeleton, e.floor_2x2,
                                                         units_per_meter=upm),
        "bone_error_mean": float(np.mean(bones)), "bone_error_max": float(np.max(bones)),
        "bone_error_bvh_max": float(np.max(metrics.bone_length_errors(bvh, skeleton))),
        "joint_difference_max_m": metrics.max_joint_difference_m(net, bvh, units_per_meter=upm),
        "path_error_mean_m": float(np.mean(err)), "path_error_final_m": float(err[-1]),
        "path_error_final_pct": 100.0 * float(err[-1]) / length if length > 0 else nan,
        "heading_error_deg": metrics.heading_error_deg(rollout.yaw, signal.yaw),
        "stop_time_s": float(np.max(stops)) if len(stops) else nan, "stop_commands": int(len(stops)),
        "jitter_m_s3": q.jitter_m_s3,
        "ankle_jerk_m_s3": metrics.foot_jerk(net, skeleton, fps, units_per_meter=upm),
        "foot_skating_floor_m_s": metrics.foot_skating(raised_to_floor(bvh, skeleton, e.floor_2x2), skeleton, fps,
                                                       units_per_meter=upm),
        "ankle_jerk_bvh_m_s3": metrics.foot_jerk(bvh, skeleton, fps, units_per_meter=upm),
        "ankle_jerk_locked_m_s3": metrics.foot_jerk(after, skeleton, fps, units_per_meter=upm),
        **({} if e.pinned is None else {
            "foot_skating_pinned_m_s": metrics.foot_skating(e.pinned, skeleton, fps, units_per_meter=upm),
            "steps_per_s_pinned": metrics.step_figures(e.pinned, skeleton, fps).steps_per_s,
            "ik_foot_offset_max_pinned_m": metrics.foot_offset_max_m(bvh, e.pinned, skeleton, units_per_meter=upm),
            "ankle_jerk_pinned_m_s3": metrics.foot_jerk(e.pinned, skeleton, fps, units_per_meter=upm)}),
        **{f"sliding_{k.replace(', ', '_')}": v for k, v in sliding_sources(e, skeleton, fps).items()},
    }


def capture_figures(clip: Motion) -> dict:
    """:func:`measure`'s figures of real motion (its skeleton is its BVH: the network, BVH and
    locked columns are the same, the lock moved nothing; the floor is its own; no path, so the
    path figures are NaN)."""
    upm, fps = estimate_units_per_meter(clip), clip.fps
    pos = global_positions(clip)
    q = metrics.motion_quality(pos, clip, fps, units_per_meter=upm)
    skate = q.foot_skating_m_s
    jerk = metrics.foot_jerk(pos, clip, fps, units_per_meter=upm)
    steps = metrics.step_figures(pos, clip, fps)
    nan = float("nan")
    return {"speed_m_s": nan, "finite": True,
            "foot_skating_m_s": skate, "foot_skating_bvh_m_s": skate, "foot_skating_locked_m_s": skate,
            "contact_fraction": q.contact_fraction, **dataclasses.asdict(steps), "steps_per_s_bvh": steps.steps_per_s,
            "ik_foot_offset_max_m": 0.0,
            "foot_below_floor_m": metrics.foot_below_floor_m(pos, clip, footlock.skeleton_floor(clip),
                                                             units_per_meter=upm),
            "bone_error_mean": q.bone_error_mean,
            "bone_error_max": q.bone_error_max, "bone_error_bvh_max": q.bone_error_max, "joint_difference_max_m": 0.0,
            "path_error_mean_m": nan, "path_error_final_m": nan, "path_error_final_pct": nan,
            "heading_error_deg": nan, "stop_time_s": nan, "jitter_m_s3": q.jitter_m_s3, "ankle_jerk_m_s3": jerk,
            "ankle_jerk_bvh_m_s3": jerk, "ankle_jerk_locked_m_s3": jerk}


SLIDING_SOURCES = ("held", "easing", "free, slow", "free, fast")
"""Where the skating left after foot locking comes from (:func:`sliding_sources`)."""


def sliding_sources(e: Exported, skeleton: Motion, fps: float) -> dict[str, float]:
    """Split the skating of the locked skeleton (:func:`jaxstyle.output.metrics.foot_skating`: the
    horizontal travel of heels and toes over frame steps they spend within 1 cm of their floor) by
    what the lock was doing with that point: ``held`` (locked in both frames), ``easing`` (free,
    its offset from a release or hand-over still decaying, over 1 mm), ``free, slow`` (free, the
    network's point slower than the touch-down speed) and ``free, fast`` (free, the network's point
    moving along the floor faster than a contact may start). Returns each share of the total
    travel (summing to 1; NaN without such steps)."""
    feet = FootJoints.find(skeleton)
    locked_pts = footlock.points_of(e.locked, feet)  # (T, 2, 2, 3)
    net_pts = footlock.points_of(e.bvh, feet)
    h = locked_pts[..., 1]
    on = h <= np.percentile(h, 5, axis=0) + metrics.TOLERANCE_M * estimate_units_per_meter(skeleton)
    planted = on[1:] & on[:-1]
    travel = np.linalg.norm(np.diff(locked_pts[..., [0, 2]], axis=0), axis=-1)
    held = e.lock.frames.locked[1:] & e.lock.frames.locked[:-1]
    drawn = np.stack([e.lock.frames.ankle, e.lock.frames.toe], axis=2)
    body = body_units_per_meter(skeleton, feet)
    easing = np.linalg.norm(drawn - net_pts, axis=-1)[1:] > 0.001 * body
    speed = np.linalg.norm(np.diff(net_pts[..., [0, 2]], axis=0), axis=-1) * fps / body
    fast = speed >= footlock.FootLockConfig().speed_on_m_s
    parts = {"held": held, "easing": ~held & easing, "free, slow": ~held & ~easing & ~fast,
             "free, fast": ~held & ~easing & fast}
    total = float(np.sum(travel[planted]))
    return {k: float(np.sum(travel[planted & m])) / total if total > 0 else float("nan") for k, m in parts.items()}
