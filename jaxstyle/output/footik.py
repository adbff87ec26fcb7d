"""Foot contact inverse kinematics (Mason, Starke & Komura 2022, section 4.4).

"To reduce foot sliding artifacts we use the predicted foot contact label ... to post-process our
animation with foot contact inverse kinematics." The paper gives no further detail. This module is
the plain reading: pin while the label says contact. What jaxstyle applies by default is
:mod:`jaxstyle.output.footlock` (contacts from the motion, bounded locks, smooth releases, live);
:func:`fix_foot_sliding` stays as the baseline it is measured against
(:func:`jaxstyle.output.measure.pinned_feet`) and :func:`two_bone_ik` is shared. Here:

* **Targets.** While a foot is in contact (its label >= 0.5), its ankle is held where it was at the
  first frame of the contact (all three coordinates). After the contact the offset between the held
  and the original ankle is faded out over ``blend_frames`` frames (smoothstep), so the foot rejoins
  the animation without a jump; a contact that starts while an earlier one is still fading out
  holds the faded position, so nothing jumps there either.
* **Two-bone IK.** The hip (upper leg) and knee rotations are changed analytically so the ankle
  reaches its target: exactly when the target is within reach, otherwise the leg points at it
  (straight when too far, folded when too near). The knee stays on the side of the hip-ankle line
  given by a pole direction, here the original knee's, and bends about the new leg plane's normal,
  so a knee that is a hinge stays a hinge.
* **Toes** (``pin_toes``; the default with heel and toe labels, ``(T, 4)``): after the heels, each
  toe contact run holds the toe joint where it was at the run's start, and the ankle turns
  (shortest arc) so the foot points at it, the same fade-out after the run; optionally
  (``toe_roll``) also while the heel is up, moving the ankle around the held toe.
* **Output.** Local rotations of hip, knee and ankle are rewritten (without toes, the ankle keeps
  its global rotation, so the foot keeps its orientation); forward kinematics then keeps every
  bone length exactly. Frames and joints the IK does not touch keep their rotations bit for bit.

Everything is NumPy and vectorised over frames; the only loops are over the two feet and their
contact runs.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxstyle.errors import MotionDataError
from jaxstyle.labels.contacts import FootContacts, FootJoints, runs
from jaxstyle.motion import Motion, kinematics, quat

_EPS = 1e-12
_STRAIGHT = 1e-2  # a knee closer than this fraction of the thigh to the hip-ankle line reads as a straight leg


class TwoBoneIK(NamedTuple):
    """Result of :func:`two_bone_ik`, all ``(..., k)`` like its inputs.

    ``hip_rotation`` and ``knee_rotation`` are *global* rotation changes ``(..., 4)``: the new global
    rotation of the hip is ``mul(hip_rotation, old_global_hip)``, likewise the knee. ``knee`` and
    ``ankle`` are the new positions ``(..., 3)``.
    """

    hip_rotation: np.ndarray
    knee_rotation: np.ndarray
    knee: np.ndarray
    ankle: np.ndarray


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, _EPS), n[..., 0]


def _orthogonal_part(v: np.ndarray, axis_unit: np.ndarray) -> np.ndarray:
    return v - np.sum(v * axis_unit, axis=-1, keepdims=True) * axis_unit


def _any_perpendicular(u: np.ndarray) -> np.ndarray:
    """A unit vector orthogonal to each unit ``u``."""
    x = np.broadcast_to(np.array([1.0, 0.0, 0.0]), u.shape)
    y = np.broadcast_to(np.array([0.0, 1.0, 0.0]), u.shape)
    pick = np.abs(u[..., :1]) < 0.9
    return _unit(np.cross(u, np.where(pick, x, y)))[0]


def _side(candidates: list[np.ndarray], axis_unit: np.ndarray, rel: float) -> np.ndarray:
    """The first candidate whose part orthogonal to ``axis_unit`` is longer than ``rel`` times the
    candidate, as a unit vector orthogonal to the axis (any perpendicular when none is)."""
    out = _any_perpendicular(axis_unit)
    for cand in reversed(candidates):
        part, norm = _unit(_orthogonal_part(cand, axis_unit))
        out = np.where((norm > rel * np.linalg.norm(cand, axis=-1))[..., None], part, out)
    return out


def _frame(direction: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Orthonormal ``(..., 3, 3)`` with columns ``direction``, ``normal`` (made orthogonal), their cross product."""
    d = _unit(direction)[0]
    n = _unit(_orthogonal_part(normal, d))[0]
    return np.stack([d, n, np.cross(d, n)], axis=-1)


