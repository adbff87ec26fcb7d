"""Procedural stylised locomotion with exact phase and contact labels.

This module makes walking and running clips of a CMU-like skeleton in a handful of clearly
different styles, from nothing but NumPy and jaxstyle's own motion core (:class:`Motion`,
:mod:`jaxstyle.motion.quat`, :func:`jaxstyle.motion.bvh.write_bvh`). It serves two purposes:

* **Data without a download.** :func:`write_dataset` writes a folder in the 100STYLE layout
  (``<root>/<Style>/<Style>_<GAIT>.bvh`` with ``Frame_Cuts.csv`` and ``Dataset_List.csv``) plus
  PFNN label files, which :func:`jaxstyle.data.clips.specs_100style` and the feature builders read
  like the real capture, so a demo can train end to end offline.
* **A labelling oracle.** Every clip comes with its phase and foot contacts *by construction*
  (:class:`Generated`), to test the automatic labellers (:func:`jaxstyle.global_phase`,
  :func:`jaxstyle.foot_contacts`) against a known truth.

How a clip is made (all vectorised over frames):

1. **Root path.** A speed ``v(t)`` and a heading rate ``w(t)`` (smooth random sums of a few
   low-frequency sinusoids per seed; walks 0.8-1.7 m/s, runs 2.4-3.6 m/s, times the style's
   ``speed_scale``; heading rates within +-60 deg/s, cubed so that near-straight stretches are
   common) are integrated into a ground path. The clip starts at the origin facing +Z.
2. **Gait timing.** The cycle frequency grows with speed (walks ~0.85-1.15 Hz, i.e. 1.7-2.3
   steps/s; runs ~1.4-1.55 Hz) and is integrated into a smooth timing cycle ``phi(t)``. The
   right foot touches down at ``phi = 0`` and the left at ``phi = left_touchdown`` (0.5 for
   symmetric styles); each foot stays down for its duty factor (walks ~0.6 with double
   support, runs ~0.35 with a flight phase).
3. **Feet.** A foot in stance is *planted*: fixed world position (the footprint is the root path
   at mid-stance plus a lateral offset), flat on the floor (ankle at its rest height
   ``ANKLE_HEIGHT``, toe joint at ``TOE_HEIGHT``), yawed along the path. In swing the ankle goes
   from one footprint to the next with a minimum-jerk horizontal interpolation and a vertical
   arc, the foot pitching toe-down then toe-up; velocity is zero at both ends of a swing.
4. **Body.** Pelvis height from the style with a vertical bob twice per cycle, lateral sway,
   yaw and roll oscillations; the pelvis is lowered wherever a leg could not otherwise reach its
   ankle target: it follows a smooth minimum of the limits at ``SOFT_REACH`` times full extension,
   smoothed over ``PELVIS_SMOOTH_S``, and never exceeds the limit at ``REACH``. Legs are solved by
   analytic two-bone IK (knee toward the walking direction), so bone lengths are exact. Spine
   lean and counter-rotation, arms swinging opposite to the legs with a style amplitude and
   elbow bend, head stabilised along the path.

What is exact, per frame: the contacts (a foot is planted, with world velocity zero up to float
error, exactly on the frames flagged), the contact-start frames, and the phase, defined as the
PFNN labels are (:func:`jaxstyle.labels.phase.phase_from_contact_starts`): 0 on the first frame of each
right contact, 0.5 on the first frame of each left contact, linear in frames in between (so a
limp, whose two steps take different times, has a piecewise-linear phase with two slopes).
Unlike the automatic labeller at clip ends, the phase before the first and after the last
contact start in a clip is exact too: the gait is generated ``PAD_SECONDS`` beyond both ends and
the phase interpolated between the real (unseen) contact starts there.

What is simplified: there is no physics (no balance, no ground reaction, no lean into turns);
the whole foot is flat for the whole stance (no heel strike or heel-off roll, so the pelvis dips
more than a real one at double support, where the legs reach furthest; the swinging leg still
straightens quickly just before touchdown, so the knees' jerk is high in the long-legged styles,
about 450 m/s^3 mean over all joints in Neutral against 45 in Crouched); touchdowns are soft
(zero foot velocity); the toes do not bend; fingers are omitted. Units are centimetres, Y up.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.ndimage import gaussian_filter1d

from jaxstyle.labels.phase import phase_from_contact_starts
from jaxstyle.motion import Motion, quat
from jaxstyle.motion.bvh import write_bvh

VERSION = 1
GAITS: tuple[str, ...] = ("FW", "FR")  # 100STYLE codes: forward walk, forward run
GAIT_NAMES = {"FW": "forward walk", "FR": "forward run"}
MIN_SECONDS = 3.0
MIN_FPS = 10.0  # below this a run's stance can fall between two frames
PAD_SECONDS = 3.0  # gait generated beyond both clip ends so that the labels there are exact
REACH = 0.995  # ankle targets are always within this fraction of the leg's full extension (exact IK)
SOFT_REACH = 0.975  # the pelvis aims to keep them within this fraction, smoothly
PELVIS_SMOOTH_S = 0.05  # standard deviation (s) of the Gaussian that smooths the pelvis height
_SWING_BULGE_CM = 2.0  # a swinging foot passes the other this much wider than its step width
SOFTMIN_CM = 3.0  # temperature of the smooth minimum that lowers the pelvis for reach

# ------------------------------------------------------------------------------------------ skeleton

_ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Yrotation", "Xrotation", "Zrotation")
_JOINT_CHANNELS = ("Zrotation", "Yrotation", "Xrotation")

TOE_HEIGHT = 2.0  # cm, toe joint centre above the floor when the foot is flat
_THIGH, _SHIN = 42.0, 42.0
_HIP_OFFSET = (9.0, -5.0, 0.0)  # LeftUpLeg from LHipJoint (at the Hips)
_TOE_OFFSET = (0.0, -6.0, 12.6)  # LeftToeBase from LeftFoot: ~14 cm ankle to toe
ANKLE_HEIGHT = TOE_HEIGHT - _TOE_OFFSET[1]  # 8 cm
REST_HIPS_HEIGHT = ANKLE_HEIGHT + _THIGH + _SHIN - _HIP_OFFSET[1]  # 97 cm: straight legs, flat feet

# (name, parent, offset in cm); the character faces +Z with its left on +X, in a T-pose like CMU.
_JOINTS: tuple[tuple[str, str | None, tuple[float, float, float]], ...] = (
    ("Hips", None, (0.0, 0.0, 0.0)),
    ("LHipJoint", "Hips", (0.0, 0.0, 0.0)),
    ("LeftUpLeg", "LHipJoint", _HIP_OFFSET),
    ("LeftLeg", "LeftUpLeg", (0.0, -_THIGH, 0.0)),
    ("LeftFoot", "LeftLeg", (0.0, -_SHIN, 0.0)),
    ("LeftToeBase", "LeftFoot", _TOE_OFFSET),
    ("RHipJoint", "Hips", (0.0, 0.0, 0.0)),
    ("RightUpLeg", "RHipJoint", (-_HIP_OFFSET[0], _HIP_OFFSET[1], _HIP_OFFSET[2])),
    ("RightLeg", "RightUpLeg", (0.0, -_THIGH, 0.0)),
    ("RightFoot", "RightLeg", (0.0, -_SHIN, 0.0)),
    ("RightToeBase", "RightFoot", _TOE_OFFSET),
    ("LowerBack", "Hips", (0.0, 0.0, 0.0)),
    ("Spine", "LowerBack", (0.0, 12.0, -1.0)),
    ("Spine1", "Spine", (0.0, 14.0, 0.0)),
    ("Neck", "Spine1", (0.0, 14.0, -1.0)),
    ("Neck1", "Neck", (0.0, 8.0, 1.0)),
    ("Head", "Neck1", (0.0, 10.0, 1.0)),
    ("LeftShoulder", "Spine1", (2.0, 13.0, -1.0)),
    ("LeftArm", "LeftShoulder", (15.0, 4.0, 0.0)),
    ("LeftForeArm", "LeftArm", (30.0, 0.0, 0.0)),
    ("LeftHand", "LeftForeArm", (25.0, 0.0, 0.0)),
    ("RightShoulder", "Spine1", (-2.0, 13.0, -1.0)),
    ("RightArm", "RightShoulder", (-15.0, 4.0, 0.0)),
    ("RightForeArm", "RightArm", (-30.0, 0.0, 0.0)),
    ("RightHand", "RightForeArm", (-25.0, 0.0, 0.0)),
)
_END_SITES = (("LeftToeBase", (0.0, 0.0, 6.0)), ("RightToeBase", (0.0, 0.0, 6.0)), ("Head", (0.0, 20.0, 2.0)),
              ("LeftHand", (12.0, 0.0, 0.0)), ("RightHand", (-12.0, 0.0, 0.0)))
NAMES: tuple[str, ...] = tuple(n for n, _, _ in _JOINTS)
_J = {n: i for i, n in enumerate(NAMES)}
_PARENTS = np.array([-1 if p is None else _J[p] for _, p, _ in _JOINTS], dtype=np.int64)
_OFFSETS = np.array([o for _, _, o in _JOINTS], dtype=np.float64)


def skeleton(fps: float = 60.0) -> Motion:
    """One-frame rest pose (T-pose, identity rotations) of the CMU-like skeleton, standing on the floor.

    25 joints named as CMU's (fingers omitted), centimetres, Y up, facing +Z; about 1.75 m tall.
    The root has 6 channels (positions, then ``Yrotation Xrotation Zrotation`` so that any heading
    is far from gimbal lock), every other joint ``Zrotation Yrotation Xrotation``.
    """
    local = _OFFSETS[None].copy()
    local[0, 0] = (0.0, REST_HIPS_HEIGHT, 0.0)
    return Motion(
        names=NAMES, parents=_PARENTS.copy(), offsets=_OFFSETS.copy(), rotations=quat.identity((1, len(NAMES))),
        local_positions=local, fps=float(fps),
        channels=tuple(_ROOT_CHANNELS if p is None else _JOINT_CHANNELS for _, p, _ in _JOINTS),
        end_site_parents=np.array([_J[p] for p, _ in _END_SITES], dtype=np.int64),
        end_site_offsets=np.array([o for _, o in _END_SITES], dtype=np.float64),
        source="procedural:skeleton")


# ------------------------------------------------------------------------------------------ styles


@dataclasses.dataclass(frozen=True)
class StyleParams:
    """The numbers that make a style (angles in degrees, lengths in centimetres).

    Walking values; runs derive theirs (see ``_gait_settings``). ``left_touchdown``,
    ``duty_asymmetry`` and ``limp_*`` make a style asymmetric (the left leg is the bad one).
    """

    description: str
    symmetric: bool = True
    speed_scale: float = 1.0  # x the gait's speed band
    cadence_scale: float = 1.0  # x the speed-dependent cycle frequency
    pelvis_height: float = 0.97  # mean walking pelvis height, fraction of REST_HIPS_HEIGHT (straight legs)
    bob: float = 2.0  # cm, vertical pelvis oscillation amplitude (two bumps per cycle)
    sway: float = 2.0  # cm, lateral pelvis sway toward the stance foot
    pelvis_yaw: float = 5.0  # pelvis rotation bringing the leading leg's hip forward
    pelvis_roll: float = 3.0  # pelvic drop on the swing side
    shoulder_yaw: float = 4.0  # chest counter-rotation against the pelvis
    lean: float = 3.0  # trunk lean, forward positive
    chest: float = 0.0  # extra upper-spine flexion (negative: chest out)
    head_pitch: float = 0.0  # positive looks down (the head is otherwise stabilised)
    arm_swing: float = 18.0  # shoulder swing amplitude
    arm_bias: float = 0.0  # forward offset of the arm swing
    arm_abduction: float = 8.0  # arms away from the body
    elbow: float = 15.0  # elbow bend
    elbow_swing: float = 12.0  # extra elbow bend with the arm forward
    step_width: float = 5.0  # cm, footprint distance from the path
    toe_out: float = 6.0  # foot yaw outward
    lift: float = 10.0  # cm, peak ankle lift in a walking swing
    walk_duty: float = 0.6  # fraction of the cycle a foot is planted, walking
    run_duty: float = 0.35  # the same, running
    duty_asymmetry: float = 0.0  # right stance longer, left stance shorter, by this fraction of a cycle
    left_touchdown: float = 0.5  # left touchdown in the timing cycle (right: 0)
    limp_dip: float = 0.0  # cm, pelvis dip while on the left (bad) leg
    limp_roll: float = 0.0  # extra pelvic drop (right side) while on the left leg
    limp_trunk: float = 0.0  # trunk lean over the left leg while on it


STYLES: dict[str, StyleParams] = {
    "Neutral": StyleParams("Normal upright locomotion"),
    "Crouched": StyleParams(
        "Knees deeply bent, trunk leaning forward, short quiet steps", speed_scale=0.7, cadence_scale=0.95,
        pelvis_height=0.8, bob=1.0, sway=1.5, pelvis_yaw=4.0, lean=28.0, chest=8.0, arm_swing=10.0, arm_bias=10.0,
        arm_abduction=12.0, elbow=40.0, elbow_swing=8.0, step_width=9.0, toe_out=10.0, lift=7.0),
    "Bouncy": StyleParams(
        "Springy steps with a large up-and-down motion of the body", speed_scale=0.9, cadence_scale=1.2,
        pelvis_height=0.86, bob=11.0, sway=1.5, arm_swing=22.0, elbow=25.0, elbow_swing=15.0, lift=15.0),
    "ArmSwing": StyleParams(
        "Exaggerated arm swing with a twisting chest", shoulder_yaw=14.0, pelvis_yaw=7.0, arm_swing=50.0,
        arm_bias=5.0, arm_abduction=12.0, elbow=10.0, elbow_swing=25.0),
    "Limping": StyleParams(
        "Favouring a painful left leg: short stance and a pelvis dip on it, a short right step",
        symmetric=False, speed_scale=0.75, cadence_scale=1.0, pelvis_height=0.96, duty_asymmetry=0.06,
        left_touchdown=0.58, limp_dip=4.0, limp_roll=5.0, limp_trunk=6.0, lean=5.0, arm_swing=12.0, lift=8.0),
    "Proud": StyleParams(
        "Chest out, leaning back, chin up, slow swagger with stiff arms", speed_scale=0.8, cadence_scale=0.9,
        pelvis_height=0.98, bob=1.5, sway=4.0, pelvis_yaw=9.0, pelvis_roll=5.0, shoulder_yaw=9.0, lean=-8.0,
        chest=-10.0, head_pitch=-10.0, arm_swing=6.0, arm_bias=-6.0, arm_abduction=15.0, elbow=5.0, elbow_swing=0.0,
        step_width=7.0, toe_out=12.0),
}


@dataclasses.dataclass(frozen=True)
class _Gait:
    speed: tuple[float, float]  # m/s band before the style's scale
    freq: tuple[float, float]  # cycle frequency a + b * v (Hz, v in m/s)
    duty: float
    lift: float  # cm
    swing_pitch: float  # deg, amplitude of the swing foot pitch curve
    pelvis_height: float  # fraction of REST_HIPS_HEIGHT
    bob: float  # cm; negative: lowest at mid-stance (running)
    sway: float
    lean: float
    elbow: float
    arm_swing: float
    heading_rate: float  # deg/s, maximum


def _gait_settings(style: StyleParams, gait: str) -> _Gait:
    if gait == "FW":
        return _Gait(speed=(0.8, 1.7), freq=(0.62, 0.3), duty=style.walk_duty, lift=style.lift, swing_pitch=50.0,
                     pelvis_height=style.pelvis_height, bob=style.bob, sway=style.sway, lean=style.lean,
                     elbow=style.elbow, arm_swing=style.arm_swing, heading_rate=60.0)
    return _Gait(speed=(2.4, 3.6), freq=(1.1, 0.12), duty=style.run_duty, lift=2.2 * style.lift, swing_pitch=70.0,
                 pelvis_height=style.pelvis_height - 0.05, bob=-(1.0 + 0.5 * style.bob), sway=0.4 * style.sway,
                 lean=style.lean + 6.0, elbow=min(style.elbow + 60.0, 85.0), arm_swing=1.3 * style.arm_swing,
                 heading_rate=60.0)


# ------------------------------------------------------------------------------------------ generation


@dataclasses.dataclass(frozen=True, eq=False)
class Generated:
    """A generated clip and its exact labels.

    Attributes:
      motion: ``T`` frames at ``fps``; ``source`` like ``"procedural:Limping_FW(seed=0)"``.
      phase: ``(T,)`` PFNN phase in ``[0, 1)`` (0 at right contact starts, 0.5 at left ones).
      contacts: ``(T, 2)`` bool, left then right: the foot is planted (flat and still).
      left_steps, right_steps: frames where left / right contacts start (a contact already under
        way at frame 0 started before the clip and is not listed; one starting exactly on frame
        0 is).
    """

    motion: Motion
    phase: np.ndarray
    contacts: np.ndarray
    left_steps: np.ndarray
    right_steps: np.ndarray


def _check_choice(value, choices, what: str) -> None:
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"unknown {what} {value!r}; valid {what}s: {', '.join(choices)}")


def _number(value) -> float | None:
    if isinstance(value, bool):
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def _check_timing(seconds: float, fps: float) -> tuple[float, float]:
    secs, rate = _number(seconds), _number(fps)
    if secs is None or not math.isfinite(secs) or secs < MIN_SECONDS:
        raise ValueError(f"seconds must be a finite number >= {MIN_SECONDS:g} (the labels need several steps), "
                         f"got {seconds!r}")
    if rate is None or not math.isfinite(rate) or rate <= 0:
        raise ValueError(f"fps must be a positive finite number (at least {MIN_FPS:g}), got {fps!r}")
    if rate < MIN_FPS:
        raise ValueError(f"fps must be at least {MIN_FPS:g} so that every stance spans a frame, got {fps!r}")
    return secs, rate


def _check_seed(seed: int) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def _smooth_signal(rng: np.random.Generator, t: np.ndarray, count: int, f_lo: float, f_hi: float) -> np.ndarray:
    """``(T,)`` smooth random signal in ``[-1, 1]``: a few sinusoids, squashed by ``tanh``."""
    freqs = rng.uniform(f_lo, f_hi, count)
    phases = rng.uniform(0.0, 2.0 * np.pi, count)
    amps = rng.uniform(0.5, 1.0, count)
    s = (amps * np.sin(2.0 * np.pi * freqs * t[:, None] + phases)).sum(-1) / amps.sum()
    return np.tanh(2.0 * s) / np.tanh(2.0)


def _cumtrapz(y_TxD: np.ndarray, dt: float) -> np.ndarray:
    steps = 0.5 * (y_TxD[1:] + y_TxD[:-1]) * dt
    return np.concatenate([np.zeros_like(y_TxD[:1]), np.cumsum(steps, axis=0)])


def _axis_quat(axis: int, angle_rad: np.ndarray) -> np.ndarray:
    """``(..., 4)`` rotations by ``angle_rad`` about the x (0), y (1) or z (2) axis."""
    angle_rad = np.asarray(angle_rad, dtype=np.float64)
    q = np.zeros(angle_rad.shape + (4,))
    q[..., 0] = np.cos(0.5 * angle_rad)
    q[..., 1 + axis] = np.sin(0.5 * angle_rad)
    return q


def _rot_y(v_Tx3: np.ndarray, theta_T: np.ndarray) -> np.ndarray:
    """Rotates ground vectors about +Y by ``theta`` (0 keeps +Z forward)."""
    c, s = np.cos(theta_T), np.sin(theta_T)
    v_Tx3 = np.broadcast_to(v_Tx3, np.shape(theta_T) + (3,))
    return np.stack([c * v_Tx3[..., 0] + s * v_Tx3[..., 2], v_Tx3[..., 1], -s * v_Tx3[..., 0] + c * v_Tx3[..., 2]],
                    axis=-1)


def _min_jerk(s: np.ndarray) -> np.ndarray:
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _orthogonal_unit(v: np.ndarray, axis_unit: np.ndarray) -> np.ndarray:
    return _unit(v - np.sum(v * axis_unit, axis=-1, keepdims=True) * axis_unit)


def _softmin(values: Sequence[np.ndarray], temperature: float) -> np.ndarray:
    """Smooth minimum (``<=`` the true minimum, by at most ``temperature * log(len(values))``)."""
    stack = np.stack(values)
    low = stack.min(axis=0)
    return low - temperature * np.log(np.exp(-(stack - low) / temperature).sum(axis=0))


def _feet(phi: np.ndarray, t: np.ndarray, path: np.ndarray, heading: np.ndarray, touchdown: float, duty: float,
          side: float, style: StyleParams, g: _Gait) -> dict[str, np.ndarray]:
    """One foot: ankle target ``(T, 3)``, global rotation ``(T, 4)``, yaw ``(T,)`` and stance flags ``(T,)``.

    ``side`` is +1 for the left foot, -1 for the right. Cycle ``k`` of the foot is its stance
    (``u`` in ``[k, k + duty)``, ``u = phi - touchdown``) on footprint ``k``, then its swing to
    footprint ``k + 1``.
    """
    u = phi - touchdown
    k = np.floor(u).astype(np.int64)
    frac = u - k
    ks = np.arange(k.min() - 1, k.max() + 3)
    t_mid = np.interp(ks + touchdown + 0.5 * duty, phi, t)  # phi increases strictly
    i = k - ks[0]
    stance = frac < duty
    s = np.where(stance, 0.0, (frac - duty) / (1.0 - duty))
    w = _min_jerk(s)
    # Footprints and swings follow the path (a swing does not cut the chord of a turn): the foot
    # sits beside the path point of an interpolated time, the footprint's at s = 0 and the next at s = 1.
    t_foot = np.where(stance, t_mid[i], t_mid[i] + (t_mid[i + 1] - t_mid[i]) * w)
    th = np.interp(t_foot, t, heading)
    out = side * (style.step_width + _SWING_BULGE_CM * np.sin(np.pi * s) ** 2)
    ankle = np.stack([np.interp(t_foot, t, path[:, 0]), np.zeros_like(t), np.interp(t_foot, t, path[:, 2])], -1)
    ankle += _rot_y(np.stack([out, np.zeros_like(t), np.zeros_like(t)], -1), th)
    ankle[:, 1] = ANKLE_HEIGHT + g.lift * 16.0 * s * s * (1.0 - s) * (1.0 - s)
    yaw = th + side * np.radians(style.toe_out)
    pitch = np.radians(g.swing_pitch * min(1.0, g.lift / 10.0)) * np.sin(np.pi * s) ** 2 * np.cos(np.pi * s)
    rot = quat.mul(_axis_quat(1, yaw), _axis_quat(0, pitch))  # toe down early in the swing, up late
    return {"ankle": ankle, "rot": rot, "yaw": yaw, "stance": stance}


def _two_bone_ik(hip: np.ndarray, ankle: np.ndarray, pole: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations ``(T, 4)`` of thigh and shin (rest bones along -Y, knee hinge about local X)
    putting the ankle on ``ankle``, the knee bending toward ``pole``."""
    d_vec = ankle - hip
    d = np.linalg.norm(d_vec, axis=-1, keepdims=True)
    u = d_vec / d
    cos_a = np.clip((_THIGH ** 2 + d ** 2 - _SHIN ** 2) / (2.0 * _THIGH * d), -1.0, 1.0)
    n = _orthogonal_unit(pole, u)
    knee = hip + _THIGH * (cos_a * u + np.sqrt(1.0 - cos_a ** 2) * n)
    b1 = (knee - hip) / _THIGH
    b2 = _unit(ankle - knee)
    q1 = quat.from_forward_up(_orthogonal_unit(pole, b1), -b1)
    q2 = quat.from_forward_up(_orthogonal_unit(pole, b2), -b2)
    return q1, q2


