"""Both feet landing together: no half-cycle jump of the global phase between two
frames, and the footsteps of a mirrored clip are the original's with the feet swapped.

Before the fix, on the shared data: Xia ``neutral_16_000`` and ``old_16_000`` (jumps) had 2 and 3
frames where the phase moved by 0.5 cycle, and the mirrors of 100STYLE ``Drunk_FR`` and
``misc/unknown_style_run_30fps`` gained or lost a step after a landing of both feet in one frame.
"""

from __future__ import annotations

import numpy as np
import pytest

from jaxstyle.labels import phase
from jaxstyle.motion import bvh, transform

MAX_JUMP = 0.25


def phase_jumps(p: np.ndarray) -> np.ndarray:
    """Circular change of the phase between consecutive frames, in cycles."""
    return phase.circular_distance(p[1:], p[:-1])


def all_clips(mocap):
    return [p for p in sorted(mocap.rglob("*.bvh")) if bvh.read_bvh(p).num_frames >= 3]


HOPS = ("xia/neutral_16_000.bvh", "xia/old_16_000.bvh", "100style/Drunk/Drunk_FR.bvh",
        "misc/unknown_style_run_30fps.bvh", "100style/Elated/Elated_FW.bvh", "xia/childlike_16_000.bvh")
"""The clips where the bugs showed, and two more stylised or jumping ones."""


def check_clips(paths) -> None:
    for path in paths:
        motion = bvh.read_bvh(path)
        left, right = phase.footsteps(motion)
        p = phase.phase_from_contact_starts(motion.num_frames, right, left)
        assert phase_jumps(p).max() < MAX_JUMP, path
        m_left, m_right = phase.footsteps(transform.mirror(motion))
        np.testing.assert_array_equal(m_left, right, err_msg=str(path))
        np.testing.assert_array_equal(m_right, left, err_msg=str(path))


def test_hop_clips_no_phase_jump_and_exact_mirrored_steps(mocap):
    check_clips([mocap / name for name in HOPS])


@pytest.mark.slow
def test_every_shared_clip_no_phase_jump_and_exact_mirrored_steps(mocap):
    """All shared clips (100STYLE, Xia, PFNN, misc) and their mirrors (12 s)."""
    clips = all_clips(mocap)
    assert len(clips) >= 80
    check_clips(clips)


def test_hops_keep_one_step_per_landing(mocap):
    motion = bvh.read_bvh(mocap / "xia" / "neutral_16_000.bvh")
    left, right = phase.footsteps(motion)
    both = np.sort(np.concatenate([left, right]))
    assert len(both) >= 2 and np.diff(both).min() > phase.MIN_MERGE_FRAMES
    # without the merge (only starts in one frame are one landing) the two feet land 1 frame apart
    left0, right0 = phase.footsteps(motion, phase.FootstepConfig(merge_window=0.0))
    p0 = phase.phase_from_contact_starts(motion.num_frames, right0, left0)
    assert phase_jumps(p0).max() >= MAX_JUMP


def _random_case(rng, frames=120):
    onset = np.zeros((frames, 2), dtype=bool)
    for k in range(2):
        t = int(rng.integers(0, 4))
        while t < frames:
            on, off = int(rng.integers(2, 15)), int(rng.integers(1, 15))
            onset[t:t + on, k] = True
            t += on + off
    if rng.random() < 0.5:  # force landings of both feet in one frame
        for s in rng.integers(5, frames - 5, size=3):
            onset[s - 1, :], onset[s:s + 6, :] = False, True
    heights = rng.normal(size=(frames, 2))
    starts = np.diff(onset.astype(int), axis=0, prepend=0) > 0
    heights[starts] = -5.0 - rng.random(int(starts.sum()))  # every lift positive and distinct: no full tie
    return onset, heights


@pytest.mark.parametrize("merge_frames", [0, 2, 4])
def test_step_starts_swapping_the_feet_swaps_the_steps(merge_frames):
    """A property over random contact masks: the rule never prefers a foot by its index, so
    the feet swapped (a mirrored clip) give the steps swapped; and steps are more than
    ``merge_frames`` frames apart. (The lifts are distinct, so the rule never falls back on the
    index; the next-landing tie-break is tested below.)"""
    rng = np.random.default_rng(merge_frames)
    for _ in range(300):
        onset, heights = _random_case(rng)
        min_lift = float(rng.choice([0.0, 0.5, 5.0]))
        left, right = phase.step_starts(onset, heights, min_lift, merge_frames)
        s_left, s_right = phase.step_starts(onset[:, ::-1], heights[:, ::-1], min_lift, merge_frames)
        np.testing.assert_array_equal(s_left, right)
        np.testing.assert_array_equal(s_right, left)
        both = np.sort(np.concatenate([left, right]))
        assert len(np.unique(both)) == len(both)
        if len(both) > 1:
            assert np.diff(both).min() > merge_frames
        if merge_frames >= phase.MIN_MERGE_FRAMES and len(both):
            p = phase.phase_from_contact_starts(len(onset), right, left)
            assert phase_jumps(p).max() <= 1.0 / (phase.MIN_MERGE_FRAMES + 1) + 1e-12


def test_a_landing_of_both_feet_keeps_the_alternating_foot():
    onset = np.zeros((60, 2), dtype=bool)
    onset[10:20, 0] = True  # left step at 10
    onset[30:40, 0] = True  # both land at 30-31: the right foot alternates
    onset[31:40, 1] = True
    heights = np.zeros((60, 2))
    left, right = phase.step_starts(onset, heights, 0.0, merge_frames=2)
    assert left.tolist() == [10] and right.tolist() == [31]
    # the same landing, feet swapped
    s_left, s_right = phase.step_starts(onset[:, ::-1], heights, 0.0, merge_frames=2)
    assert s_right.tolist() == [10] and s_left.tolist() == [31]
    # the first landing of a clip, both feet in one frame, equal lifts: the next start decides
    onset = np.zeros((60, 2), dtype=bool)
    onset[5:15, :] = True
    onset[30:40, 1] = True
    left, right = phase.step_starts(onset, np.zeros((60, 2)), 0.0)
    assert left.tolist() == [5] and right.tolist() == [30]
    s_left, s_right = phase.step_starts(onset[:, ::-1], np.zeros((60, 2)), 0.0)
    assert s_right.tolist() == [5] and s_left.tolist() == [30]
