"""Whole-motion transforms: unit scaling, up axis, global rotation, resampling and mirroring."""

from __future__ import annotations

import numpy as np

from jaxstyle.errors import MotionDataError
from jaxstyle.motion import Motion, quat, skeleton

_AXES = {"x": 0, "y": 1, "z": 2}
MAX_UPSAMPLE = 8  # resample() makes a clip at most this many times longer (24 -> 120 frames/s is 5x)


def scale(motion: Motion, factor: float) -> Motion:
    """Scales all lengths (offsets, translations, end sites) by ``factor``, e.g. 0.01 for cm -> m."""
    if not (np.isfinite(factor) and factor > 0):
        raise ValueError(f"scale factor must be a positive number, got {factor}")
    return motion.replace(offsets=motion.offsets * factor, local_positions=motion.local_positions * factor,
                          end_site_offsets=motion.end_site_offsets * factor)


def rotate(motion: Motion, q: np.ndarray) -> Motion:
    """Applies a global rotation ``q`` (``(4,)`` quaternion) to the whole motion about the origin.

    Only root joints change: their rotations are pre-multiplied by ``q`` and their translations
    rotated by it.
    """
    q = quat.normalize(np.asarray(q, dtype=np.float64))
    roots = np.flatnonzero(motion.parents < 0)
    rotations = motion.rotations.copy()
    local_positions = motion.local_positions.copy()
    offsets = motion.offsets.copy()
    rotations[:, roots] = quat.mul(q, rotations[:, roots])
    local_positions[:, roots] = quat.rotate(q, local_positions[:, roots])
    offsets[roots] = quat.rotate(q, offsets[roots])
    return motion.replace(rotations=rotations, local_positions=local_positions, offsets=offsets)


def _axis_vector(axis: str) -> np.ndarray:
    axis = axis.strip().lower()
    sign = -1.0 if axis.startswith("-") else 1.0
    name = axis.lstrip("+-")
    if name not in _AXES:
        raise ValueError(f"axis must be one of x, y, z (optionally signed), got {axis!r}")
    v = np.zeros(3)
    v[_AXES[name]] = sign
    return v


def set_up_axis(motion: Motion, up: str = "y") -> Motion:
    """Converts a motion whose up axis is ``up`` (e.g. ``"z"`` or ``"-y"``) to jaxstyle's Y-up frame.

    The shortest rotation taking ``up`` onto +Y is applied (for ``"z"``: -90 degrees about X, so
    +Z becomes +Y and +Y becomes -Z). ``"y"`` returns the motion unchanged.
    """
    u = _axis_vector(up)
    if np.array_equal(u, [0.0, 1.0, 0.0]):
        return motion
    return rotate(motion, quat.between(u, np.array([0.0, 1.0, 0.0])))


def resample(motion: Motion, fps: float) -> Motion:
    """Resamples to ``fps``: rotations by slerp, translations linearly, at times ``k / fps``.

    When the source rate is an integer multiple of ``fps`` (120 -> 60, as both papers do), the
    sample times fall exactly on source frames, so this is plain frame dropping (every 2nd frame).
    The last sample is the last one at or before the clip's final frame.

    Raises:
      MotionDataError: ``fps`` is more than :data:`MAX_UPSAMPLE` times the clip's rate (the
        resampled clip would be that many times longer: a memory bound, not a quality one).
    """
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"target fps must be a positive number, got {fps}")
    if fps > MAX_UPSAMPLE * motion.fps:
        raise MotionDataError(
            f"the clip runs at {motion.fps:.4g} frames/s; resampling it to {fps:g} would make it "
            f"{fps / motion.fps:.0f} times longer (at most {MAX_UPSAMPLE}x)", motion.source or None)
    ratio = motion.fps / fps
    n_out = int(np.floor((motion.num_frames - 1) / ratio + 1e-9)) + 1
    src = np.arange(n_out) * ratio
    nearest = np.round(src)
    src = np.where(np.abs(src - nearest) < 1e-9, nearest, src)
    i0 = np.clip(np.floor(src).astype(np.int64), 0, motion.num_frames - 1)
    i1 = np.minimum(i0 + 1, motion.num_frames - 1)
    w = (src - i0)[:, None]
    rot = quat.slerp(motion.rotations[i0], motion.rotations[i1], w)
    pos = motion.local_positions[i0] * (1.0 - w[..., None]) + motion.local_positions[i1] * w[..., None]
    return motion.replace(rotations=rot, local_positions=pos, fps=float(fps))


