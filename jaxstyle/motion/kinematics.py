"""Forward kinematics, skeleton measures, root ground trajectory and facing direction.

All functions are vectorised over frames; the only Python loop is over the skeleton's depth
levels (about 10), each level processing all its joints for all frames at once.
"""

from __future__ import annotations

import functools

import numpy as np

from jaxstyle.errors import MotionDataError
from jaxstyle.motion import Motion, quat, skeleton

UP_AXIS = 1  # jaxstyle works Y-up; use transform.set_up_axis for files that are not.


@functools.lru_cache(maxsize=64)
def _depth_levels(parents: tuple[int, ...]) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    depth = np.zeros(len(parents), dtype=np.int64)
    for j, p in enumerate(parents):
        depth[j] = 0 if p < 0 else depth[p] + 1
    levels = []
    for d in range(1, int(depth.max(initial=0)) + 1):
        idx = np.flatnonzero(depth == d)
        levels.append((idx, np.asarray(parents, dtype=np.int64)[idx]))
    return tuple(levels)


def forward_kinematics(rotations_TxJx4: np.ndarray, local_positions_TxJx3: np.ndarray,
                       parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations ``(T, J, 4)`` and positions ``(T, J, 3)`` from local ones.

    ``global_rot[j] = global_rot[parent] * local_rot[j]`` and
    ``global_pos[j] = global_pos[parent] + rotate(global_rot[parent], local_pos[j])``.
    Roots (parent ``-1``) keep their local values.
    """
    g_rot = np.array(rotations_TxJx4, dtype=np.float64, copy=True)
    g_pos = np.array(local_positions_TxJx3, dtype=np.float64, copy=True)
    for idx, par in _depth_levels(tuple(int(p) for p in parents)):
        p_rot = g_rot[:, par]
        g_pos[:, idx] = g_pos[:, par] + quat.rotate(p_rot, g_pos[:, idx])
        g_rot[:, idx] = quat.mul(p_rot, g_rot[:, idx])
    return g_rot, g_pos


def global_transforms(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Global joint rotations ``(T, J, 4)`` and positions ``(T, J, 3)`` of a motion."""
    return forward_kinematics(motion.rotations, motion.local_positions, motion.parents)


def global_positions(motion: Motion, end_sites: bool = False) -> np.ndarray:
    """Global joint positions ``(T, J, 3)``; with ``end_sites=True``, ``(T, J + E, 3)``."""
    g_rot, g_pos = global_transforms(motion)
    if not end_sites:
        return g_pos
    return np.concatenate([g_pos, end_site_positions(motion, g_rot, g_pos)], axis=1)


def end_site_positions(motion: Motion, g_rot: np.ndarray, g_pos: np.ndarray) -> np.ndarray:
    """``(T, E, 3)`` end-site positions from already computed global joint transforms."""
    p = motion.end_site_parents
    if len(p) == 0:
        return np.zeros(g_pos.shape[:1] + (0, 3))
    return g_pos[:, p] + quat.rotate(g_rot[:, p], np.broadcast_to(motion.end_site_offsets, g_pos[:, p].shape))


def motion_from_global(skeleton: Motion, rotations_TxJx4: np.ndarray, root_positions_TxRx3: np.ndarray) -> Motion:
    """A :class:`Motion` on ``skeleton``'s hierarchy from global joint rotations and root positions.

    Local rotations are ``inverse(global[parent]) * global[joint]``; non-root joints keep the
    skeleton's offsets (bones have fixed lengths); roots take the given positions. The inverse
    of :func:`global_transforms` for skeletons without per-frame joint translations.
    """
    g_rot = np.asarray(rotations_TxJx4, dtype=np.float64)
    parents = skeleton.parents
    has_parent = parents >= 0
    local_rot = g_rot.copy()
    local_rot[:, has_parent] = quat.mul(quat.inverse(g_rot[:, parents[has_parent]]), g_rot[:, has_parent])
    local_pos = np.broadcast_to(skeleton.offsets, g_rot.shape[:2] + (3,)).copy()
    local_pos[:, ~has_parent] = root_positions_TxRx3
    return skeleton.replace(rotations=local_rot, local_positions=local_pos, source=None)


def rest_positions(motion: Motion, end_sites: bool = True) -> np.ndarray:
    """Joint (and end-site) positions ``(J [+ E], 3)`` of the rest pose: identity rotations, offsets only."""
    rest = motion.replace(rotations=quat.identity((1, motion.num_joints)),
                          local_positions=motion.offsets[None].copy())
    return global_positions(rest, end_sites=end_sites)[0]


def skeleton_height(motion: Motion) -> float:
    """Height of the rest pose along the up axis (end sites included), in file units.

    Used as the length scale of tolerances ("within 1e-4 of skeleton height").
    """
    pts = rest_positions(motion)
    height = float(np.ptp(pts[:, UP_AXIS]))
    if height <= 0:  # a flat skeleton: fall back to its largest extent
        height = float(np.max(np.ptp(pts, axis=0)))
    return height


def bone_lengths(motion: Motion) -> np.ndarray:
    """``(J,)`` length of each joint's offset (0 for roots)."""
    lengths = np.linalg.norm(motion.offsets, axis=-1)
    return np.where(motion.parents < 0, 0.0, lengths)


def root_trajectory(motion: Motion, root: int | str = 0) -> np.ndarray:
    """``(T, 3)`` ground trajectory: the root joint's global position projected to the floor (y = 0)."""
    j = motion.joint_index(root) if isinstance(root, str) else int(root)
    pos = global_positions(motion)[:, j].copy()
    pos[:, UP_AXIS] = 0.0
    return pos


def facing_directions(motion: Motion, *, hips: tuple[str, str] | None = None,
                      shoulders: tuple[str, str] | None = None, smooth_sigma: float = 0.0,
                      positions_TxJx3: np.ndarray | None = None) -> np.ndarray:
    """``(T, 3)`` unit facing direction on the ground plane (y = 0).

    As in Holden et al. 2017 (which both papers follow): the across vector is
    ``(left_shoulder - right_shoulder) + (left_hip - right_hip)``; facing is ``across x up``,
    i.e. the direction the chest and pelvis point to.

    Args:
      hips, shoulders: ``(left, right)`` joint names; found from the names when omitted (see
        :func:`jaxstyle.motion.skeleton.find_hips_and_shoulders`).
      smooth_sigma: optional Gaussian smoothing over frames (in frames; the PFNN code uses 20 at
        60 fps) applied to the across vector before normalising.
      positions_TxJx3: global positions, if already computed.

    Frames where the across vector is degenerate (vertical or zero) take the root's own forward
    axis projected to the ground, so the result is always finite and unit length.
    """
    if hips is None or shoulders is None:
        found_hips, found_shoulders = skeleton.find_hips_and_shoulders(motion.names, motion.source,
                                                                            motion.joint_map)
        hips = hips or found_hips
        shoulders = shoulders or found_shoulders
    pos = global_positions(motion) if positions_TxJx3 is None else positions_TxJx3
    lh, rh, ls, rs = motion.joint_indices([hips[0], hips[1], shoulders[0], shoulders[1]])
    across = (pos[:, ls] - pos[:, rs]) + (pos[:, lh] - pos[:, rh])
    if smooth_sigma > 0:
        from scipy.ndimage import gaussian_filter1d

        across = gaussian_filter1d(across, smooth_sigma, axis=0, mode="nearest")
    up = np.zeros(3)
    up[UP_AXIS] = 1.0
    fwd = np.cross(across, up)
    fwd[:, UP_AXIS] = 0.0
    norm = np.linalg.norm(fwd, axis=-1, keepdims=True)
    scale = max(float(np.median(np.linalg.norm(across, axis=-1))), 1e-12)
    bad = norm[:, 0] < 1e-6 * scale
    if np.any(bad):
        root_fwd = quat.forward(motion.rotations[:, 0])  # joint 0 is a root: local == global
        root_fwd[:, UP_AXIS] = 0.0
        root_norm = np.linalg.norm(root_fwd, axis=-1, keepdims=True)
        root_fwd = np.where(root_norm > 1e-9, root_fwd / np.maximum(root_norm, 1e-12), np.array([0.0, 0.0, 1.0]))
        fwd[bad], norm[bad] = root_fwd[bad], 1.0
    out = fwd / norm
    if not np.isfinite(out).all():
        raise MotionDataError("facing direction is not finite (NaN in joint positions?)", motion.source)
    return out
