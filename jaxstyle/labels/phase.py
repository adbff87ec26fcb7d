"""Global locomotion phase for the PFNN (Holden et al. 2017; Mason et al. 2018 section 5.1).

The phase is 0 at the start of a right-foot contact, 0.5 at the start of a left-foot contact and
linear in between, in cycles (``[0, 1)``), which is how the PFNN captures were hand-labelled.
:func:`global_phase` finds those contact starts automatically (:mod:`jaxstyle.labels.contacts`).

Behaviour away from steps, by design:

* **Clip ends.** Before the first and after the last contact start, the phase continues at the
  rate of the neighbouring step for at most that step's length, then holds: it never claims a
  step that was not seen.
* **Standing still.** With both feet planted there are no contact starts, so the phase holds
  (a clip without any step is constant 0). A pause between two steps is one long interval, over
  which the phase advances slowly and linearly, exactly as the hand labels do.
* **Same foot twice** (the other foot's step was missed or shuffled): a whole cycle is assumed
  between the two starts.
* **Both feet land together** (a two-footed hop, a jump, a shuffle): contact starts closer than
  ``merge_window`` (0.1 s, at least :data:`MIN_MERGE_FRAMES` frames) are one landing, and one foot
  is kept for it (:func:`step_starts`): the one that alternates with the previous step, else the
  one lifted higher before landing. So the phase never advances by half a cycle between two
  frames, and the choice does not depend on which foot is called left: the steps of a mirrored
  clip are the original's with the feet swapped (before, a landing of both feet in one frame kept
  the left foot first, and the mirrored clip lost or gained a step after it).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from jaxstyle.errors import MotionDataError
from jaxstyle.labels import contacts as contacts_lib
from jaxstyle.motion import Motion, kinematics

# Chosen on the hand-labelled PFNN captures; see docs/motion_and_labels.md and experiments/phase_accuracy.py.
# The speeds and the lift are metres of a body the size of the 100STYLE actor (the "scaled" contact rule
# of jaxstyle.labels.contacts). They were tuned as 0.15 m/s, 0.5 m/s and 0.03 m with the PFNN skeleton read
# as 13.65 units per metre (a 1.75 m person); its legs make it 17.02 units per body metre, so the same
# thresholds in file units, the ones tuned, are 0.12, 0.4 and 0.024 body metres.
DEFAULT_CONTACT_MOMENT = "toe"
DEFAULT_SPEED_THRESHOLD_M_S = 0.12
DEFAULT_MAX_GAP_S = 0.05
DEFAULT_MIN_DURATION_S = 0.1
DEFAULT_MIN_LIFT_M = 0.024
DEFAULT_RELEASE_SPEED_M_S = 0.4
DEFAULT_MERGE_WINDOW_S = 0.1
MIN_MERGE_FRAMES = 4
"""With contact starts at least ``MIN_MERGE_FRAMES + 1`` frames apart, the phase moves at most
1/5 cycle per frame (a whole cycle between two starts of the same foot), under the 0.25 limit."""


def circular_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance between phases in cycles, in ``[0, 0.5]``."""
    d = np.mod(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64), 1.0)
    return np.minimum(d, 1.0 - d)


def phase_from_contact_starts(num_frames: int, right_starts: np.ndarray, left_starts: np.ndarray) -> np.ndarray:
    """``(T,)`` phase in ``[0, 1)`` from the frames where right and left contacts start.

    Right starts are phase 0 and left starts phase 0.5; in between the phase is linear (it always
    moves forward: half a cycle between opposite feet, a whole one between two starts of the same
    foot). Ends and pauses behave as described in the module docstring.
    """
    events = sorted([(int(f), 0.0) for f in np.asarray(right_starts).ravel()]
                    + [(int(f), 0.5) for f in np.asarray(left_starts).ravel()])
    # Two starts in one frame (both feet land together): keep the one that alternates.
    kept: list[tuple[int, float]] = []
    for frame, ph in events:
        if kept and kept[-1][0] == frame:
            if len(kept) >= 2 and kept[-2][1] == kept[-1][1] and ph != kept[-1][1]:
                kept[-1] = (frame, ph)
            continue
        kept.append((frame, ph))
    if not kept:
        return np.zeros(num_frames)
    frames = np.array([f for f, _ in kept], dtype=np.float64)
    phases = np.array([p for _, p in kept])
    steps = np.mod(np.diff(phases), 1.0)
    steps[steps == 0] = 1.0
    unwrapped = phases[0] + np.concatenate([[0.0], np.cumsum(steps)])
    t = np.arange(num_frames, dtype=np.float64)
    out = np.interp(t, frames, unwrapped)
    if len(kept) >= 2:
        first_len, last_len = frames[1] - frames[0], frames[-1] - frames[-2]
        first_rate, last_rate = steps[0] / first_len, steps[-1] / last_len
        before = t < frames[0]
        out[before] = unwrapped[0] - first_rate * np.minimum(frames[0] - t[before], first_len)
        after = t > frames[-1]
        out[after] = unwrapped[-1] + last_rate * np.minimum(t[after] - frames[-1], last_len)
    return np.mod(out, 1.0)


