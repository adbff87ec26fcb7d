"""Foot contacts from joint heights and speeds (Mason, Starke & Komura 2022, section 4.1.2).

A joint is in contact with the floor in a frame when the ball of radius ``d_max`` centred on it
touches the floor plane **and** its speed is below ``v_max``; the paper's defaults are
``d_max = 0.01 m`` and ``v_max = 0.15 m/s``. Three details the paper leaves open are fixed here:

* **Units and size** (``rule``, see :data:`CONTACT_RULES`). The paper's thresholds are for the
  100STYLE actor, in metres, at 60 fps. The default rule, ``"scaled"``, measures them in the
  skeleton's own size: one "metre" is the skeleton's leg length (thigh + shin, :func:`leg_length`)
  divided by the 100STYLE skeleton's, 0.8696 m (:func:`body_units_per_meter`). On 100STYLE this
  is exactly 100 file units (centimetres), so the rule is the paper's; on any other skeleton it
  is the paper's rule applied to the same motion scaled to the 100STYLE actor's size, so a clip
  gives the same contacts in metres, centimetres, inches or millimetres and when the whole
  skeleton is shrunk or grown. The paper's own setting, ``"paper2022"``, converts metres with
  :func:`estimate_units_per_meter`, which recognises metre, centimetre and millimetre skeletons
  from their height and otherwise assumes a 1.75 m tall character; it jumps at the edges of those
  height ranges (a 1.19 m and a 1.21 m tall skeleton get thresholds 100 times apart) and reads
  Holden's CMU skeletons (24 units tall, legs of 14.8 units) as having 1.08 m legs.
* **Frame rate.** Under ``"scaled"`` a joint's speed is its displacement over a fixed time span,
  :data:`SPEED_SPAN_S` (the 2/60 s of a central difference at the paper's 60 fps), interpolated
  between frames where needed (:func:`joint_speeds`): the same at 30, 60 or 120 fps, where
  per-frame central differences of a 120 fps capture see twice its jitter. ``"paper2022"`` uses
  per-frame central differences. Gaps and minimum durations (``max_gap``, ``min_duration``) are
  in seconds under both rules.
* **Floor.** A joint sits above the floor by its own clearance (an ankle is ~8 cm up even when
  planted), so "the ball touches the floor" is measured from the height the joint has when
  planted: the floor of joint ``j`` in a clip is a low percentile (default 5th) of its height over
  the clip. This estimates the floor per clip and needs no knowledge of the foot's geometry.

Everything is vectorised over frames and joints; ``(T, J)`` arrays are frames x joints.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from jaxstyle.errors import MotionDataError
from jaxstyle.motion import Motion, kinematics, skeleton
from jaxstyle.motion.kinematics import UP_AXIS

HEIGHT_THRESHOLD_M = 0.01  # d_max, 2022 section 4.1.2
SPEED_THRESHOLD_M_S = 0.15  # v_max, 2022 section 4.1.2
ASSUMED_HEIGHT_M = 1.75
FLOOR_PERCENTILE = 5.0
REFERENCE_LEG_LENGTH_M = 0.869581919967294
"""Thigh + shin of the 100STYLE skeleton (86.958 cm), the actor the paper's thresholds are for."""
SPEED_SPAN_S = 2.0 / 60.0
"""Time span of the ``"scaled"`` rule's speeds: a central difference at the paper's 60 fps."""
CONTACT_RULES = ("scaled", "paper2022")
"""``"scaled"`` (default): the paper's thresholds for a body of the skeleton's leg length, speeds
over :data:`SPEED_SPAN_S`; ``"paper2022"``: the paper's setting, metres from
:func:`estimate_units_per_meter`, speeds by per-frame central differences."""
DEFAULT_CONTACT_RULE = "scaled"


def estimate_units_per_meter(motion: Motion) -> float:
    """File units per metre, judged from the rest-pose height of the skeleton.

    Heights of 1.2-2.5 read as metres, 120-250 as centimetres, 1200-2500 as millimetres; any
    other height (e.g. Holden's CMU skeletons, ~24 units) is taken as a 1.75 m tall person. Pass
    ``units_per_meter`` explicitly to the functions below when this guess is wrong.
    """
    height = kinematics.skeleton_height(motion)
    for unit in (1.0, 100.0, 1000.0):
        if 1.2 * unit <= height <= 2.5 * unit:
            return unit
    return height / ASSUMED_HEIGHT_M