def two_bone_ik(hip_Nx3: np.ndarray, knee_Nx3: np.ndarray, ankle_Nx3: np.ndarray, target_Nx3: np.ndarray,
                pole_Nx3: np.ndarray) -> TwoBoneIK:
    """Analytic two-bone IK of a hip-knee-ankle chain, vectorised over any leading axes.

    Bone lengths are those of the given pose. The ankle lands on ``target`` when
    ``|l1 - l2| <= |target - hip| <= l1 + l2``; otherwise on the nearest reachable point on the
    hip-target line (a straight leg pointing at a far target). The knee lies in the plane of hip,
    target and ``pole`` (a direction from the hip), on the pole's side of the hip-target line. The
    rotations map the old leg plane's normal onto the new one, so the knee only bends about it.
    Degenerate inputs fall back sensibly: a pole along the hip-target line uses the current knee's
    side, a straight current leg the pole's side, a target on the hip the current ankle direction.
    """
    hip, knee, ankle, target, pole = np.broadcast_arrays(
        *[np.asarray(v, dtype=np.float64) for v in (hip_Nx3, knee_Nx3, ankle_Nx3, target_Nx3, pole_Nx3)])
    if hip.shape[-1:] != (3,):
        raise ValueError(f"two_bone_ik needs (..., 3) points, got shape {hip.shape}")
    thigh, shin = knee - hip, ankle - knee
    l1, l2 = np.linalg.norm(thigh, axis=-1), np.linalg.norm(shin, axis=-1)
    reach = l1 + l2
    # The current leg plane: u0 towards the ankle, n0 towards the knee.
    u0, leg0 = _unit(ankle - hip)
    u0 = np.where((leg0 > _EPS * reach)[..., None], u0, _unit(thigh)[0])
    n0 = _side([thigh, pole], u0, _STRAIGHT)
    # The new one: u1 towards the target, n1 towards the pole.
    u1, dist = _unit(target - hip)
    u1 = np.where((dist > _EPS * reach)[..., None], u1, u0)
    n1 = _side([pole, n0], u1, 1e-6)
    # Law of cosines at the hip for the clamped hip-ankle distance.
    d = np.clip(dist, np.abs(l1 - l2), reach)
    # (1 - cos)(1 + cos) in factored form, so a straight or folded leg gives sin = 0 exactly (not ~1e-8).
    denom = np.maximum(2.0 * l1 * d, _EPS)
    cos_hip = np.clip((l1 ** 2 + d ** 2 - l2 ** 2) / denom, -1.0, 1.0)
    sin_hip = np.sqrt(np.maximum((d - l1 + l2) * (reach - d) * (l1 + d - l2) * (l1 + d + l2), 0.0)) / denom
    new_knee = hip + l1[..., None] * (cos_hip[..., None] * u1 + sin_hip[..., None] * n1)
    new_ankle = hip + d[..., None] * u1
    w0, w1 = np.cross(u0, n0), np.cross(u1, n1)  # leg plane normals: the knee's bend axis
    r_hip = _frame(new_knee - hip, w1) @ np.swapaxes(_frame(thigh, w0), -1, -2)
    r_knee = _frame(new_ankle - new_knee, w1) @ np.swapaxes(_frame(shin, w0), -1, -2)
    return TwoBoneIK(quat.from_matrix(r_hip), quat.from_matrix(r_knee), new_knee, new_ankle)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    return x * x * (3.0 - 2.0 * x)


