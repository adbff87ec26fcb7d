"""Quality metrics of generated motion: path error, jitter, foot skating and their summary."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.motion import Motion
from jaxstyle.output import metrics
from tests.synthetic_legs import NAMES, OFFSETS, PARENTS

FPS = 60.0
UPM = 100.0  # centimetres

ANKLES_TOES = [6, 10, 7, 11]  # the order of metrics' foot joints: ankles (left, right), then toes


def synthetic_skeleton(num_frames: int = 2) -> Motion:
    """A small centimetre skeleton whose feet and hands are found by name, in its rest pose."""
    rot = np.zeros((num_frames, len(NAMES), 4))
    rot[..., 0] = 1.0
    local = np.broadcast_to(OFFSETS, (num_frames, len(NAMES), 3)).copy()
    local[:, 0] = [0, 88, 0]
    return Motion(names=NAMES, parents=PARENTS, offsets=OFFSETS, rotations=rot, local_positions=local, fps=FPS,
                  channels=tuple(() for _ in NAMES), end_site_parents=np.zeros(0, dtype=np.int64),
                  end_site_offsets=np.zeros((0, 3)), source="synthetic.bvh")


def test_foot_joint_order_is_ankles_then_toes():
    feet = js.FootJoints.find(synthetic_skeleton())
    assert list(feet.ankles) + list(feet.toes) == ANKLES_TOES


# --- jitter -----------------------------------------------------------------------------------------------------------

def test_jitter_is_zero_for_constant_velocity():
    rng = np.random.default_rng(0)
    t = np.arange(120) / FPS
    start, velocity = rng.normal(size=(5, 3)) * 50, rng.normal(size=(5, 3)) * 100
    pos = start + velocity * t[:, None, None]
    assert metrics.jitter(pos, FPS, units_per_meter=UPM) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("upm", [1.0, 100.0])
def test_jitter_of_a_cubic_is_its_analytic_jerk(upm):
    # x(t) = t^3 metres has jerk d^3x/dt^3 = 6 m/s^3 everywhere; the third difference of a cubic is exact.
    t = np.arange(90) / FPS
    directions = np.array([[1.0, 0, 0], [0, 0.6, 0.8], [-0.48, 0.6, 0.64]])
    pos = upm * (t ** 3)[:, None, None] * directions + 7.0
    assert metrics.jitter(pos, FPS, units_per_meter=upm) == pytest.approx(6.0, rel=1e-6)
    # the scale is m/s^3: the same motion read in the wrong units is 1/upm times off
    assert metrics.jitter(pos, FPS, units_per_meter=1.0) == pytest.approx(6.0 * upm, rel=1e-6)
    assert np.isnan(metrics.jitter(pos[:3], FPS, units_per_meter=upm))


# --- path error -------------------------------------------------------------------------------------------------------

def test_path_error_of_a_shifted_copy_is_the_shift():
    rng = np.random.default_rng(1)
    origin = np.cumsum(rng.normal(size=(200, 2)) * 3.0, axis=0)
    angle = np.linspace(0, 6, 200)
    shift = 0.37 * UPM * np.stack([np.cos(angle), np.sin(angle)], -1)  # 37 cm in a turning direction
    np.testing.assert_allclose(metrics.path_error(origin, origin + shift, units_per_meter=UPM), 0.37, rtol=1e-12)
    np.testing.assert_allclose(metrics.path_error(origin, origin, units_per_meter=UPM), 0.0)


def _dense_polyline_distance(points, polyline, samples_per_segment):
    dense = np.concatenate([a + np.linspace(0, 1, samples_per_segment)[:, None] * (b - a)
                            for a, b in zip(polyline[:-1], polyline[1:], strict=True)])
    return np.sqrt(((points[:, None] - dense[None]) ** 2).sum(-1)).min(axis=1)


def test_path_distance_matches_a_dense_sampling():
    rng = np.random.default_rng(2)
    polyline = np.cumsum(rng.normal(size=(7, 2)) * 80.0, axis=0)
    polyline = np.insert(polyline, 3, polyline[3], axis=0)  # a repeated waypoint: a zero-length segment
    points = rng.uniform(polyline.min(0) - 50, polyline.max(0) + 50, size=(300, 2))
    points[:3] = polyline[[0, 2, -1]]  # on the path
    n = 4001
    want = _dense_polyline_distance(points, polyline, n) / UPM
    spacing = np.linalg.norm(np.diff(polyline, axis=0), axis=-1).max() / (n - 1) / UPM
    got = metrics.path_distance(points, polyline, units_per_meter=UPM)
    assert got.shape == (300,)
    assert np.all(got <= want + 1e-12) and np.all(want - got <= spacing / 2 + 1e-12)
    np.testing.assert_allclose(got[:3], 0.0, atol=1e-12)
    # chunking does not change the answer
    np.testing.assert_array_equal(metrics.path_distance(points, polyline, units_per_meter=UPM, chunk_elements=50),
                                  got)
    # a single waypoint is a point
    np.testing.assert_allclose(metrics.path_distance(points, polyline[:1], units_per_meter=UPM),
                               np.linalg.norm(points - polyline[0], axis=-1) / UPM)


# --- foot skating -----------------------------------------------------------------------------------------------------

def _walker_positions(num_frames: int, foot_velocity_m_s: float, lift_from: int | None = None) -> np.ndarray:
    """Rest-pose joint positions; the body drifts at 1 m/s, the foot joints move at the given speed on
    the floor, from ``lift_from`` 20 cm up and fast (2 m/s sideways)."""
    m = synthetic_skeleton(num_frames)
    pos = js.global_positions(m)
    t = np.arange(num_frames) / FPS
    pos[:, :, 2] += UPM * 1.0 * t[:, None]
    feet = pos[0, ANKLES_TOES].copy()
    feet[:, 1] -= feet[:, 1].min()  # ankles and toes on y = 0 for simplicity
    pos[:, ANKLES_TOES] = feet + np.array([0, 0, UPM * foot_velocity_m_s]) * t[:, None, None]
    if lift_from is not None:
        lift = np.arange(num_frames) >= lift_from
        pos[lift, :, 1] += 20.0
        pos[lift, :, 0] += UPM * 2.0 * t[lift, None]
    return pos


def test_foot_skating_pinned_is_zero_and_sliding_is_its_speed():
    m = synthetic_skeleton()
    pinned = _walker_positions(100, 0.0, lift_from=60)
    assert metrics.foot_skating(pinned, m, FPS, units_per_meter=UPM) == pytest.approx(0.0, abs=1e-12)
    sliding = _walker_positions(100, 0.4, lift_from=60)
    assert metrics.foot_skating(sliding, m, FPS, units_per_meter=UPM) == pytest.approx(0.4, rel=1e-9)
    # the floor can be given (per foot joint); a floor far below leaves no contact
    assert metrics.foot_skating(sliding, m, FPS, units_per_meter=UPM, floor_F=np.zeros(4)) == pytest.approx(0.4)
    assert np.isnan(metrics.foot_skating(sliding, m, FPS, units_per_meter=UPM, floor_F=np.full(4, -50.0)))


def test_foot_skating_with_given_contacts():
    m = synthetic_skeleton()
    sliding = _walker_positions(100, 0.4, lift_from=60)
    t = np.arange(100)
    per_foot = np.stack([t < 30, t >= 80], -1)  # left foot labelled down early (sliding), right late (lifted)
    # the right foot's labels cover the lifted part, where the joints move at sqrt(2^2 + 0.4^2) m/s
    lifted_speed = np.hypot(2.0, 0.4)
    want = (29 * 2 * 0.4 + 19 * 2 * lifted_speed) / (29 * 2 + 19 * 2)
    got = metrics.foot_skating(sliding, m, FPS, units_per_meter=UPM, contacts_TxF=per_foot)
    assert got == pytest.approx(want, rel=1e-9)
    # network outputs in [0, 1] are thresholded at 0.5; per foot joint labels work the same
    soft = np.where(per_foot, 0.8, 0.2)
    assert metrics.foot_skating(sliding, m, FPS, units_per_meter=UPM, contacts_TxF=soft) == pytest.approx(want)
    per_joint = np.concatenate([per_foot, per_foot], axis=1)
    per_joint[:, 2:] = False  # toes never down: half the steps
    want_ankles = (29 * 0.4 + 19 * lifted_speed) / (29 + 19)
    assert metrics.foot_skating(sliding, m, FPS, units_per_meter=UPM, contacts_TxF=per_joint) == pytest.approx(
        want_ankles)


# --- summary ----------------------------------------------------------------------------------------------------------

def test_motion_quality_summary():
    m = synthetic_skeleton()
    pos = _walker_positions(100, 0.0, lift_from=60)
    origin = pos[:, 0][:, [0, 2]]
    q = metrics.motion_quality(pos, m, FPS, units_per_meter=UPM, path_Tx2=origin + [0.0, 25.0])
    assert q.num_frames == 100
    assert q.path_error_mean_m == pytest.approx(0.25) and q.path_error_final_m == pytest.approx(0.25)
    assert q.foot_skating_m_s == pytest.approx(0.0, abs=1e-12)
    assert q.contact_fraction == pytest.approx(0.6)
    np.testing.assert_allclose(q.jitter_m_s3, metrics.jitter(pos, FPS, units_per_meter=UPM))
    errors = metrics.bone_length_errors(pos, m)
    assert q.bone_error_mean == pytest.approx(errors.mean()) and q.bone_error_max == pytest.approx(errors.max())
    assert q.bone_error_max > 0.1  # the feet were moved off the skeleton
    row = q.as_row()
    assert list(row) == ["num_frames", "foot_skating_m_s", "contact_fraction", "bone_error_mean", "bone_error_max",
                         "path_error_mean_m", "path_error_final_m", "jitter_m_s3"]
    assert row["path_error_mean_m"] == q.path_error_mean_m
    no_path = metrics.motion_quality(pos, m, FPS, units_per_meter=UPM)
    assert np.isnan(no_path.path_error_mean_m) and np.isnan(no_path.path_error_final_m)
    with pytest.raises(dataclasses.FrozenInstanceError):
        q.jitter_m_s3 = 0.0


def test_reference_quality_of_a_real_walk(mocap):
    m = js.read_bvh(mocap / "100style/Neutral/Neutral_FW.bvh").frames(0, 300)
    q = metrics.reference_quality(m)
    assert q.num_frames == 300
    assert q.bone_error_max < 1e-9  # forward kinematics keeps bones exact
    assert np.isfinite(q.jitter_m_s3) and 1.0 < q.jitter_m_s3 < 1000.0
    assert 0.0 <= q.foot_skating_m_s < 0.3
    assert q.contact_fraction > 0.5
    assert np.isnan(q.path_error_mean_m) and np.isnan(q.path_error_final_m)
    # the same poses gliding forward at 1 m/s: heights (so contacts) are unchanged, feet slide ~1 m/s more
    upm = js.estimate_units_per_meter(m)
    local = m.local_positions.copy()
    local[:, 0, 2] += upm * np.arange(m.num_frames) / m.fps
    glide = metrics.reference_quality(m.replace(local_positions=local))
    assert glide.contact_fraction == q.contact_fraction
    assert glide.foot_skating_m_s > q.foot_skating_m_s + 0.7
    assert glide.jitter_m_s3 == pytest.approx(q.jitter_m_s3, rel=1e-3)  # constant velocity adds no jerk


# --- bad input --------------------------------------------------------------------------------------------------------

def test_bad_shapes_name_the_argument():
    m = synthetic_skeleton()
    pos = _walker_positions(20, 0.0)
    two = np.zeros((20, 2))
    cases = [
        ("positions_TxJx3", lambda: metrics.jitter(pos[:, :, :2], FPS, units_per_meter=UPM)),
        ("positions_TxJx3", lambda: metrics.foot_skating(pos[:, :5], m, FPS, units_per_meter=UPM)),
        ("positions_TxJx3", lambda: metrics.motion_quality(pos[0], m, FPS, units_per_meter=UPM)),
        ("origin_Tx2", lambda: metrics.path_error(np.zeros((20, 3)), two, units_per_meter=UPM)),
        ("path_Tx2", lambda: metrics.path_error(two, two[:-1], units_per_meter=UPM)),
        ("path_Tx2", lambda: metrics.motion_quality(pos, m, FPS, units_per_meter=UPM, path_Tx2=two[:5])),
        ("polyline_Nx2", lambda: metrics.path_distance(two, np.zeros((4, 3)), units_per_meter=UPM)),
        ("polyline_Nx2", lambda: metrics.path_distance(two, np.zeros((0, 2)), units_per_meter=UPM)),
        ("contacts_TxF", lambda: metrics.foot_skating(pos, m, FPS, units_per_meter=UPM, contacts_TxF=np.ones((20, 3)))),
        ("contacts_TxF", lambda: metrics.motion_quality(pos, m, FPS, units_per_meter=UPM,
                                                        contacts_TxF=np.ones((19, 2)))),
        ("floor_F", lambda: metrics.foot_skating(pos, m, FPS, units_per_meter=UPM, floor_F=np.zeros(2))),
        ("units_per_meter", lambda: metrics.jitter(pos, FPS, units_per_meter=0.0)),
        ("fps", lambda: metrics.jitter(pos, -1.0, units_per_meter=UPM)),
    ]
    for name, call in cases:
        with pytest.raises(ValueError, match=name):
            call()
    nan = pos.copy()
    nan[3, 2, 1] = np.nan
    with pytest.raises(ValueError, match="positions_TxJx3 contains NaN"):
        metrics.motion_quality(nan, m, FPS, units_per_meter=UPM)


# --- the benchmark's figures (jaxstyle.output.quality) ---

def test_stop_times_count_from_each_stop_command():
    """A root that walks at 1 m/s for 60 frames, then decelerates linearly to 0 over 30 frames, and
    walks again from frame 120: one stop, reached when the trailing 10-frame mean speed falls below
    0.1 m/s (a numpy loop as the reference)."""
    v_cmd = np.zeros((180, 2))
    v_cmd[:60, 1] = UPM
    v_cmd[120:, 1] = UPM
    speed = np.concatenate([np.full(60, 1.0), np.linspace(1.0, 0.0, 30), np.zeros(30), np.full(60, 1.0)])
    origin = np.zeros((180, 2))
    origin[1:, 1] = np.cumsum(speed[1:]) * UPM / FPS
    got = metrics.stop_times(origin, v_cmd, FPS, units_per_meter=UPM)
    s = metrics.ground_speed(origin, FPS, units_per_meter=UPM)
    np.testing.assert_allclose(s[1:], speed[1:], atol=1e-9)
    first = next(t for t in range(60, 120) if np.mean(s[max(0, t - 9):t + 1]) < 0.1)
    np.testing.assert_allclose(got, [(first - 60) / FPS])
    walking = np.stack([np.zeros(180), np.arange(180) * UPM / FPS], axis=1)  # never slows down
    assert np.isnan(metrics.stop_times(walking, v_cmd, FPS, units_per_meter=UPM)).all()


def test_heading_error_wraps_and_joint_difference_is_in_metres():
    yaw = np.array([0.0, np.pi - 0.1, 0.2])
    path = np.array([2 * np.pi, -np.pi + 0.1, 0.0])
    np.testing.assert_allclose(metrics.heading_error_deg(yaw, path), np.degrees((0.0 + 0.2 + 0.2) / 3))
    a = np.zeros((3, 2, 3))
    b = a.copy()
    b[1, 1] = [3.0, 4.0, 0.0]
    assert metrics.max_joint_difference_m(a, b, units_per_meter=UPM) == pytest.approx(0.05)


def test_foot_jerk_is_the_ankles_third_difference():
    m = synthetic_skeleton(20)
    pos = js.global_positions(m)
    pos[:, 6, 0] += 0.5 * (np.arange(20) / FPS) ** 3 * UPM  # left ankle: x = t^3 / 2 m, jerk 3 m/s^3
    got = metrics.foot_jerk(pos, m, FPS, units_per_meter=UPM)
    np.testing.assert_allclose(got, 3.0 / 2, rtol=1e-6)  # the mean over the two ankles
