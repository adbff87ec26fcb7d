"""Generated motion out of jaxstyle: a :class:`jaxstyle.Motion` on the source skeleton, BVH files
(importable in Blender and other tools) and ``.npz`` arrays.

A rollout of :mod:`jaxstyle.control.controller` (PFNN) or :mod:`jaxstyle.control.lpn_controller` (LPN, MANN)
records the de-normalised network outputs. :func:`rollout_motion` decodes them with the feature
decoders (:func:`jaxstyle.decode_pfnn`, :func:`jaxstyle.decode_lpn`): joint rotations come from
the predicted forward and up vectors, the root from the predicted root motion, and every other
joint keeps the skeleton's bone offsets, so bone lengths are exact in the BVH (the predicted joint
positions, which nothing ties to the skeleton, are kept in the ``.npz``). The character starts at
the origin facing +Z, as the controllers' :func:`initial_state` does; frame ``t`` of the motion is
generated frame ``t``.

Optionally the feet (heels and toes) are pinned while in contact
(:func:`jaxstyle.output.footik.fix_foot_sliding`, the 2022 paper's post-process, section 4.4), with the
network's predicted contact labels (the LPN's; the PFNN's when trained with the 2018 layout's
contact outputs) or contacts labelled on the decoded motion by height. Forward kinematics of the
exported motion is what :mod:`jaxstyle.output.quality` measures, so what a user sees in Blender is
what is measured.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jaxstyle.control.controller import Rollout
from jaxstyle.control.lpn_controller import LPNRollout
from jaxstyle.data.lpn_features import decode_lpn
from jaxstyle.data.pfnn_features import decode_pfnn, output_contacts
from jaxstyle.labels.contacts import foot_contacts
from jaxstyle.motion import Motion
from jaxstyle.motion.bvh import write_bvh
from jaxstyle.output import footik


def _check_single(rollout) -> None:
    if np.ndim(rollout.yaw) != 1:
        raise ValueError(f"export one character at a time: this rollout has shape {np.shape(rollout.yaw)} yaw values "
                         "(take one with jax.tree.map(lambda v: v[i], rollout))")


def rollout_motion(rollout: Rollout | LPNRollout, skeleton: Motion, *, fps: float | None = None) -> Motion:
    """The :class:`Motion` of one character's rollout on ``skeleton`` (the training data's), at
    ``fps`` (default the skeleton's)."""
    _check_single(rollout)
    outputs = np.asarray(rollout.outputs, dtype=np.float64)
    if not np.isfinite(outputs).all():
        bad = int(np.flatnonzero(~np.isfinite(outputs).all(axis=1))[0])
        raise ValueError(f"the rollout's outputs are not finite from frame {bad} on; nothing to export")
    if isinstance(rollout, LPNRollout):
        motion = decode_lpn(outputs, skeleton)
    elif isinstance(rollout, Rollout):
        motion = decode_pfnn(outputs, skeleton)[0]
    else:
        raise TypeError(f"expected a controller Rollout or an LPNRollout, got {type(rollout).__name__}")
    return motion.replace(fps=float(fps or skeleton.fps), source=None)


def fix_feet(motion: Motion, rollout: Rollout | LPNRollout, *, blend_frames: int = 5) -> Motion:
    """``motion`` with its heels and toes pinned while in contact
    (:func:`jaxstyle.output.footik.fix_foot_sliding`, ``pin_toes``): the network's predicted
    contacts when it has them (the LPN's two foot labels; the heel and toe labels of a PFNN with
    the 2018 layout's contact outputs, :func:`jaxstyle.data.pfnn_features.output_contacts`),
    otherwise heel and toe contacts labelled on the motion itself by height alone (within the
    paper's 1 cm of the floor, runs of at least 0.1 s). The paper's speed test is left out there:
    a generated foot that slides is exactly the one to pin, and it would fail it."""
    contacts = None
    if isinstance(rollout, LPNRollout):
        contacts = np.asarray(rollout.contacts, dtype=np.float64)
    else:
        contacts = output_contacts(np.asarray(rollout.outputs), motion.num_joints)
    if contacts is None:
        c = foot_contacts(motion, speed_threshold=None, min_duration=0.1)
        contacts = np.concatenate([c.heel, c.toe], axis=1)
    return footik.fix_foot_sliding(motion, contacts, blend_frames=blend_frames, pin_toes=True)


def save_rollout(path: str | os.PathLike, rollout: Rollout | LPNRollout, skeleton: Motion, *,
                 foot_ik: bool = False, fps: float | None = None, motion: Motion | None = None) -> dict[str, Path]:
    """Write ``<path>.bvh`` (the decoded motion, feet pinned when ``foot_ik``; or ``motion`` when
    given, e.g. one already post-processed) and ``<path>.npz`` (the network's global joint
    ``positions (T, B, 3)``, ground ``origin (T, 2)``, ``yaw (T,)``, ``phase`` (global ``(T,)`` or
    local ``(T, 8)``), ``contacts`` (LPN), the de-normalised ``outputs``, ``fps``, and the
    skeleton's joint ``names`` and ``parents``). Returns both paths."""
    base = Path(path)
    base.parent.mkdir(parents=True, exist_ok=True)
    if motion is None:
        motion = rollout_motion(rollout, skeleton, fps=fps)
        if foot_ik:
            motion = fix_feet(motion, rollout)
    bvh_path, npz_path = base.with_suffix(".bvh"), base.with_suffix(".npz")
    write_bvh(motion, bvh_path)
    arrays = {"positions": rollout.positions, "origin": rollout.origin, "yaw": rollout.yaw,
              "outputs": rollout.outputs,
              "phase": rollout.phases if isinstance(rollout, LPNRollout) else rollout.phase}
    if isinstance(rollout, LPNRollout):
        arrays["contacts"] = rollout.contacts
    np.savez(npz_path, **{k: np.asarray(v) for k, v in arrays.items()}, fps=np.float64(motion.fps),
             names=np.array(skeleton.names), parents=np.asarray(skeleton.parents))
    return {"bvh": bvh_path, "npz": npz_path}
