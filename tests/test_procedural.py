"""The procedural locomotion generator (jaxstyle.data.procedural): geometry, exact labels, styles,
the dataset folder it writes, and the automatic labellers checked against its exact labels.

No motion capture needed; clips are 8-10 s so the whole file runs in seconds.
"""

from __future__ import annotations

import csv
import functools
import json

import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.data import procedural as P
from jaxstyle.data.clips import specs_100style
from jaxstyle.labels.contacts import runs
from jaxstyle.labels.phase import circular_distance

SECONDS = 10.0
CLIPS = [(s, g) for s in P.STYLES for g in P.GAITS]


@functools.lru_cache(maxsize=None)
def clip(style: str, gait: str, seed: int = 0, turning: bool = True, speed_changes: bool = True):
    gen = P.generate(style, gait, seconds=SECONDS, seed=seed, turning=turning, speed_changes=speed_changes)
    return gen, js.global_positions(gen.motion)


def contact_runs(mask_T):
    """(start, stop) of each contact run that starts and ends inside the clip."""
    starts, stops = runs(mask_T)
    return [(a, b) for a, b in zip(starts, stops, strict=True) if a > 0 and b < len(mask_T)]


# ---------------------------------------------------------------------------------------- skeleton


def test_skeleton_is_cmu_like_and_human_sized():
    skel = P.skeleton()
    assert skel.num_frames == 1 and skel.num_joints == 25
    assert skel.names[0] == "Hips" and skel.channels[0][:3] == ("Xposition", "Yposition", "Zposition")
    assert all(len(c) == 3 for c in skel.channels[1:])
    found = js.find_feet_and_hands(skel.names)
    assert found == {"ankles": ("LeftFoot", "RightFoot"), "toes": ("LeftToeBase", "RightToeBase"),
                     "hands": ("LeftHand", "RightHand")}
    assert js.find_hips_and_shoulders(skel.names) == (("LeftUpLeg", "RightUpLeg"), ("LeftArm", "RightArm"))
    pairs = js.mirror_pairs(skel.names)
    assert skel.names[pairs[skel.joint_index("LHipJoint")]] == "RHipJoint"
    np.testing.assert_allclose(skel.offsets[pairs] * [-1, 1, 1], skel.offsets)  # symmetric
    lengths = dict(zip(skel.names, js.bone_lengths(skel), strict=True))
    assert lengths["LeftLeg"] == pytest.approx(42) and lengths["LeftFoot"] == pytest.approx(42)
    assert 13 <= lengths["LeftToeBase"] <= 15
    assert 170 <= js.skeleton_height(skel) <= 180
    assert js.estimate_units_per_meter(skel) == 100.0
    pos = js.global_positions(skel)[0]
    assert pos[skel.joint_index("LeftToeBase"), 1] == pytest.approx(P.TOE_HEIGHT)  # standing on the floor
    assert pos[skel.joint_index("LeftFoot"), 1] == pytest.approx(P.ANKLE_HEIGHT)
    # Facing +Z with the left side on +X, as the library's facing direction reads it.
    np.testing.assert_allclose(js.facing_directions(skel)[0], [0, 0, 1], atol=1e-12)


# ---------------------------------------------------------------------------------------- geometry


@pytest.mark.parametrize("style,gait", [("Neutral", "FR"), ("Limping", "FW"), ("Crouched", "FR")])
def test_bone_lengths_are_the_rest_offsets_in_every_frame(style, gait):
    gen, pos = clip(style, gait)
    m = gen.motion
    child = np.flatnonzero(m.parents >= 0)
    lengths = np.linalg.norm(pos[:, child] - pos[:, m.parents[child]], axis=-1)  # (T, J-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(js.bone_lengths(m)[child], lengths.shape), atol=1e-9)
    np.testing.assert_array_equal(m.local_positions[:, 1:], np.broadcast_to(m.offsets[1:], (m.num_frames, 24, 3)))
    np.testing.assert_allclose(np.linalg.norm(m.rotations, axis=-1), 1.0, atol=1e-12)