def _clip_seed(seed: int, style: str, gait: str) -> int:
    digest = hashlib.sha256(f"{int(seed)}:{style}:{gait}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


def generate(style: str, gait: str = "FW", *, seconds: float = 20.0, fps: float = 60.0, seed: int = 0,
             turning: bool = True, speed_changes: bool = True) -> Generated:
    """A clip of ``round(seconds * fps)`` frames in ``style`` (a key of :data:`STYLES`) and ``gait``
    (one of :data:`GAITS`), with its exact phase and contacts.

    ``seed`` draws the speed and heading profiles and the starting point in the gait cycle.
    ``turning=False`` walks straight along +Z; ``speed_changes=False`` keeps the speed at the
    middle of the band; with both the path is a straight line at constant speed.

    Raises:
      ValueError: unknown style or gait, ``seconds < 3``, ``fps`` not a finite number >= 10, a
        negative or non-integer ``seed``.
    """
    _check_choice(style, STYLES, "style")
    _check_choice(gait, GAITS, "gait")
    seconds, fps = _check_timing(seconds, fps)
    seed = _check_seed(seed)
    params = STYLES[style]
    g = _gait_settings(params, gait)
    rng = np.random.default_rng(seed)
    n = int(round(seconds * fps))
    pad = int(math.ceil(PAD_SECONDS * fps))
    t = np.arange(-pad, n + pad, dtype=np.float64) / fps  # (T_ext,) seconds; frame `pad` is the clip's frame 0
    dt = 1.0 / fps

    # Root path: speed and heading rate, integrated; the clip starts at the origin facing +Z.
    speed_signal = _smooth_signal(rng, t, 3, 0.04, 0.12)
    turn_signal = _smooth_signal(rng, t, 3, 0.02, 0.08)
    start_phase = rng.uniform(0.0, 1.0)
    lo, hi = (params.speed_scale * v for v in g.speed)
    v = (0.5 * (lo + hi) + 0.5 * (hi - lo) * speed_signal) if speed_changes else np.full_like(t, 0.5 * (lo + hi))
    w = np.radians(g.heading_rate) * turn_signal ** 3 if turning else np.zeros_like(t)
    heading = _cumtrapz(w, dt)
    heading -= heading[pad]
    vel = 100.0 * v[:, None] * np.stack([np.sin(heading), np.zeros_like(t), np.cos(heading)], -1)  # cm/s
    path = _cumtrapz(vel, dt)
    path -= path[pad]

    # Gait timing: the cycle frequency follows the speed; phi in cycles, right touchdown at integers.
    freq = params.cadence_scale * (g.freq[0] + g.freq[1] * v)
    phi = _cumtrapz(freq, dt)
    phi += start_phase - phi[pad]
    touchdown = {"left": params.left_touchdown, "right": 0.0}
    duty = {"left": g.duty - params.duty_asymmetry, "right": g.duty + params.duty_asymmetry}
    feet = {name: _feet(phi, t, path, heading, touchdown[name], duty[name], side, params, g)
            for name, side in (("left", 1.0), ("right", -1.0))}

    # Warped cycle psi: 0 at right mid-stance, 0.5 at left mid-stance (pelvis bob, sway and roll).
    mid_r = 0.5 * duty["right"]
    gap = (touchdown["left"] + 0.5 * duty["left"] - mid_r) % 1.0
    x = np.mod(phi - mid_r, 1.0)
    psi = np.where(x < gap, 0.5 * x / gap, 0.5 + 0.5 * (x - gap) / (1.0 - gap))
    on_left = 0.5 * (1.0 - np.cos(2.0 * np.pi * psi))  # 1 at left mid-stance, 0 at right mid-stance
    cyc = np.cos(2.0 * np.pi * phi)  # +1 at right touchdown: right leg and left arm forward

    # Pelvis orientation and position.
    yaw_osc = np.radians(params.pelvis_yaw) * cyc
    roll = np.radians(-params.pelvis_roll * np.cos(2.0 * np.pi * psi) - params.limp_roll * on_left)
    pelvis_pitch = np.radians(0.4 * g.lean)
    pelvis_rot = quat.mul(quat.mul(_axis_quat(1, heading + yaw_osc), _axis_quat(0, np.full_like(t, pelvis_pitch))),
                          _axis_quat(2, roll))
    lateral = -g.sway * np.cos(2.0 * np.pi * psi)
    ground = path + _rot_y(np.stack([lateral, np.zeros_like(t), np.zeros_like(t)], -1), heading)
    y_wanted = (g.pelvis_height * REST_HIPS_HEIGHT + g.bob * np.cos(4.0 * np.pi * psi) - params.limp_dip * on_left)
    soft_limits, hard_limits = [y_wanted], []
    hip_rel = {}
    for name, side in (("left", 1.0), ("right", -1.0)):
        hip_rel[name] = quat.rotate(pelvis_rot, np.broadcast_to([side * _HIP_OFFSET[0], *_HIP_OFFSET[1:]], (len(t), 3)))
        hip_ground = ground + hip_rel[name]
        ankle = feet[name]["ankle"]
        dh = np.hypot(ankle[:, 0] - hip_ground[:, 0], ankle[:, 2] - hip_ground[:, 2])
        for limits, fraction in ((soft_limits, SOFT_REACH), (hard_limits, REACH)):
            reach = fraction * (_THIGH + _SHIN)
            limits.append(ankle[:, 1] + np.sqrt(np.maximum(reach ** 2 - dh ** 2, (0.3 * reach) ** 2))
                          - hip_rel[name][:, 1])
    # The pelvis follows a smoothed, slightly conservative reach limit (no knee snapping at double
    # support), and never exceeds the hard limit (so the IK below is exact).
    smooth = gaussian_filter1d(_softmin(soft_limits, SOFTMIN_CM), PELVIS_SMOOTH_S * fps, mode="nearest")
    pelvis = ground.copy()
    pelvis[:, 1] = np.minimum(smooth, np.min(hard_limits, axis=0))

    rot = np.empty((len(t), len(NAMES), 4))
    rot[:] = quat.identity()
    rot[:, _J["Hips"]] = pelvis_rot

    # Legs by two-bone IK; LHipJoint/RHipJoint keep identity rotations (their global is the pelvis').
    for name, prefix in (("left", "Left"), ("right", "Right")):
        f = feet[name]
        hip = pelvis + hip_rel[name]
        pole = _unit(quat.forward(pelvis_rot) * np.array([1.0, 0.0, 1.0]) + quat.forward(_axis_quat(1, f["yaw"])))
        q1, q2 = _two_bone_ik(hip, f["ankle"], pole)
        rot[:, _J[f"{prefix}UpLeg"]] = quat.mul(quat.inverse(pelvis_rot), q1)
        rot[:, _J[f"{prefix}Leg"]] = quat.mul(quat.inverse(q1), q2)
        rot[:, _J[f"{prefix}Foot"]] = quat.mul(quat.inverse(q2), f["rot"])

    # Spine: lean, chest, counter-rotation against the pelvis, roll undone (plus a limp's trunk lean).
    spine_yaw = -yaw_osc - np.radians(params.shoulder_yaw) * cyc
    spine_pitch = np.radians(0.6 * g.lean)
    spine_roll = -roll - np.radians(params.limp_trunk) * on_left
    chest = np.radians(params.chest)
    spine_global = pelvis_rot
    for joint, share, extra in (("LowerBack", 0.3, 0.0), ("Spine", 0.3, 0.4), ("Spine1", 0.4, 0.6)):
        bend = _axis_quat(0, np.full_like(t, share * spine_pitch + extra * chest))
        local = quat.mul(quat.mul(_axis_quat(1, share * spine_yaw), bend), _axis_quat(2, share * spine_roll))
        rot[:, _J[joint]] = local
        spine_global = quat.mul(spine_global, local)

    # Head stabilised along the path; the neck takes half of the correction.
    head_global = quat.mul(_axis_quat(1, heading), _axis_quat(0, np.full_like(t, np.radians(params.head_pitch))))
    correction = quat.mul(quat.inverse(spine_global), head_global)
    neck = quat.slerp(quat.identity((len(t),)), correction, 0.5)
    rot[:, _J["Neck"]] = neck
    rot[:, _J["Head"]] = quat.mul(quat.inverse(neck), correction)

    # Arms hang from a yaw-only chest frame and swing opposite to the legs.
    chest_yaw = _axis_quat(1, heading - np.radians(params.shoulder_yaw) * cyc)
    lagged = np.cos(2.0 * np.pi * (phi - 0.05))
    for prefix, side in (("Left", 1.0), ("Right", -1.0)):
        swing = np.radians(g.arm_swing) * side * lagged
        forward = np.radians(params.arm_bias) + swing  # the left arm is forward when the right leg is
        down = _axis_quat(2, np.full_like(t, -side * np.radians(90.0 - params.arm_abduction)))
        arm_global = quat.mul(chest_yaw, quat.mul(_axis_quat(0, -forward), down))
        rot[:, _J[f"{prefix}Arm"]] = quat.mul(quat.inverse(spine_global), arm_global)  # the clavicle stays identity
        bend = np.radians(g.elbow + params.elbow_swing * 0.5 * (1.0 + side * lagged))
        rot[:, _J[f"{prefix}ForeArm"]] = _axis_quat(1, -side * bend)

    # Exact labels on the extended range, then the clip.
    stance = np.stack([feet["left"]["stance"], feet["right"]["stance"]], -1)  # (T_ext, 2)
    starts = stance[1:] & ~stance[:-1]
    left_ext, right_ext = (np.flatnonzero(starts[:, k]) + 1 for k in (0, 1))
    phase_ext = phase_from_contact_starts(len(t), right_ext, left_ext)
    clip = slice(pad, pad + n)

    def in_clip(frames):
        frames = frames - pad
        return frames[(frames >= 0) & (frames < n)]

    base = skeleton(fps)
    local_pos = np.broadcast_to(base.offsets, (n, len(NAMES), 3)).copy()
    local_pos[:, 0] = pelvis[clip]
    motion = base.replace(rotations=rot[clip], local_positions=local_pos,
                          source=f"procedural:{style}_{gait}(seed={seed})")
    return Generated(motion=motion, phase=np.mod(phase_ext[clip], 1.0), contacts=stance[clip].copy(),
                     left_steps=in_clip(left_ext), right_steps=in_clip(right_ext))


# ------------------------------------------------------------------------------------------ dataset

_DATASET_LIST_HEADER = ("Style Name", "Description", "Stochastic", "Symmetric", "Notes")


def write_dataset(root: str | os.PathLike, styles: Sequence[str] | None = None, gaits: Sequence[str] = GAITS, *,
                  seconds: float = 20.0, fps: float = 60.0, seed: int = 0, progress: bool = False) -> Path:
    """Writes generated clips in the 100STYLE layout under ``root`` and returns ``root``.

    Files (``<stem>`` is ``<root>/<Style>/<Style>_<GAIT>``):

    * ``<stem>.bvh``: the clip (:func:`generate` with a seed derived from ``seed``, style and
      gait, so every clip differs);
    * ``<stem>.phase``: the exact phase, one value in ``[0, 1)`` per line, and
      ``<stem>_footsteps.txt``: the contact-start frames of both feet, sorted, one per line (the
      PFNN label files, read by :func:`jaxstyle.labels.phase.read_phase_labels`);
    * ``<stem>_contacts.txt``: the exact contacts, one line per frame, ``left right`` as ``0``/``1``;
    * ``Frame_Cuts.csv``: 100STYLE's header (all 10 gaits), each generated clip cut whole
      (``0`` to its frame count), ``N/A`` for the others; ``Dataset_List.csv``: description and
      ``Symmetric`` Yes/No (only symmetric styles are mirrored by :func:`specs_100style`);
    * ``procedural.json``: generator version and settings, and every clip's seed and frames.

    Existing files of the same names are overwritten; others are left alone.

    Raises:
      ValueError: an unknown style or gait, or bad ``seconds`` / ``fps`` / ``seed`` (see :func:`generate`).
    """
    from jaxstyle.data.clips import GAITS_100STYLE

    styles = list(STYLES) if styles is None else ([styles] if isinstance(styles, str) else list(styles))
    gaits = [gaits] if isinstance(gaits, str) else list(gaits)
    if not styles or not gaits:
        raise ValueError(f"no {'styles' if not styles else 'gaits'} to write; valid styles: {', '.join(STYLES)}; "
                         f"valid gaits: {', '.join(GAITS)}")
    for s in styles:
        _check_choice(s, STYLES, "style")
    for g in gaits:
        _check_choice(g, GAITS, "gait")
    seconds, fps = _check_timing(seconds, fps)
    seed = _check_seed(seed)
    styles = list(dict.fromkeys(styles))
    gaits = list(dict.fromkeys(gaits))
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    jobs = [(s, g) for s in styles for g in gaits]
    if progress:
        from tqdm.auto import tqdm

        jobs = tqdm(jobs, desc="procedural clips", unit="clip")
    clips = []
    frames: dict[tuple[str, str], int] = {}
    for style, gait in jobs:
        clip_seed = _clip_seed(seed, style, gait)
        gen = generate(style, gait, seconds=seconds, fps=fps, seed=clip_seed)
        folder = root / style
        folder.mkdir(exist_ok=True)
        stem = folder / f"{style}_{gait}"
        write_bvh(gen.motion, stem.with_suffix(".bvh"))
        phase = np.mod(np.round(gen.phase, 8), 1.0)  # never prints as 1.00000000
        _write_text(Path(f"{stem}.phase"), "".join(f"{p:.8f}\n" for p in phase))
        steps = np.sort(np.concatenate([gen.left_steps, gen.right_steps]))
        _write_text(Path(f"{stem}_footsteps.txt"), "".join(f"{int(f)}\n" for f in steps))
        _write_text(Path(f"{stem}_contacts.txt"), "".join(f"{int(a)} {int(b)}\n" for a, b in gen.contacts))
        frames[style, gait] = gen.motion.num_frames
        clips.append({"style": style, "gait": gait, "seed": clip_seed, "frames": gen.motion.num_frames,
                      "left_steps": len(gen.left_steps), "right_steps": len(gen.right_steps)})

    header = ["STYLE_NAME"] + [f"{g}_{edge}" for g in GAITS_100STYLE for edge in ("START", "STOP")]
    rows = []
    for style in styles:
        row = [style]
        for g in GAITS_100STYLE:
            row += [0, frames[style, g]] if (style, g) in frames else ["N/A", "N/A"]
        rows.append(row)
    _write_csv(root / "Frame_Cuts.csv", header, rows)
    _write_csv(root / "Dataset_List.csv", list(_DATASET_LIST_HEADER),
               [[s, STYLES[s].description, "No", "Yes" if STYLES[s].symmetric else "No",
                 "procedural (jaxstyle.data.procedural)"] for s in styles])
    settings = {"generator": "jaxstyle.data.procedural", "version": VERSION, "seconds": seconds, "fps": fps,
                "seed": seed, "styles": styles, "gaits": gaits, "clips": clips,
                "contacts_format": "<stem>_contacts.txt: one line per frame, 'left right', 1 = planted",
                "style_params": {s: dataclasses.asdict(STYLES[s]) for s in styles}}
    _write_text(root / "procedural.json", json.dumps(settings, indent=2, allow_nan=False) + "\n")
    return root


def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


def _write_csv(path: Path, header: list[str], rows: list[list]) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)
    os.replace(tmp, path)