def step_starts(onset_TxF: np.ndarray, toe_heights_TxF: np.ndarray, min_lift: float,
                merge_frames: int = 0) -> list[np.ndarray]:
    """Contact starts of each foot that are footsteps, as a list of frame arrays (one per foot).

    A contact start is a footstep unless the previous footstep (of either foot) was made by the
    same foot and that foot's toe did not rise ``min_lift`` (file units) above its landing height
    since its previous contact ended: a foot that pivots or slides and touches down again, or a
    capture glitch that breaks a contact, is not a new step. Hops (the same foot twice, lifted
    in between) are kept.

    Contact starts each at most ``merge_frames`` frames after the one before (0: in the same
    frame) are one landing of both feet, and give one footstep, so footsteps are more than
    ``merge_frames`` frames apart: of the starts that are footsteps by the rule above, the one of
    the foot that did not make the previous footstep, else (no previous footstep) the one lifted
    higher before it landed, then the one of the foot that does not make the next landing, then
    the earlier one. Every test is the same for both feet, so swapping the feet (mirroring) swaps
    the result (unless all of them tie).
    """
    onset = np.asarray(onset_TxF, dtype=bool)
    events = []  # (frame, foot, lift)
    for k in range(onset.shape[1]):
        starts, ends = contacts_lib.runs(onset[:, k])
        for i, s in enumerate(starts):
            if s == 0:
                continue
            prev_end = ends[i - 1] if i > 0 else 0
            lift = float(np.max(toe_heights_TxF[prev_end:s + 1, k]) - toe_heights_TxF[s, k])
            events.append((int(s), k, lift))
    events.sort()
    groups, i = [], 0
    while i < len(events):
        j = i + 1  # a group: starts each at most merge_frames after the one before
        while j < len(events) and events[j][0] - events[j - 1][0] <= merge_frames:
            j += 1
        groups.append(events[i:j])
        i = j
    kept: list[tuple[int, int]] = []
    for g, group in enumerate(groups):
        prev = kept[-1][1] if kept else None
        steps = [e for e in group if not (e[1] == prev and e[2] < min_lift)]
        if steps:
            # alternating foot first, then the higher lift, then the foot that alternates with the next
            # group if one foot makes it, then the earlier frame (the foot's index decides only if all tie)
            next_feet = {e[1] for e in groups[g + 1]} if g + 1 < len(groups) else set()
            after = next_feet.pop() if len(next_feet) == 1 else None
            frame, foot, _ = min(steps, key=lambda e: (e[1] == prev, -e[2], e[1] == after, e[0]))
            kept.append((frame, foot))
    return [np.array([f for f, k in kept if k == foot], dtype=np.int64) for foot in range(onset.shape[1])]


@dataclasses.dataclass(frozen=True)
class FootstepConfig:
    """How footsteps are found for the global phase; the defaults were chosen on the hand-labelled
    PFNN captures (``experiments/phase_accuracy.py``).

    Attributes:
      contact_moment: which moment starts a contact: ``"toe"`` (the toe joint touches down, the
        default), ``"heel"`` (heel strike), ``"first"`` (either) or ``"planted"`` (both; the
        whole foot is flat). See :meth:`jaxstyle.labels.contacts.FootContacts.moment`.
      contacts: the contact test (:class:`jaxstyle.labels.contacts.ContactConfig`), here with
        ``height_threshold`` off (a slow foot is a planted foot, also on a step or a box, and the
        speed test alone finds every stance on the PFNN captures, whose last steps land on a
        raised surface); ``speed_threshold`` 0.12 m/s (a contact starts when the joint slows below
        it); ``release_speed`` 0.4 m/s (the contact lasts until the joint is faster, so a planted
        foot that slides or jitters, as on the PFNN captures' last steps, stays one contact);
        ``max_gap`` 0.05 s (a contact broken this long, a glitch in the capture, is one contact);
        ``min_duration`` 0.1 s (shorter contacts, a toe scuffing a stair edge, are ignored).
      min_lift: metres; see :func:`step_starts`.
      merge_window: seconds; contact starts this close are one landing of both feet, one footstep
        (:func:`step_starts`; at least :data:`MIN_MERGE_FRAMES` frames; 0: only starts in one frame).
    """

    contact_moment: str = DEFAULT_CONTACT_MOMENT
    contacts: contacts_lib.ContactConfig = contacts_lib.ContactConfig(
        height_threshold=None, speed_threshold=DEFAULT_SPEED_THRESHOLD_M_S, release_speed=DEFAULT_RELEASE_SPEED_M_S,
        max_gap=DEFAULT_MAX_GAP_S, min_duration=DEFAULT_MIN_DURATION_S)
    min_lift: float = DEFAULT_MIN_LIFT_M
    merge_window: float = DEFAULT_MERGE_WINDOW_S


