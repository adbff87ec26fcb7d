"""``jaxstyle play`` without a browser: steering -> controls, the batched live step against the
single-character ``step_fn``, style switches and blends without recompiling, recording, bad clips.

The model is a randomly initialised PFNN on two short procedural styles (no training: these tests
check the session's plumbing against independent references, not motion quality); the slow test
of ``tests/test_play_browser.py`` drives a trained one."""

from __future__ import annotations

import math
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxstyle.control import controller
from jaxstyle.data import procedural
from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.errors import JaxstyleError
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2018 import pipeline
from jaxstyle.motion.bvh import read_bvh
from jaxstyle.nn import pfnn
from jaxstyle.output import synthesis
from jaxstyle.play import learn, session
from jaxstyle.play.server import bone_transforms, ground_point
from jaxstyle.play.session import PlayError, Steering, control_row

STYLES = ("Neutral", "Crouched")


def tiny_model(folder: Path, styles=STYLES, seconds: float = 6.0, hidden: int = 32, rank: int = 4
               ) -> session.PlayModel:
    """A :class:`PlayModel` with a random PFNN (no training) on procedural clips written to ``folder``;
    the adapters are random too, so the styles differ."""
    root = procedural.write_dataset(folder / "data", list(styles), ["FW"], seconds=seconds)
    settings = pipeline.BaseSettings(data=str(root), styles=tuple(styles), hidden=hidden, rank=rank, epochs=1)
    dataset = pipeline.build(pipeline.clip_specs(root, settings.styles, None), None)
    layout = PFNNLayout((dataset.inputs.shape[1] - 48) // 6)
    config = pfnn.PFNNConfig(input_size=layout.input_size, output_size=layout.output_size, hidden_size=hidden,
                             rank=rank)
    keys = jax.random.split(jax.random.PRNGKey(0), len(styles) + 1)
    params = pfnn.init_pfnn(keys[0], config)
    adapters = pfnn.stack_adapters([pfnn.init_adapter(k, config) for k in keys[1:]])
    adapters["b"] = adapters["b"] + 0.1 * jax.random.normal(keys[0], adapters["b"].shape)
    skeleton = pipeline.datasets.load_clip(dataset.specs[0], fps=60.0)
    base = pipeline.Base(params, adapters, dataset.normalisers(), config, dataset, skeleton, settings)
    named = {s: session.Style(s, "base", None, jax.tree.map(lambda v, i=i: v[i], adapters))
             for i, s in enumerate(dataset.styles)}
    upm = estimate_units_per_meter(skeleton)
    speed = synthesis.own_speed(dataset, synthesis.style_rows(dataset, dataset.styles[0]), upm)
    return session.PlayModel(base, named, upm, speed, Path(folder))


def other_skeleton_bvh(path: Path) -> Path:
    """A valid BVH of a three-joint skeleton (not the base's)."""
    frames = "\n".join(" ".join(["0"] * 12) for _ in range(30))
    path.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation "
                    "Yrotation Xrotation\n JOINT Spine\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Yrotation "
                    "Xrotation\n  JOINT Head\n  {\n   OFFSET 0 10 0\n   CHANNELS 3 Zrotation Yrotation Xrotation\n"
                    "   End Site\n   {\n    OFFSET 0 5 0\n   }\n  }\n }\n}\nMOTION\nFrames: 30\n"
                    f"Frame Time: 0.0333333\n{frames}\n")
    return path


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> session.PlayModel:
    return tiny_model(tmp_path_factory.mktemp("play"))


# --- steering ----------------------------------------------------------------------------------