@pytest.mark.parametrize("style,gait", CLIPS)
def test_stance_feet_are_planted_flat_and_swing_feet_lift_and_move(style, gait):
    gen, pos = clip(style, gait)
    m = gen.motion
    ankles = m.joint_indices(["LeftFoot", "RightFoot"])
    toes = m.joint_indices(["LeftToeBase", "RightToeBase"])
    contacts = gen.contacts
    assert contacts.any(axis=0).all() and (~contacts).any(axis=0).all()
    for k in range(2):
        for joint, height in ((ankles[k], P.ANKLE_HEIGHT), (toes[k], P.TOE_HEIGHT)):
            for a, b in contact_runs(contacts[:, k]):
                planted = pos[a:b, joint]
                assert np.abs(planted - planted[0]).max() < 1e-9, f"foot {k} slides in stance {a}-{b}"
                np.testing.assert_allclose(planted[:, 1], height, atol=1e-9)  # flat on the floor
        swing = ~contacts[:, k]
        assert (pos[swing, ankles[k], 1] > P.ANKLE_HEIGHT).all()
        assert pos[swing, toes[k], 1].min() > P.TOE_HEIGHT - 0.5
        speed = np.linalg.norm(np.gradient(pos[:, ankles[k]], axis=0), axis=-1) * m.fps
        assert (speed[swing] > 0).all()
        root_speed = np.linalg.norm(np.diff(pos[:, 0, ::2], axis=0), axis=-1).mean() * m.fps
        assert speed[swing].mean() > 1.2 * root_speed  # a swinging foot outruns the body (by 1 / (1 - duty))
    # Legs never reach full extension (the pelvis is lowered instead).
    for hip, ankle in (("LeftUpLeg", "LeftFoot"), ("RightUpLeg", "RightFoot")):
        reach = np.linalg.norm(pos[:, m.joint_index(hip)] - pos[:, m.joint_index(ankle)], axis=-1)
        assert reach.max() <= P.REACH * 84.0 + 1e-6


def test_speed_and_turning_stay_in_their_bands():
    for gait, (lo, hi) in (("FW", (0.8, 1.7)), ("FR", (2.4, 3.6))):
        gen, pos = clip("Neutral", gait, seed=3)
        root = pos[:, 0, ::2] / 100.0
        fps = gen.motion.fps
        speed = np.linalg.norm(root[60:] - root[:-60], axis=-1)  # m/s over 1 s windows
        assert lo - 0.1 <= speed.min() and speed.max() <= hi + 0.1
        facing = js.facing_directions(gen.motion, smooth_sigma=20)
        rate = np.degrees(np.gradient(np.unwrap(np.arctan2(facing[:, 0], facing[:, 2])))) * fps
        assert np.abs(rate).max() < 70 and np.ptp(rate) > 10  # it turns, within about +-60 deg/s


def test_straight_constant_speed_path():
    for gait in P.GAITS:
        gen, pos = clip("Proud", gait, turning=False, speed_changes=False)
        root = pos[:, 0]
        assert np.abs(root[:, 0]).max() < 5.0  # only the pelvis sway, in cm
        vz = np.diff(root[:, 2]) * gen.motion.fps
        np.testing.assert_allclose(vz, vz.mean(), rtol=1e-6)
        assert vz.mean() > 0
        steps = np.diff(gen.right_steps)
        assert steps.max() - steps.min() <= 1  # constant cadence
        # Footprints lie on two straight lines beside the path.
        for k, side in ((0, 1.0), (1, -1.0)):
            x = pos[gen.contacts[:, k], gen.motion.joint_index(("LeftFoot", "RightFoot")[k]), 0]
            np.testing.assert_allclose(x, side * P.STYLES["Proud"].step_width, atol=1e-9)