def leg_length(motion: Motion, feet: "FootJoints | None" = None) -> float:
    """Rest length of the legs in file units: ankle-to-knee plus knee-to-hip bone (the offsets of
    the ankle and of its parent), averaged over both legs."""
    feet = feet or FootJoints.find(motion)
    lengths = [np.linalg.norm(motion.offsets[a]) + (np.linalg.norm(motion.offsets[motion.parents[a]])
                                                    if motion.parents[a] >= 0 else 0.0) for a in feet.ankles]
    length = float(np.mean(lengths))
    if not (np.isfinite(length) and length > 0):
        raise MotionDataError(f"the legs have length {length:g}; cannot scale contact thresholds", motion.source)
    return length


def body_units_per_meter(motion: Motion, feet: "FootJoints | None" = None) -> float:
    """File units per metre of a body the size of the 100STYLE actor: :func:`leg_length` over
    :data:`REFERENCE_LEG_LENGTH_M`. Exactly 100 on 100STYLE; scales with the skeleton."""
    return leg_length(motion, feet) / REFERENCE_LEG_LENGTH_M


def contact_units_per_meter(motion: Motion, rule: str = DEFAULT_CONTACT_RULE,
                            feet: "FootJoints | None" = None) -> float:
    """The file units per metre a contact ``rule`` (:data:`CONTACT_RULES`) measures thresholds in."""
    if rule == "scaled":
        return body_units_per_meter(motion, feet)
    if rule == "paper2022":
        return estimate_units_per_meter(motion)
    raise ValueError(f"unknown contact rule {rule!r}; expected one of {CONTACT_RULES}")


def speed_span(rule: str) -> float | None:
    """The speed time span of a contact ``rule`` (``None``: per-frame central differences)."""
    if rule not in CONTACT_RULES:
        raise ValueError(f"unknown contact rule {rule!r}; expected one of {CONTACT_RULES}")
    return SPEED_SPAN_S if rule == "scaled" else None


def joint_speeds(positions_TxJx3: np.ndarray, fps: float, span: float | None = None) -> np.ndarray:
    """``(T, J)`` speed of each joint in units per second.

    ``span=None``: central differences over one frame each way (one-sided at the ends). ``span``
    in seconds: ``|p(t + span/2) - p(t - span/2)| / span``, positions between frames interpolated
    linearly and times clipped to the clip (so the span shrinks at the ends); at 60 fps with
    ``span = 2/60`` this is exactly the central difference, at 120 fps it spans two frames each way.
    """
    pos = np.asarray(positions_TxJx3, dtype=np.float64)
    if pos.shape[0] < 2:
        return np.zeros(pos.shape[:2])
    if span is None:
        return np.linalg.norm(np.gradient(pos, axis=0), axis=-1) * fps
    if not span > 0:
        raise ValueError(f"speed span must be positive, got {span}")
    last = pos.shape[0] - 1
    t = np.arange(pos.shape[0], dtype=np.float64)
    half = 0.5 * span * fps
    ahead, behind = np.minimum(t + half, last), np.maximum(t - half, 0.0)

    def at(x):
        i0 = np.minimum(np.floor(x).astype(np.int64), last - 1)
        w = (x - i0)[:, None, None]
        return pos[i0] * (1.0 - w) + pos[i0 + 1] * w

    return np.linalg.norm(at(ahead) - at(behind), axis=-1) / ((ahead - behind)[:, None] / fps)


def floor_heights(heights_TxJ: np.ndarray, percentile: float = FLOOR_PERCENTILE) -> np.ndarray:
    """``(J,)`` height each joint has when planted: a low percentile of its height over the clip.

    A percentile rather than the minimum, so a few glitched frames cannot pull the floor down.
    """
    return np.percentile(np.asarray(heights_TxJ, dtype=np.float64), percentile, axis=0)


def clean_runs(mask_TxJ: np.ndarray, *, max_gap: int = 0, min_length: int = 0) -> np.ndarray:
    """Fill ``False`` gaps of at most ``max_gap`` frames between ``True`` runs, then drop ``True``
    runs shorter than ``min_length`` frames. Runs touching the clip ends are never dropped for
    being short (they may continue outside the clip). Works column-wise on ``(T,)`` or ``(T, J)``.
    """
    mask = np.asarray(mask_TxJ, dtype=bool)
    squeeze = mask.ndim == 1
    mask = mask[:, None] if squeeze else mask.copy()
    num_frames = mask.shape[0]
    for j in range(mask.shape[1]):
        col = mask[:, j]
        if max_gap > 0:
            starts, ends = runs(~col)
            for s, e in zip(starts, ends, strict=True):
                if s > 0 and e < num_frames and e - s <= max_gap:
                    col[s:e] = True
        if min_length > 1:
            starts, ends = runs(col)
            for s, e in zip(starts, ends, strict=True):
                if s > 0 and e < num_frames and e - s < min_length:
                    col[s:e] = False
    return mask[:, 0] if squeeze else mask