def contact_targets(ankle_Tx3: np.ndarray, contact_T: np.ndarray, blend_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Ankle targets ``(T, 3)`` and the ``(T,)`` frames where they differ from the ankle (contacts and blends).

    Each contact run holds the ankle's position at its first frame (plus whatever offset an earlier
    run's blend still applies there); after the run the offset fades out over ``blend_frames``.
    """
    ankle = np.asarray(ankle_Tx3, dtype=np.float64)
    num_frames = len(ankle)
    target = ankle.copy()
    active = np.zeros(num_frames, dtype=bool)
    fade = 1.0 - _smoothstep(np.arange(1, blend_frames + 1) / (blend_frames + 1.0))
    starts, ends = runs(np.asarray(contact_T, dtype=bool))
    for s, e in zip(starts, ends, strict=True):
        hold = target[s].copy()  # the ankle, or where an earlier run's blend has it
        target[s:e] = hold
        n = min(blend_frames, num_frames - e)
        target[e:e + n] = ankle[e:e + n] + (hold - ankle[e - 1]) * fade[:n, None]
        target[e + n:] = ankle[e + n:]  # clear anything left from an earlier run
        active[s:e + n] = True
    return target, active


def _contact_mask(contacts_TxF, num_frames: int) -> np.ndarray:
    """``(T, 2)`` or ``(T, 4)`` booleans (a :class:`FootContacts` gives ``heel | toe`` per foot)."""
    if isinstance(contacts_TxF, FootContacts):
        contacts_TxF = contacts_TxF.foot
    c = np.asarray(contacts_TxF)
    if c.ndim != 2 or c.shape[0] != num_frames or c.shape[1] not in (2, 4):
        raise ValueError(f"contacts_TxF must have shape ({num_frames}, 2) (frames x left/right foot) or "
                         f"({num_frames}, 4) (heel L, heel R, toe L, toe R), got {c.shape}")
    if c.dtype == bool:
        return c
    c = c.astype(np.float64)
    if not np.isfinite(c).all():
        raise ValueError("contacts_TxF contains NaN or infinity")
    return c >= 0.5


def _leg_chains(motion: Motion, feet: FootJoints | None) -> list[tuple[int, int, int]]:
    """``(hip, knee, ankle)`` joint indices of the left and right legs."""
    where = motion.source or "<motion without source>"
    if feet is None:
        try:
            feet = FootJoints.find(motion)
        except MotionDataError as err:
            raise MotionDataError(f"fix_foot_sliding cannot find the feet of skeleton {where}: {err.reason}; "
                                  "pass feet=FootJoints(ankles=..., toes=...)", motion.source) from None
    chains = []
    for ankle in feet.ankles:
        ankle = int(ankle)
        knee = int(motion.parents[ankle])
        hip = int(motion.parents[knee]) if knee >= 0 else -1
        if hip < 0:
            raise MotionDataError(f"ankle {motion.names[ankle]!r} of skeleton {where} has no knee and hip above it",
                                  motion.source)
        chains.append((hip, knee, ankle))
    if len({j for chain in chains for j in chain}) != 3 * len(chains):
        raise MotionDataError(f"the legs of skeleton {where} share joints: {chains}", motion.source)
    return chains


def _knee_poles(g_rot_knee: np.ndarray, hip: np.ndarray, knee: np.ndarray, ankle: np.ndarray) -> np.ndarray:
    """``(T, 3)`` direction of the original knee from the hip-ankle line.

    Where the leg is straight (no such direction), the knee's usual bend direction is used, taken in
    the knee's own frame (averaged over the clip's bent frames) and turned with the knee.
    """
    axis = _unit(ankle - hip)[0]
    side, norm = _unit(_orthogonal_part(knee - hip, axis))
    bent = norm > _STRAIGHT * np.linalg.norm(knee - hip, axis=-1)
    if bent.all():
        return side
    if bent.any():
        local = quat.rotate(quat.inverse(g_rot_knee[bent]), side[bent]).mean(axis=0)
    else:
        local = np.asarray(quat.FORWARD)
    fallback = quat.rotate(g_rot_knee, np.broadcast_to(_unit(local)[0], side.shape))
    return np.where(bent[:, None], side, fallback)


def _same_hemisphere(q: np.ndarray, like: np.ndarray) -> np.ndarray:
    q = quat.normalize(q)
    return np.where(np.sum(q * like, axis=-1, keepdims=True) < 0, -q, q)


def _solve_legs(motion: Motion, rotations: np.ndarray, chains, targets: dict[int, tuple[np.ndarray, np.ndarray]]
                ) -> None:
    """Move each ``side``'s ankle to ``targets[side] = (target (T, 3), active (T,))`` with
    :func:`two_bone_ik` on the frames where it is active (the ankle keeps its global rotation),
    writing the hip, knee and ankle local rotations into ``rotations`` in place."""
    g_rot, g_pos = kinematics.global_transforms(motion.replace(rotations=rotations))
    for side, (target, active) in targets.items():
        hip, knee, ankle = chains[side]
        idx = np.flatnonzero(active)
        if idx.size == 0:
            continue
        pole = _knee_poles(g_rot[:, knee], g_pos[:, hip], g_pos[:, knee], g_pos[:, ankle])[idx]
        ik = two_bone_ik(g_pos[idx, hip], g_pos[idx, knee], g_pos[idx, ankle], target[idx], pole)
        hip_global = quat.mul(ik.hip_rotation, g_rot[idx, hip])
        knee_global = quat.mul(ik.knee_rotation, g_rot[idx, knee])
        above = int(motion.parents[hip])
        hip_local = hip_global if above < 0 else quat.mul(quat.inverse(g_rot[idx, above]), hip_global)
        new = {hip: hip_local,
               knee: quat.mul(quat.inverse(hip_global), knee_global),
               ankle: quat.mul(quat.inverse(knee_global), g_rot[idx, ankle])}
        for joint, local in new.items():
            rotations[idx, joint] = _same_hemisphere(local, motion.rotations[idx, joint])


def fix_foot_sliding(motion: Motion, contacts_TxF, *, feet: FootJoints | None = None,
                     blend_frames: int = 5, pin_toes: bool | None = None, toe_roll: bool = False) -> Motion:
    """A new :class:`Motion` whose feet stay put while in contact (2022 section 4.4).

    Args:
      motion: the animation to correct (e.g. decoded from the network's output).
      contacts_TxF: ``(T, 2)`` contact labels of the left and right foot, or ``(T, 4)`` heel and
        toe labels (heel L, heel R, toe L, toe R: the 2018 layout's optional outputs,
        :func:`jaxstyle.data.pfnn_features.contact_labels`), booleans or values in ``[0, 1]``
        (a network's prediction) thresholded at 0.5; a :class:`FootContacts` gives its ``foot``
        labels.
      feet: the ankle and toe joints (the ankles with their knee and hip parents); found by name
        when omitted.
      blend_frames: frames over which a released heel or toe returns to the original animation.
      pin_toes: also pin the toe joints (default: with ``(T, 4)`` labels). With ``(T, 2)`` labels
        a foot's toe is pinned while its foot label is on.
      toe_roll: also hold a toe while its heel is up (the ankle moved around the held toe, see
        below). Off by default: with a network's predicted labels, whose toe contacts outlast the
        real push-off, it drags the leg (measured on a small 100STYLE base along a straight path:
        skating of the exported Neutral walk 0.23 m/s raw, 0.17 with heels and flat-foot toes
        pinned, 0.55 with the roll), so a toe is held only while its heel is down too.

    Heels (the ankle joints) are pinned first, as described in the module docstring. Toes then:
    each toe contact run holds the toe joint where the heel-pinned animation had it at the run's
    start (and fades out after it, as the heels). While the heel is also down the ankle turns
    (shortest arc) so the ankle-toe bone points at the held toe; while only the toe is down (the
    heel rolls off) the ankle is first moved, by the same two-bone IK, to the point one foot
    length from the held toe in the direction of the animation's ankle, and then turned, so the
    toe lands exactly where the leg reaches. Every change is a rotation: bone lengths stay exact.
    """
    contact = _contact_mask(contacts_TxF, motion.num_frames)
    if int(blend_frames) != blend_frames or blend_frames < 0:
        raise ValueError(f"blend_frames must be a non-negative integer, got {blend_frames}")
    blend = int(blend_frames)
    heel, toe = (contact[:, :2], contact[:, 2:]) if contact.shape[1] == 4 else (contact, contact)
    pin_toes = contact.shape[1] == 4 if pin_toes is None else bool(pin_toes)
    if pin_toes and feet is None:
        try:
            feet = FootJoints.find(motion)
        except MotionDataError:
            feet = None  # _leg_chains names the problem
    chains = _leg_chains(motion, feet)
    rotations = np.array(motion.rotations, dtype=np.float64, copy=True)
    _, g_pos = kinematics.global_transforms(motion)
    _solve_legs(motion, rotations, chains,
                {side: contact_targets(g_pos[:, chain[2]], heel[:, side], blend) for side, chain in enumerate(chains)})
    if pin_toes:
        _pin_toes(motion, rotations, chains, feet, heel, toe if toe_roll else toe & heel, blend)
    return motion.replace(rotations=rotations)


def _pin_toes(motion: Motion, rotations: np.ndarray, chains, feet: FootJoints, heel, toe, blend: int) -> None:
    """The toe stage of :func:`fix_foot_sliding`, in place on ``rotations`` (heels already pinned)."""
    _, g_pos = kinematics.global_transforms(motion.replace(rotations=rotations))
    toe_targets, ankle_targets = {}, {}
    for side, (_, _, ankle) in enumerate(chains):
        t_joint = int(feet.toes[side])
        target, active = contact_targets(g_pos[:, t_joint], toe[:, side], blend)
        toe_targets[side] = (target, active)
        length = np.linalg.norm(g_pos[:, t_joint] - g_pos[:, ankle], axis=-1)
        away = _unit(g_pos[:, ankle] - target)[0]
        moved = active & ~heel[:, side]  # heel up: the ankle goes to a foot length from the held toe
        ankle_targets[side] = (np.where(moved[:, None], target + length[:, None] * away, g_pos[:, ankle]), moved)
    _solve_legs(motion, rotations, chains, ankle_targets)
    g_rot, g_pos = kinematics.global_transforms(motion.replace(rotations=rotations))
    for side, (_, knee, ankle) in enumerate(chains):
        target, active = toe_targets[side]
        idx = np.flatnonzero(active)
        if idx.size == 0:
            continue
        t_joint = int(feet.toes[side])
        swing = quat.between(g_pos[idx, t_joint] - g_pos[idx, ankle], target[idx] - g_pos[idx, ankle])
        ankle_global = quat.mul(swing, g_rot[idx, ankle])
        local = quat.mul(quat.inverse(g_rot[idx, knee]), ankle_global)
        rotations[idx, ankle] = _same_hemisphere(local, motion.rotations[idx, ankle])