def test_same_seed_same_motion_other_seed_other_motion():
    a = P.generate("Bouncy", "FW", seconds=4, seed=7)
    b = P.generate("Bouncy", "FW", seconds=4, seed=7)
    c = P.generate("Bouncy", "FW", seconds=4, seed=8)
    np.testing.assert_array_equal(a.motion.rotations, b.motion.rotations)
    np.testing.assert_array_equal(a.motion.local_positions, b.motion.local_positions)
    np.testing.assert_array_equal(a.phase, b.phase)
    assert not np.allclose(a.motion.local_positions, c.motion.local_positions)
    assert a.motion.source == "procedural:Bouncy_FW(seed=7)"
    assert a.motion.num_frames == 240 and a.motion.fps == 60.0


# ---------------------------------------------------------------------------------------- exact labels


@pytest.mark.parametrize("style,gait", CLIPS)
def test_exact_labels_are_consistent(style, gait):
    gen, _ = clip(style, gait)
    t = gen.motion.num_frames
    assert gen.phase.shape == (t,) and gen.contacts.shape == (t, 2) and gen.contacts.dtype == bool
    assert ((gen.phase >= 0) & (gen.phase < 1)).all()
    np.testing.assert_allclose(gen.phase[gen.right_steps], 0.0, atol=1e-12)
    np.testing.assert_allclose(gen.phase[gen.left_steps], 0.5, atol=1e-12)
    for k, steps in ((0, gen.left_steps), (1, gen.right_steps)):
        starts = np.flatnonzero(gen.contacts[1:, k] & ~gen.contacts[:-1, k]) + 1
        np.testing.assert_array_equal(steps[steps > 0], starts)
    # The phase always moves forward, by less than a tenth of a cycle a frame; also at the clip
    # ends, where it is exact (the gait runs on beyond them).
    d = np.mod(np.diff(gen.phase), 1.0)
    assert (d > 0).all() and (d < 0.1).all()
    # Feet alternate.
    events = sorted([(f, "L") for f in gen.left_steps] + [(f, "R") for f in gen.right_steps])
    assert all(a[1] != b[1] for a, b in zip(events, events[1:], strict=False))


def test_limp_is_asymmetric_in_timing_and_the_others_are_not():
    for gait in P.GAITS:
        for style in ("Neutral", "Limping"):
            gen, pos = clip(style, gait, turning=False, speed_changes=False)
            r, left = gen.right_steps, gen.left_steps
            right_to_left = [left[left > a][0] - a for a in r if (left > a).any()]
            left_to_right = [r[r > a][0] - a for a in left if (r > a).any()]
            ratio = np.median(right_to_left) / np.median(left_to_right)
            stance = [np.median([b - a for a, b in contact_runs(gen.contacts[:, k])]) for k in range(2)]
            if style == "Neutral":
                assert 0.9 < ratio < 1.1 and abs(stance[0] - stance[1]) <= 1
            else:
                # Left touches down late in the cycle (0.58): the right-to-left step takes longer, the
                # phase has two slopes; the painful left leg's stance is shorter.
                assert ratio > 1.25, ratio
                assert stance[1] > stance[0] + 3
                # The right (good) leg's step is the shorter one: its footprint lands closer ahead of the left.
                feet = {k: pos[gen.contacts[:, k], m_idx, 2] for k, m_idx in
                        ((0, gen.motion.joint_index("LeftFoot")), (1, gen.motion.joint_index("RightFoot")))}
                prints = sorted([(z, "L") for z in np.unique(np.round(feet[0], 6))]
                                + [(z, "R") for z in np.unique(np.round(feet[1], 6))])
                ahead = {"L": [], "R": []}
                for (z0, _), (z1, f1) in zip(prints, prints[1:], strict=False):
                    ahead[f1].append(z1 - z0)
                assert np.median(ahead["R"]) < np.median(ahead["L"]) - 3


# ---------------------------------------------------------------------------------------- the labellers