def runs(col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start (inclusive) and end (exclusive) frames of the ``True`` runs of a 1-D mask."""
    padded = np.concatenate([[False], col, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return edges[0::2], edges[1::2]


def contact_starts(mask_T: np.ndarray) -> np.ndarray:
    """Frames where a contact run begins (a run already under way at frame 0 is not a start)."""
    starts, _ = runs(np.asarray(mask_T, dtype=bool))
    return starts[starts > 0]


def hysteresis(low_TxJ: np.ndarray, high_TxJ: np.ndarray) -> np.ndarray:
    """``(T, J)`` state that switches on where ``low`` holds and off where ``high`` holds.

    Between the two (neither flag set) the previous state is kept; before the first switch the
    state is off. ``low`` wins when both hold. Vectorised: no loop over frames.
    """
    low, high = np.asarray(low_TxJ, dtype=bool), np.asarray(high_TxJ, dtype=bool)
    frames = np.arange(low.shape[0]).reshape((-1,) + (1,) * (low.ndim - 1))
    last_switch = np.maximum.accumulate(np.where(low | high, frames, -1), axis=0)
    state = np.take_along_axis(low, np.maximum(last_switch, 0), axis=0)
    return state & (last_switch >= 0)


def joint_contacts(positions_TxJx3: np.ndarray, fps: float, *, units_per_meter: float,
                   height_threshold: float | None = HEIGHT_THRESHOLD_M,
                   speed_threshold: float | None = SPEED_THRESHOLD_M_S,
                   release_speed: float | None = None,
                   floor_J: np.ndarray | None = None, speed_span: float | None = None) -> np.ndarray:
    """``(T, J)`` contact flags of the given joints (2022 section 4.1.2).

    Args:
      positions_TxJx3: global positions of the joints to test (Y up), in file units.
      fps: frame rate, for speeds.
      units_per_meter: file units per metre; thresholds are in metres and metres per second.
      height_threshold: ``d_max``; ``None`` drops the height test (speed only), which also finds
        contacts on raised surfaces such as steps.
      speed_threshold: ``v_max``; ``None`` drops the speed test.
      release_speed: m/s; when given (above ``speed_threshold``), the speed test has hysteresis:
        a contact begins when the joint slows below ``speed_threshold`` and lasts until it is
        faster than ``release_speed``, so a planted foot that slides a little or jitters stays one
        contact. ``None`` (the paper's rule) tests every frame against ``speed_threshold`` alone.
      floor_J: height of each joint when planted; estimated per clip with :func:`floor_heights`
        when omitted.
      speed_span: seconds; speeds over this time span (see :func:`joint_speeds`); ``None``:
        per-frame central differences.
    """
    pos = np.asarray(positions_TxJx3, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[-1] != 3:
        raise ValueError(f"positions must have shape (T, J, 3), got {pos.shape}")
    if not np.isfinite(pos).all():
        raise MotionDataError("joint positions contain NaN or infinity; cannot detect contacts")
    contact = np.ones(pos.shape[:2], dtype=bool)
    if height_threshold is not None:
        heights = pos[..., UP_AXIS]
        floor = floor_heights(heights) if floor_J is None else np.asarray(floor_J, dtype=np.float64)
        contact &= heights - floor < height_threshold * units_per_meter
    if speed_threshold is not None:
        speed = joint_speeds(pos, fps, speed_span)
        slow = speed < speed_threshold * units_per_meter
        if release_speed is not None:
            if release_speed < speed_threshold:
                raise ValueError(f"release_speed ({release_speed}) must be >= speed_threshold ({speed_threshold})")
            slow = hysteresis(slow, speed > release_speed * units_per_meter)
        contact &= slow
    return contact


@dataclass(frozen=True)
class FootJoints:
    """Indices of the ankle and toe joints of each foot, left then right."""

    ankles: tuple[int, int]
    toes: tuple[int, int]

    @classmethod
    def find(cls, motion: Motion, ankles: Sequence[str] | None = None,
             toes: Sequence[str] | None = None) -> "FootJoints":
        """Find the feet by name (see :func:`jaxstyle.motion.skeleton.find_feet_and_hands`) unless given."""
        if ankles is None or toes is None:
            found = skeleton.find_feet_and_hands(motion.names, motion.source, motion.joint_map)
            ankles = ankles or found["ankles"]
            toes = toes or found["toes"]
        return cls(tuple(motion.joint_indices(list(ankles))), tuple(motion.joint_indices(list(toes))))


@dataclass(frozen=True)
class FootContacts:
    """Per-foot contact flags, left then right, as ``(T, 2)`` boolean arrays.

    ``heel`` is the ankle joint's contact, ``toe`` the toe joint's. ``foot`` is the 2022 paper's
    foot contact label (either bone touching), i.e. ``heel | toe``.
    """

    heel: np.ndarray
    toe: np.ndarray

    @property
    def foot(self) -> np.ndarray:
        return self.heel | self.toe

    def moment(self, which: str) -> np.ndarray:
        """The ``(T, 2)`` contact whose onset is taken as the start of a contact.

        ``"heel"``: the ankle touches down (heel strike); ``"toe"``: the toe joint touches down;
        ``"first"``: whichever touches first (onset of ``heel | toe``); ``"planted"``: both
        touch (onset of ``heel & toe``, the whole foot flat on the floor).
        """
        if which == "heel":
            return self.heel
        if which == "toe":
            return self.toe
        if which == "first":
            return self.heel | self.toe
        if which == "planted":
            return self.heel & self.toe
        raise ValueError(f"unknown contact moment {which!r}; expected one of {CONTACT_MOMENTS}")


CONTACT_MOMENTS = ("heel", "toe", "first", "planted")


@dataclass(frozen=True)
class ContactConfig:
    """How a foot joint is judged on the floor (2022 section 4.1.2); the defaults are the paper's.

    Attributes:
      height_threshold, speed_threshold: ``d_max`` (m) and ``v_max`` (m/s); ``None`` disables a
        test.
      release_speed: m/s; adds hysteresis (see :func:`joint_contacts`); ``None``: off.
      max_gap, min_duration: in seconds; gaps up to ``max_gap`` inside a contact are filled and
        contacts shorter than ``min_duration`` dropped (both 0, i.e. off, as in the paper;
        :func:`jaxstyle.labels.phase.global_phase` uses them to ignore single-frame flicker).
      rule: ``"scaled"`` (default: thresholds for the skeleton's size, speeds over a fixed time
        span) or ``"paper2022"`` (the paper's setting); see the module docstring.
    """

    height_threshold: float | None = HEIGHT_THRESHOLD_M
    speed_threshold: float | None = SPEED_THRESHOLD_M_S
    release_speed: float | None = None
    max_gap: float = 0.0
    min_duration: float = 0.0
    rule: str = DEFAULT_CONTACT_RULE


def foot_contacts(motion: Motion, config: ContactConfig = ContactConfig(), *,
                  units_per_meter: float | None = None, feet: FootJoints | None = None,
                  positions_TxJx3: np.ndarray | None = None) -> FootContacts:
    """Heel and toe contacts of both feet (2022 section 4.1.2), left then right.

    Args:
      config: thresholds, hysteresis, clean-up and unit rule (:class:`ContactConfig`).
      units_per_meter: file units per metre; when omitted, the rule's
        (:func:`contact_units_per_meter`).
      feet: ankle and toe joints; found by name when omitted.
      positions_TxJx3: global joint positions, if already computed.
    """
    feet = feet or FootJoints.find(motion)
    span = speed_span(config.rule)
    upm = (contact_units_per_meter(motion, config.rule, feet) if units_per_meter is None
           else float(units_per_meter))
    pos = kinematics.global_positions(motion) if positions_TxJx3 is None else positions_TxJx3
    joints = list(feet.ankles) + list(feet.toes)
    flags = joint_contacts(pos[:, joints], motion.fps, units_per_meter=upm,
                           height_threshold=config.height_threshold, speed_threshold=config.speed_threshold,
                           release_speed=config.release_speed, speed_span=span)
    flags = clean_runs(flags, max_gap=int(round(config.max_gap * motion.fps)),
                       min_length=int(round(config.min_duration * motion.fps)))
    return FootContacts(heel=flags[:, :2], toe=flags[:, 2:])
