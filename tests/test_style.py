"""The style distance (jaxstyle.output.style): 0 for a clip against itself, invariant to where and
which way the character walks, and growing as a known perturbation of the pose grows, by the amount
an independent numpy computation gives."""

from __future__ import annotations

import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.data import clips, datasets
from jaxstyle.motion.character_frame import rotate_yaw
from jaxstyle.motion.skeleton import find_feet_and_hands
from jaxstyle.output import style


@pytest.fixture(scope="module")
def walk(mocap):
    spec = next(s for s in clips.specs_100style(mocap / "100style", styles=["Neutral"], gaits=("FW",))
                if not s.mirror)
    clip = datasets.load_clip(spec, fps=60.0)
    return clip, js.global_positions(clip), js.estimate_units_per_meter(clip)


def test_a_clip_against_itself_and_moved_or_turned_is_at_distance_zero(walk):
    clip, pos, upm = walk
    a = style.style_stats(pos, clip, 60.0)
    assert all(v == 0 for v in style.style_distance(a, a).values())
    moved = rotate_yaw(pos, np.full(pos.shape[:2], 1.3)) + np.array([300.0, 0.0, -120.0])  # turned and walked off
    b = style.style_stats(moved, clip, 60.0)
    d = style.style_distance(a, b)
    assert d["style_distance"] < 1e-6, d
    assert np.isfinite(a.stride_m) and a.cadence > 0.5 and 0.2 < a.wrist_below_head_m < 1.2


@pytest.mark.parametrize("lift_m", [0.05, 0.1, 0.2])
def test_raising_the_arms_moves_the_distance_by_the_numpy_reference(walk, lift_m):
    """Both arms (elbows, wrists and below) raised ``lift_m`` in every frame: the pose term is the
    root mean square of that shift over the joints, the arms term the wrists' height change; the
    other terms stay 0 (the feet, the root and so the gait are untouched)."""
    clip, pos, upm = walk
    hands = find_feet_and_hands(clip.names)["hands"]
    moved_joints = set()
    for h in hands:  # the wrist, its parent (forearm) and every joint below the wrist
        j = clip.names.index(h)
        moved_joints |= {j, int(clip.parents[j])}
        moved_joints |= {k for k in range(clip.num_joints) if _is_below(clip.parents, k, j)}
    lifted = pos.copy()
    lifted[:, sorted(moved_joints), 1] += lift_m * upm
    a = style.style_stats(pos, clip, 60.0)
    b = style.style_stats(lifted, clip, 60.0)
    d = style.style_distance(a, b)
    assert d["style_pose_m"] == pytest.approx(lift_m * np.sqrt(len(moved_joints) / clip.num_joints), rel=1e-6)
    assert d["style_arms_m"] == pytest.approx(lift_m, rel=1e-6)
    assert d["style_motion_m"] == pytest.approx(0.0, abs=1e-9) and d["style_gait_m"] == 0.0
    assert d["style_distance"] == pytest.approx(d["style_pose_m"] + lift_m, rel=1e-6)


def _is_below(parents, k: int, ancestor: int) -> bool:
    while k >= 0:
        k = int(parents[k])
        if k == ancestor:
            return True
    return False


def test_halves_and_the_shows_rule(walk):
    clip, pos, upm = walk
    halves = style.halves_distance(pos, clip, 60.0)
    assert 0 < halves < 1.0
    assert style.shows(0.1, 0.5) and not style.shows(0.3, 0.5) and not style.shows(float("nan"), 0.5)
    short = style.style_stats(pos[:10], clip, 60.0)
    assert np.isnan(style.style_distance(short, style.style_stats(pos, clip, 60.0))["style_distance"])