@pytest.mark.parametrize("style,gait", CLIPS)
def test_global_phase_labeller_matches_the_exact_phase(style, gait):
    """The contact-based labeller finds every footstep within one frame of the exact one.

    A swing here ends with zero foot velocity, so the toe slows below the labeller's 0.15 m/s
    a frame early at most (measured: detected starts are 0 or 1 frame off, median 0). One
    frame of offset moves the phase by at most 0.5 / (frames in that step) near the step: that
    is the bound on the median error; the maximum gets two frames' worth.
    """
    gen, pos = clip(style, gait)
    left, right = js.footsteps(gen.motion, positions_TxJx3=pos)
    assert len(left) == len(gen.left_steps[gen.left_steps > 0])
    assert len(right) == len(gen.right_steps[gen.right_steps > 0])
    for found, exact in ((left, gen.left_steps[gen.left_steps > 0]), (right, gen.right_steps[gen.right_steps > 0])):
        assert np.abs(found - exact).max() <= 1
    phase = js.global_phase(gen.motion, positions_TxJx3=pos)
    steps = np.sort(np.concatenate([gen.left_steps, gen.right_steps]))
    err = circular_distance(phase, gen.phase)[steps[0]:steps[-1] + 1]
    one_frame = 0.5 / np.diff(steps).min()
    assert np.median(err) <= one_frame
    assert err.max() <= 2 * one_frame


@pytest.mark.parametrize("style,gait", CLIPS)
def test_foot_contacts_match_the_exact_contacts(style, gait):
    """The 2022 paper's contact rule (ball of 1 cm on the per-clip floor, speed below 0.15 m/s;
    ``foot`` = heel or toe) against the exact contacts.

    Measured over the 12 clips: 96-99 % of frames agree; the labeller starts a contact at most a
    frame early and ends it up to 3 frames late (the foot is slow near the ends of a swing, and
    both tests pass there), and misses only the first planted frame after a fast touchdown (the
    central-difference speed of that frame includes the last swing frame). So: at least 95 %,
    and every disagreement within 3 frames of an exact contact boundary.
    """
    gen, pos = clip(style, gait)
    labelled = js.foot_contacts(gen.motion, positions_TxJx3=pos).foot
    assert (labelled == gen.contacts).mean() >= 0.95
    for k in range(2):
        boundaries = np.flatnonzero(np.diff(gen.contacts[:, k].astype(int))) + 0.5
        wrong = np.flatnonzero(labelled[:, k] != gen.contacts[:, k])
        if len(wrong):
            assert np.abs(wrong[:, None] - boundaries[None]).min(axis=1).max() <= 3


# ---------------------------------------------------------------------------------------- styles


def _per_cycle(values_T, steps):
    return np.median([np.ptp(values_T[a:b]) for a, b in zip(steps[:-1], steps[1:], strict=True)])


def _hand_swing(gen, pos):
    """Per-cycle range of the hands' distance ahead of the pelvis (on a straight path along +Z)."""
    hands = gen.motion.joint_indices(["LeftHand", "RightHand"])
    forward = pos[:, hands, 2] - pos[:, :1, 2]
    return max(_per_cycle(forward[:, k], gen.right_steps) for k in range(2))


def test_styles_look_different():
    for gait in P.GAITS:
        c = {s: clip(s, gait, turning=False, speed_changes=False) for s in P.STYLES}
        pelvis = {s: pos[:, 0, 1] for s, (_, pos) in c.items()}
        assert pelvis["Crouched"].mean() < pelvis["Neutral"].mean() - 10
        bob = {s: _per_cycle(pelvis[s], c[s][0].right_steps) for s in c}
        assert bob["Bouncy"] > 1.5 * bob["Neutral"], bob

        assert _hand_swing(*c["ArmSwing"]) > 2.5 * _hand_swing(*c["Proud"])
        # Proud leans back, Crouched forward: the neck relative to the pelvis along the path.
        lean = {s: np.median(pos[:, c[s][0].motion.joint_index("Neck"), 2] - pos[:, 0, 2]) for s, (_, pos) in c.items()}
        assert lean["Proud"] < lean["Neutral"] < lean["Crouched"]


