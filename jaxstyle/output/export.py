"""Generated motion out of jaxstyle: a :class:`jaxstyle.Motion` on the source skeleton, BVH files
(importable in Blender and other tools) and ``.npz`` arrays.

A rollout of any :class:`jaxstyle.control.model.CharacterModel` (the PFNN of
:mod:`jaxstyle.control.controller`, the LPN, MANN and PFNN-backbone style models of
:mod:`jaxstyle.control.lpn_controller`) records the de-normalised network outputs, and its frames
decode themselves (:meth:`jaxstyle.control.model.Frames.decode`: the feature decoders
:func:`jaxstyle.decode_pfnn`, :func:`jaxstyle.decode_lpn`): joint rotations come from
the predicted forward and up vectors, the root from the predicted root motion, and every other
joint keeps the skeleton's bone offsets, so bone lengths are exact in the BVH (the predicted joint
positions, which nothing ties to the skeleton, are kept in the ``.npz``). The character starts at
the origin facing +Z, as the controllers' :func:`initial_state` does; frame ``t`` of the motion is
generated frame ``t``.

By default the feet (heels and toes) are locked while planted (:func:`lock_feet`,
:mod:`jaxstyle.output.footlock`: the 2022 paper's section 4.4 post-process), with contacts decided
from the decoded motion and started also by the network's predicted labels (the LPN's; the PFNN's
when trained with the 2018 layout's contact outputs). Forward kinematics of the
exported motion is what :mod:`jaxstyle.output.quality` measures, so what a user sees in Blender is
what is measured.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jaxstyle.control.model import Frames
from jaxstyle.motion import Motion
from jaxstyle.motion.bvh import write_bvh
from jaxstyle.output import footlock


def _check_single(rollout) -> None:
    if np.ndim(rollout.yaw) != 1:
        raise ValueError(f"export one character at a time: this rollout has shape {np.shape(rollout.yaw)} yaw values "
                         "(take one with jax.tree.map(lambda v: v[i], rollout))")


def rollout_motion(rollout: Frames, skeleton: Motion, *, fps: float | None = None) -> Motion:
    """The :class:`Motion` of one character's rollout on ``skeleton`` (the training data's), at
    ``fps`` (default the skeleton's)."""
    _check_single(rollout)
    outputs = np.asarray(rollout.outputs, dtype=np.float64)
    if not np.isfinite(outputs).all():
        bad = int(np.flatnonzero(~np.isfinite(outputs).all(axis=1))[0])
        raise ValueError(f"the rollout's outputs are not finite from frame {bad} on; nothing to export")
    if not isinstance(rollout, Frames):
        raise TypeError(f"expected a model's rollout frames (jaxstyle.control.model.Frames), got "
                        f"{type(rollout).__name__}")
    motion = rollout.decode(skeleton)
    return motion.replace(fps=float(fps or skeleton.fps), source=None)


def network_contacts(rollout: Frames, num_joints: int) -> np.ndarray | None:
    """The contact labels a rollout's network predicted (:meth:`jaxstyle.control.model.Frames.predicted_contacts`):
    the LPN's two foot labels ``(T, 2)``, the heel and toe labels ``(T, 4)`` of a PFNN with the
    2018 layout's contact outputs, ``None`` for the paper's PFNN layout."""
    return rollout.predicted_contacts(num_joints)


def lock_feet(motion: Motion, rollout: Frames | None = None, *,
              config: footlock.FootLockConfig | None = None, skeleton: Motion | None = None,
              floor_2x2: np.ndarray | None = None) -> footlock.LockedMotion:
    """``motion`` with its feet locked while planted (:func:`jaxstyle.output.footlock.lock_motion`):
    contacts decided from the motion itself, started also by the network's predicted labels when
    ``rollout``'s model has them (:func:`network_contacts`); the floor is ``floor_2x2`` when given,
    else the training ``skeleton``'s (a clip of it, :func:`jaxstyle.output.footlock.skeleton_floor`),
    else the motion's own."""
    contacts = None if rollout is None else network_contacts(rollout, motion.num_joints)
    if floor_2x2 is None and skeleton is not None:
        floor_2x2 = footlock.skeleton_floor(skeleton)
    return footlock.lock_motion(motion, contacts, config=config, floor_2x2=floor_2x2)


def save_rollout(path: str | os.PathLike, rollout: Frames, skeleton: Motion, *,
                 foot_lock: bool = True, fps: float | None = None, motion: Motion | None = None) -> dict[str, Path]:
    """Write ``<path>.bvh`` (the decoded motion, feet locked with ``foot_lock``, :func:`lock_feet`; or ``motion`` when
    given, e.g. one already post-processed) and ``<path>.npz`` (the network's global joint
    ``positions (T, B, 3)``, ground ``origin (T, 2)``, ``yaw (T,)``, ``phase`` (global ``(T,)`` or
    local ``(T, 8)``), ``contacts`` (LPN), the de-normalised ``outputs``, ``fps``, and the
    skeleton's joint ``names`` and ``parents``). Returns both paths."""
    base = Path(path)
    base.parent.mkdir(parents=True, exist_ok=True)
    if motion is None:
        motion = rollout_motion(rollout, skeleton, fps=fps)
        if foot_lock:
            motion = lock_feet(motion, rollout, skeleton=skeleton).motion
    bvh_path, npz_path = base.with_suffix(".bvh"), base.with_suffix(".npz")
    write_bvh(motion, bvh_path)
    arrays = rollout.arrays()
    np.savez(npz_path, **{k: np.asarray(v) for k, v in arrays.items()}, fps=np.float64(motion.fps),
             names=np.array(skeleton.names), parents=np.asarray(skeleton.parents))
    return {"bvh": bvh_path, "npz": npz_path}