def footsteps(motion: Motion, config: FootstepConfig = FootstepConfig(), *,
              units_per_meter: float | None = None, feet: contacts_lib.FootJoints | None = None,
              positions_TxJx3: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Frames where footsteps start, ``(left, right)``; the events :func:`global_phase` uses.

    Args:
      config: contact moment, contact test, lift and merging (:class:`FootstepConfig`).
      units_per_meter, feet, positions_TxJx3: see :func:`jaxstyle.labels.contacts.foot_contacts`.
    """
    feet = feet or contacts_lib.FootJoints.find(motion)
    upm = (contacts_lib.contact_units_per_meter(motion, config.contacts.rule, feet) if units_per_meter is None
           else float(units_per_meter))
    pos = kinematics.global_positions(motion) if positions_TxJx3 is None else positions_TxJx3
    fc = contacts_lib.foot_contacts(motion, config.contacts, units_per_meter=upm, feet=feet, positions_TxJx3=pos)
    toe_heights = pos[:, list(feet.toes), kinematics.UP_AXIS]
    merge = config.merge_window
    merge_frames = max(int(round(merge * motion.fps)), MIN_MERGE_FRAMES) if merge > 0 else 0
    left, right = step_starts(fc.moment(config.contact_moment), toe_heights, config.min_lift * upm, merge_frames)
    return left, right


def global_phase(motion: Motion, config: FootstepConfig = FootstepConfig(), *,
                 positions_TxJx3: np.ndarray | None = None) -> np.ndarray:
    """``(T,)`` PFNN phase in ``[0, 1)``: 0 where right footsteps start, 0.5 where left ones do.

    ``config`` says how footsteps are found (:func:`footsteps`); ``positions_TxJx3``: global joint
    positions, if already computed.
    """
    left, right = footsteps(motion, config, positions_TxJx3=positions_TxJx3)
    return phase_from_contact_starts(motion.num_frames, right, left)


def label_errors(bvh_path: str | os.PathLike, config: FootstepConfig = FootstepConfig()) -> np.ndarray:
    """Circular errors (cycles) of :func:`global_phase` against a capture's hand-cleaned labels,
    over its labelled frames only (see :func:`read_phase_labels`)."""
    from jaxstyle.motion.bvh import read_bvh

    labels, labelled = read_phase_labels(bvh_path)
    motion = read_bvh(bvh_path)
    if motion.num_frames != len(labels):
        raise ValueError(f"{bvh_path}: {motion.num_frames} frames but {len(labels)} phase labels")
    return circular_distance(global_phase(motion, config)[labelled], labels[labelled])


def read_footsteps(path: str | os.PathLike) -> np.ndarray:
    """The hand-labelled footstep frames of a PFNN capture's ``<name>_footsteps.txt``, 0-based.

    The files count frames from 1: the phase label 0 (right) or 0.5 (left) of a listed step ``n``
    sits on line ``n`` of ``<name>.phase``, i.e. 0-based frame ``n - 1`` (checked on every shared
    capture by ``tests/test_contacts_phase.py``)."""
    path = Path(path)
    try:
        return np.array([int(tok) for tok in path.read_text().split()], dtype=np.int64) - 1
    except ValueError as e:
        raise MotionDataError(f"cannot read footstep labels: {e}", path) from None


def read_phase_labels(bvh_path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Hand-cleaned PFNN phase labels of a capture: ``(phase_T, labelled_T)``.

    Reads ``<name>.phase`` (one phase in ``[0, 1)`` per frame) and ``<name>_footsteps.txt``
    beside ``<name>.bvh``. A frame is labelled only between the first and last footstep listed
    (:func:`read_footsteps`, 1-based in the file; clipped to the clip); outside that range the
    file holds 0 meaning "unlabelled", and a file
    with a single footstep has no labelled frame.
    """
    bvh_path = Path(bvh_path)
    stem = bvh_path.with_suffix("")
    phase_path, steps_path = Path(f"{stem}.phase"), Path(f"{stem}_footsteps.txt")
    for p in (phase_path, steps_path):
        if not p.is_file():
            raise FileNotFoundError(f"{p} not found (phase labels of {bvh_path})")
    try:
        phase = np.loadtxt(phase_path, dtype=np.float64, ndmin=1)
    except ValueError as e:
        raise MotionDataError(f"cannot read phase labels: {e}", phase_path) from None
    steps = read_footsteps(steps_path)
    if phase.ndim != 1 or not np.isfinite(phase).all() or (phase < 0).any() or (phase >= 1).any():
        raise MotionDataError("phase labels must be one finite value in [0, 1) per line", phase_path)
    labelled = np.zeros(len(phase), dtype=bool)
    if len(steps) >= 2:
        labelled[max(int(steps.min()), 0):min(int(steps.max()), len(phase) - 1) + 1] = True
    return phase, labelled