def mirror(motion: Motion, axis: str = "x", pairs: np.ndarray | None = None) -> Motion:
    """Mirrors a motion: reflects it through the plane normal to ``axis`` and swaps left and right.

    For a Y-up clip the default reflection ``x -> -x`` is the reflection through the character's
    sagittal plane up to a rigid motion of the whole clip, which root-relative features do not
    see; it is also what the papers' mirrored data does (trajectories with x negated).

    Exact for any skeleton: with ``M`` the reflection and ``s(j)`` the counterpart of joint ``j``,
    the mirrored clip's global joint positions are ``M @ p[s(j)]``. Local rotations become
    ``M R M`` (quaternion ``(w, x, -y, -z)`` for the x-axis) of the counterpart, and offsets
    ``M @ offset[s(j)]``, so an asymmetric skeleton is mirrored too. Mirroring twice is the
    identity.

    Args:
      pairs: counterpart of each joint; found from the joint names (and the motion's
        ``joint_map``) when omitted (:func:`jaxstyle.motion.skeleton.mirror_pairs`).
    """
    if pairs is None:
        pairs = skeleton.mirror_pairs(motion.names, motion.source, motion.joint_map)
    pairs = np.asarray(pairs)
    if pairs.shape != (motion.num_joints,):
        raise MotionDataError(f"pairs must have shape ({motion.num_joints},), got {pairs.shape}", motion.source)
    if np.any(motion.parents[pairs] != np.where(motion.parents < 0, -1, pairs[motion.parents])):
        bad = [motion.names[j] for j in np.flatnonzero(
            motion.parents[pairs] != np.where(motion.parents < 0, -1, pairs[motion.parents]))]
        raise MotionDataError("left/right pairs are not consistent with the hierarchy (a joint's counterpart must "
                              f"hang from its parent's counterpart; not so for {', '.join(bad[:6])}); name the pairs "
                              "the names do not say in a joint map (--joint-map FILE)", motion.source)
    refl = -_axis_vector(axis)  # diagonal of M: -1 on the axis, +1 elsewhere
    refl = np.where(refl == 0, 1.0, refl)
    # A reflection conjugates rotations: the axis (a pseudovector) maps to -M v.
    q_sign = np.concatenate([[1.0], -refl])
    end_pairs = _end_site_pairs(motion, pairs)
    return motion.replace(
        offsets=motion.offsets[pairs] * refl,
        rotations=motion.rotations[:, pairs] * q_sign,
        local_positions=motion.local_positions[:, pairs] * refl,
        end_site_offsets=motion.end_site_offsets[end_pairs] * refl,
    )


def _end_site_pairs(motion: Motion, pairs: np.ndarray) -> np.ndarray:
    """Counterpart of each end site: the k-th end site of a joint pairs with the k-th of its counterpart."""
    parents = motion.end_site_parents
    by_parent: dict[int, list[int]] = {}
    for e, p in enumerate(parents):
        by_parent.setdefault(int(p), []).append(e)
    out = np.arange(len(parents))
    for e, p in enumerate(parents):
        mine = by_parent[int(p)]
        theirs = by_parent.get(int(pairs[p]), [])
        if len(theirs) != len(mine):
            raise MotionDataError(
                f"joint {motion.names[p]!r} and its counterpart {motion.names[pairs[p]]!r} have different "
                "numbers of end sites; cannot mirror", motion.source)
        out[e] = theirs[mine.index(e)]
    return out
