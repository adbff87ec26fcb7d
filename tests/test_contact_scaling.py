"""Foot contacts on skeletons of any unit, size and frame rate.

The default ``"scaled"`` rule measures the paper's 0.01 m / 0.15 m/s in metres of a body with the
100STYLE actor's legs and speeds over a fixed time span; ``"paper2022"`` is the paper's setting.
Real clips of the shared data (100STYLE, Xia and PFNN, the last two on Holden's CMU skeleton) are
re-expressed in other units (x0.01, x2.54, x100), shrunk and grown (x0.7, x1.3) and resampled to
30, 60 and 120 fps. Stated tolerances: the same contact flags in every frame after a change of
units or size; after resampling, flags agreeing with the original's nearest frame in at least 97%
of frames and a stance fraction within 0.015 (measured: 97.5-100% and within 0.011).
"""

from __future__ import annotations

import numpy as np
import pytest

from jaxstyle.labels import contacts
from jaxstyle.motion import bvh, kinematics, transform

CLIPS = ("100style/Neutral/Neutral_FW.bvh", "100style/Elated/Elated_FW.bvh", "xia/neutral_01_000.bvh",
         "pfnn_excerpt/NewCaptures01_000.bvh")
SCALES = (0.01, 2.54, 100.0, 0.7, 1.3)
MIN_AGREEMENT = 0.97
MAX_FRACTION_CHANGE = 0.015


def _clip(mocap, name):
    motion = bvh.read_bvh(mocap / name)
    return motion.frames(0, 1200) if motion.num_frames > 1200 else motion


@pytest.fixture(scope="module")
def clips(mocap):
    return {name: _clip(mocap, name) for name in CLIPS}


@pytest.mark.parametrize("name", CLIPS)
def test_contacts_do_not_depend_on_units_or_size(clips, name):
    motion = clips[name]
    ref = contacts.foot_contacts(motion)
    assert 0.3 < ref.foot.mean() < 0.9
    for s in SCALES:
        got = contacts.foot_contacts(transform.scale(motion, s))
        np.testing.assert_array_equal(got.heel, ref.heel, err_msg=f"{name} x{s}")
        np.testing.assert_array_equal(got.toe, ref.toe, err_msg=f"{name} x{s}")


@pytest.mark.parametrize("name", CLIPS)
def test_contacts_do_not_depend_on_the_frame_rate(clips, name):
    motion = clips[name]
    ref = contacts.foot_contacts(motion).foot
    for fps in (30.0, 60.0, 120.0):
        if fps == motion.fps:
            continue
        resampled = transform.resample(motion, fps)
        got = contacts.foot_contacts(resampled).foot
        nearest = np.minimum(np.round(np.arange(resampled.num_frames) * motion.fps / fps).astype(int),
                             motion.num_frames - 1)
        assert (got == ref[nearest]).mean() >= MIN_AGREEMENT, (name, fps)
        assert abs(got.mean() - ref.mean()) <= MAX_FRACTION_CHANGE, (name, fps)


def test_the_paper_rule_fails_the_size_test_that_the_scaled_rule_passes(clips):
    """The regression: the paper's unit guess treats a 100STYLE skeleton shrunk to 0.7 (125 cm) as
    centimetres and a CMU one in x100 units as millimetres, and the contacts change."""
    for name, s in (("100style/Elated/Elated_FW.bvh", 0.7), ("xia/neutral_01_000.bvh", 100.0)):
        motion = clips[name]
        ref = contacts.foot_contacts(motion, contacts.ContactConfig(rule="paper2022")).foot
        got = contacts.foot_contacts(transform.scale(motion, s), contacts.ContactConfig(rule="paper2022")).foot
        assert (got == ref).mean() < 0.95


def _paper_reference(motion):
    """The paper's rule written out in NumPy: per joint, height above its 5th-percentile floor under
    0.01 m and central-difference speed under 0.15 m/s, metres from the skeleton's height."""
    feet = contacts.FootJoints.find(motion)
    pos = kinematics.global_positions(motion)[:, list(feet.ankles) + list(feet.toes)]
    height = kinematics.skeleton_height(motion)
    upm = next((u for u in (1.0, 100.0, 1000.0) if 1.2 * u <= height <= 2.5 * u), height / 1.75)
    h = pos[..., 1]
    low = h - np.percentile(h, 5.0, axis=0) < 0.01 * upm
    speed = np.linalg.norm(np.gradient(pos, axis=0), axis=-1) * motion.fps
    flags = low & (speed < 0.15 * upm)
    return flags[:, :2] | flags[:, 2:]


@pytest.mark.parametrize("name", CLIPS)
def test_paper2022_is_the_papers_rule(clips, name):
    motion = clips[name]
    paper = contacts.ContactConfig(rule="paper2022")
    np.testing.assert_array_equal(contacts.foot_contacts(motion, paper).foot, _paper_reference(motion))


def test_on_100style_the_scaled_rule_is_the_papers(clips):
    for name in CLIPS[:2]:
        motion = clips[name]
        assert contacts.body_units_per_meter(motion) == 100.0
        np.testing.assert_array_equal(contacts.foot_contacts(motion).foot, _paper_reference(motion))
        # local phases read the clip in these metres too: the LPN's features on 100STYLE are the paper's
        assert contacts.contact_units_per_meter(motion, "paper2022") == 100.0


def test_speeds_over_a_time_span():
    rng = np.random.default_rng(0)
    for fps in (30.0, 60.0, 120.0, 47.0):
        t = np.arange(int(2 * fps)) / fps
        v = rng.normal(size=3)
        line = t[:, None, None] * v  # constant velocity: exact everywhere, ends included
        np.testing.assert_allclose(contacts.joint_speeds(line, fps, span=2 / 60), np.linalg.norm(v), rtol=1e-12)
        a = rng.normal(size=3)
        quad = (t ** 2)[:, None, None] * a  # central differences are exact on a parabola
        inner = slice(int(np.ceil(fps / 60)) + 1, len(t) - int(np.ceil(fps / 60)) - 1)
        np.testing.assert_allclose(contacts.joint_speeds(quad, fps, span=2 / 60)[inner, 0],
                                   np.linalg.norm(2 * a) * t[inner], rtol=1e-9)
    pos = rng.normal(size=(50, 2, 3))  # at 60 fps the span is the per-frame central difference
    np.testing.assert_allclose(contacts.joint_speeds(pos, 60.0, span=2 / 60), contacts.joint_speeds(pos, 60.0),
                               rtol=1e-12)


def test_unknown_rule():
    with pytest.raises(ValueError, match="paper2022"):
        contacts.speed_span("paper")