def test_style_table():
    assert set(P.STYLES) >= {"Neutral", "Crouched", "Bouncy", "ArmSwing", "Limping", "Proud"}
    assert P.GAITS == ("FW", "FR")
    assert [s for s, p in P.STYLES.items() if not p.symmetric] == ["Limping"]
    assert P.STYLES["Limping"].left_touchdown != 0.5
    for p in P.STYLES.values():
        assert p.description and "\n" not in p.description
        with pytest.raises(AttributeError):
            p.bob = 0.0  # frozen


# ---------------------------------------------------------------------------------------- dataset


def test_write_dataset_reads_back(tmp_path):
    root = P.write_dataset(tmp_path / "proc", ["Neutral", "Limping"], seconds=8, seed=5)
    assert root == tmp_path / "proc"
    specs = specs_100style(root)
    listed = sorted((s.style, s.gait, s.mirror) for s in specs)
    assert listed == [("Limping", "FR", False), ("Limping", "FW", False),
                      ("Neutral", "FR", False), ("Neutral", "FR", True),
                      ("Neutral", "FW", False), ("Neutral", "FW", True)]
    assert all(s.start == 0 and s.stop == 480 for s in specs)
    with open(root / "Frame_Cuts.csv", newline="") as f:
        header = next(csv.reader(f))
    assert header[0] == "STYLE_NAME" and len(header) == 21 and header[-1] == "TR3_STOP"
    settings = json.loads((root / "procedural.json").read_text())
    assert settings["version"] == P.VERSION and settings["seconds"] == 8 and settings["seed"] == 5
    seeds = {(c["style"], c["gait"]): c["seed"] for c in settings["clips"]}
    assert len(set(seeds.values())) == 4  # every clip its own seed

    gen = P.generate("Limping", "FW", seconds=8, seed=seeds["Limping", "FW"])
    path = root / "Limping" / "Limping_FW.bvh"
    read = js.read_bvh(path)
    assert read.names == gen.motion.names and read.fps == 60.0
    np.testing.assert_allclose(js.global_positions(read, end_sites=True),
                               js.global_positions(gen.motion, end_sites=True), atol=2e-3)
    phase, labelled = js.read_phase_labels(path)
    steps = np.sort(np.concatenate([gen.left_steps, gen.right_steps]))
    assert circular_distance(phase, gen.phase).max() < 1e-8
    assert labelled.sum() == steps[-1] - steps[0] + 1
    contacts = np.loadtxt(root / "Limping" / "Limping_FW_contacts.txt", dtype=int)
    np.testing.assert_array_equal(contacts.astype(bool), gen.contacts)
    # Other clips differ from this one.
    other = js.read_bvh(root / "Neutral" / "Neutral_FW.bvh")
    assert not np.allclose(other.local_positions[:, 0], read.local_positions[:, 0])


@pytest.mark.parametrize("call,match", [
    (lambda: P.generate("Sneaky"), r"'Sneaky'.*Neutral, Crouched"),
    (lambda: P.generate("Neutral", "BW"), r"'BW'.*FW, FR"),
    (lambda: P.generate("Neutral", seconds=2.5), r"seconds.*>= 3.*2\.5"),
    (lambda: P.generate("Neutral", seconds=float("nan")), r"seconds.*nan"),
    (lambda: P.generate("Neutral", fps=0), r"fps.*positive.*got 0"),
    (lambda: P.generate("Neutral", fps=-60.0), r"fps.*-60"),
    (lambda: P.generate("Neutral", fps=5), r"fps.*at least 10.*5"),
    (lambda: P.generate("Neutral", seed=-1), r"seed.*non-negative.*-1"),
    (lambda: P.write_dataset("/nonexistent/never", ["Neutral", "neutral"]), r"'neutral'.*Neutral"),
    (lambda: P.write_dataset("/nonexistent/never", gaits=["FW", "SR"]), r"'SR'.*FW, FR"),
    (lambda: P.write_dataset("/nonexistent/never", fps=-1), r"fps"),
    (lambda: P.write_dataset("/nonexistent/never", styles=[]), r"no styles"),
])
def test_bad_arguments_raise_clear_value_errors(call, match):
    with pytest.raises(ValueError, match=match):
        call()