def test_control_row_walks_towards_the_target_and_stops_there():
    upm, speed = 100.0, 1.5
    origin, yaw = np.array([1.0, 2.0]), 0.3
    steer = Steering("target", [(4.0, 6.0), (4.0, 9.0)], speed=speed)
    offsets, facing = control_row(origin, yaw, steer, upm)
    direction = np.array([3.0, 4.0]) / 5.0
    for k in range(6):  # independent: distance covered k/6 s ahead, capped at the target
        np.testing.assert_allclose(offsets[k], upm * min(speed * k / 6.0, 5.0) * direction, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(facing, math.atan2(3.0, 4.0))
    # within ARRIVE_M of the first waypoint: on to the next one
    offsets, facing = control_row(np.array([4.0, 5.9]), 0.6, steer, upm)
    assert steer.waypoints == [(4.0, 9.0)]
    np.testing.assert_allclose(offsets[-1], upm * np.array([0.0, speed * 50 / 60]), atol=1e-9)
    # the last one reached: stand, keep facing where it faces
    offsets, facing = control_row(np.array([4.1, 8.9]), 0.2, steer, upm)
    assert steer.mode == "stop" and not steer.waypoints
    assert not offsets.any()
    np.testing.assert_allclose(facing, 0.2)


def test_control_row_turns_the_short_way_round():
    steer = Steering("target", [(-0.1, -5.0)], speed=1.0)  # almost straight behind a character facing -Z+
    _, facing = control_row(np.zeros(2), 3.0, steer, 1.0)
    want = math.atan2(-0.1, -5.0)  # about -3.12, i.e. 3.16 going on from 3.0
    assert abs(facing[0] - 3.0) < 0.2
    np.testing.assert_allclose(np.cos(facing[0]), np.cos(want), atol=1e-12)
    np.testing.assert_allclose(np.sin(facing[0]), np.sin(want), atol=1e-12)


def test_direction_steering_and_keys():
    steer = Steering("direction", heading=-math.pi / 2, speed=2.0)
    offsets, facing = control_row(np.zeros(2), 0.0, steer, 1.0)
    np.testing.assert_allclose(offsets[3], [-1.0, 0.0], atol=1e-12)  # 2 m/s x 0.5 s along -X
    np.testing.assert_allclose(facing, -math.pi / 2)
    # a camera looking along +Z (Y up): its right is -X, so D walks along -X, A along +X, S back
    for key, expected in (("W", (0, 1)), ("ArrowUp", (0, 1)), ("D", (-1, 0)), ("A", (1, 0)), ("s", (0, -1))):
        h = session.key_heading(key, 0.0)
        np.testing.assert_allclose([math.sin(h), math.cos(h)], expected, atol=1e-12)
    h = session.key_heading("W", 1.0)  # forward is where the camera looks
    np.testing.assert_allclose(h, 1.0)
    with pytest.raises(PlayError, match="unknown steering key"):
        session.key_heading("Q", 0.0)


# --- the live step -----------------------------------------------------------------------------

def test_batched_step_matches_step_fn_per_character(model):
    """The session's one jitted call for all characters == ``controller.step_fn`` per character."""
    s = session.Session(model, style="Neutral")
    s.add_character("Crouched")
    s.walk_to(2.0, 4.0)
    single = controller.step_fn(model.base.params, None, *model.base.normalisers, s.num_joints)
    states = [jax.tree.map(lambda v, i=i: v[i], s._states) for i in range(2)]
    adapters = [s.adapter_of(c) for c in s.characters]
    for _ in range(5):
        controls = s.controls()
        frame = s.step()
        for i in range(2):
            row = (controls.offsets[i], controls.yaw[i], None, None, controls.stand[i])
            states[i], out = single(states[i], row, adapters[i])
            np.testing.assert_allclose(frame.positions[i], np.asarray(out.positions) / model.units_per_meter,
                                       rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(s.origin(), np.stack([np.asarray(st.hist_xz[-1]) for st in states]) /
                               model.units_per_meter, atol=1e-5)


def test_style_switch_and_blend_take_effect_without_recompiling(model):
    s = session.Session(model, style="Neutral")
    s.step()
    compiled = s._step._cache_size()
    a = s.step().positions
    s.set_style("Crouched")
    assert s.characters[0].style == "Crouched" and s.describe() == ("Crouched", "-")
    s.step()
    s.set_blend(["Neutral", "Crouched"], [3.0, 1.0])  # normalised to 0.75 / 0.25
    assert s.describe()[0] == "75% Neutral + 25% Crouched"
    s.step()
    assert s._step._cache_size() == compiled
    assert np.isfinite(a).all()
    # the blend's residual is the weighted sum of the styles' residuals (Mason et al. 2018, Eq. 4)
    h = jax.random.normal(jax.random.PRNGKey(3), (5, model.base.model.hidden_size))
    w4 = pfnn.catmull_rom_weights(jax.numpy.linspace(0, 0.9, 5))
    blended = pfnn.apply_adapter(s.adapter_of(s.characters[0]), h, w4)
    want = sum(wk * pfnn.apply_adapter(model.styles[n].adapter, h, w4) for n, wk in (("Neutral", 0.75),
                                                                                       ("Crouched", 0.25)))
    np.testing.assert_allclose(blended, want, rtol=1e-4, atol=1e-5)
    with pytest.raises(PlayError, match="unknown style"):
        s.set_style("Nope")
    with pytest.raises(PlayError, match="non-negative"):
        s.set_blend(["Neutral", "Crouched"], [0.0, 0.0])


def test_characters_added_and_removed(model):
    s = session.Session(model)
    s.add_character()
    frame = s.step()
    assert frame.positions.shape == (2, model.base.skeleton.num_joints, 3) and frame.future.shape == (2, 6, 2)
    assert abs(frame.origin[0, 0] - frame.origin[1, 0]) > 1.0  # side by side, not on top of each other
    s.remove_character()
    assert s.step().positions.shape[0] == 1
    s.key("D", 0.0, run=True)
    assert all(c.steering.mode == "direction" and c.steering.speed == pytest.approx(2 * s.speed)
               for c in s.characters)
    s.stop()
    assert all(c.steering.mode == "stop" for c in s.characters)
    for _ in range(150):  # told to stand, the character eases to a stop (the PFNN demo's standing amount)
        s.step()
    assert s.characters[0].stand > 0.999
    before = s.origin()
    for _ in range(30):
        s.step()
    assert np.linalg.norm(s.origin() - before, axis=1).max() < 0.05 * 0.5 * s.speed  # < 5% of walking 0.5 s


def test_recording_writes_bvh_of_the_last_seconds(model, tmp_path):
    s = session.Session(model)
    with pytest.raises(PlayError, match="nothing recorded"):
        s.recording(1.0)
    s.walk_along(0.5)
    for _ in range(90):
        s.step()
    rollout = s.recording(1.0)
    assert rollout.positions.shape[0] == 60
    files = session.save_recording(rollout, model, tmp_path / "rec", foot_ik=True, gif=True)
    assert {f.suffix for f in files} == {".bvh", ".npz", ".gif"}
    motion = read_bvh(tmp_path / "rec.bvh")
    assert motion.num_frames == 60 and motion.names == model.base.skeleton.names


# --- bad clips, learning failures ---------------------------------------------------------------

def test_check_clip_refuses_other_skeletons_and_non_bvh(model, tmp_path):
    other = other_skeleton_bvh(tmp_path / "other.bvh")
    with pytest.raises(PlayError, match="another skeleton"):
        learn.check_clip(other, model)
    text = tmp_path / "notes.bvh"
    text.write_text("these are not motion capture\n")
    with pytest.raises(JaxstyleError, match="notes.bvh"):
        learn.check_clip(text, model)
    binary = tmp_path / "image.bvh"
    binary.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(JaxstyleError, match="image.bvh"):
        learn.check_clip(binary, model)
    with pytest.raises(PlayError, match="no such file"):
        learn.check_clip(tmp_path / "missing.bvh", model)
    learn.check_clip(Path(model.base.settings.data) / "Neutral" / "Neutral_FW.bvh", model)  # the base's own


def test_learner_reports_a_bad_clip_without_raising(model, tmp_path):
    failures = []
    learner = learn.Learner(model, lambda _: pytest.fail("nothing to learn"), on_fail=failures.append)
    learner.start(other_skeleton_bvh(tmp_path / "walk.bvh"))
    learner.wait(30)
    state, fraction, message = learner.status()
    assert state == "failed" and fraction == 0.0 and "another skeleton" in message
    assert failures == [message]


def test_style_names():
    assert learn.style_name("/x/my walk (2).bvh") == "my_walk_2"
    assert learn.style_name("a.bvh", ["a", "a_2"]) == "a_3"


# --- scene geometry ----------------------------------------------------------------------------

def _rotate(q, v):
    w, x, y, z = q
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    return r @ v


def test_bone_transforms_put_the_unit_cylinder_on_each_bone():
    rng = np.random.default_rng(0)
    positions = rng.normal(size=(5, 3))
    positions[2] = positions[1] - np.array([0, 0, 0.7])  # a bone along -Z (the degenerate rotation)
    parents = np.array([-1, 0, 1, 2, 0])
    mid, q, scales = bone_transforms(positions, parents)
    for b, j in enumerate([1, 2, 3, 4]):
        bone = positions[j] - positions[parents[j]]
        np.testing.assert_allclose(mid[b], (positions[j] + positions[parents[j]]) / 2)
        np.testing.assert_allclose(scales[b, 2], np.linalg.norm(bone))
        np.testing.assert_allclose(_rotate(q[b], [0, 0, 1]), bone / np.linalg.norm(bone), atol=1e-9)


def test_ground_point():
    assert ground_point((0, 2, 0), (0.6, -0.8, 0)) == pytest.approx((1.5, 0.0))
    assert ground_point((0, 2, 0), (0, 0.5, 1)) is None


def test_cli_refuses_a_bad_port(tmp_path, capsys):
    from jaxstyle.cli.main import main

    assert main(["play", "--run", str(tmp_path / "r"), "--port", "70000"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == "jaxstyle play: error: --port must be in 1 .. 65535, got 70000"
