"""``jaxstyle play`` without a browser: steering -> controls, the batched live step against the
single-character ``step_fn``, style switches and blends without recompiling, recording, bad clips.

The model is a randomly initialised PFNN on two short procedural styles (no training: these tests
check the session's plumbing against independent references, not motion quality); the slow test
of ``tests/test_play_browser.py`` drives a trained one. The 2022 model (LPN-FiLM) is a randomly
initialised one on procedural styles with a fine-tuned new style written as ``jaxstyle lpn`` writes
it; the slow test at the end reloads a trained one from its run folder."""

from __future__ import annotations

import copy
import math
import threading
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxstyle.control import loop, lpn_phases
from jaxstyle.control.controller import PFNNModel
from jaxstyle.control.lpn_controller import StyleNetModel
from jaxstyle.control.model import step_fn
from jaxstyle.data import datasets, folders, procedural
from jaxstyle.data.datasets import style_rows
from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.errors import JaxstyleError
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2018 import base_model
from jaxstyle.mason2022 import finetune as finetune2022
from jaxstyle.mason2022 import pipeline as pipeline2022
from jaxstyle.mason2022 import styledata
from jaxstyle.mason2022 import synthesis as synthesis2022
from jaxstyle.motion.bvh import read_bvh
from jaxstyle.nn import film_generator, pfnn, style_models
from jaxstyle.play import learn, models, session
from jaxstyle.play.frame import Steering, control_row, control_rows
from jaxstyle.play.models import PlayError
from jaxstyle.play.scene import bone_transforms, ground_point
from jaxstyle.train.defaults import BODY_SMOOTH, FOOT_SMOOTH
from tests import test_synthesis_lpn

STYLES = ("Neutral", "Crouched")


def tiny_model(folder: Path, styles=STYLES, seconds: float = 6.0, hidden: int = 32, rank: int = 4
               ) -> models.PlayModel:
    """A :class:`PlayModel` with a random PFNN (no training) on procedural clips written to ``folder``;
    the adapters are random too, so the styles differ."""
    root = procedural.write_dataset(folder / "data", list(styles), ["FW"], seconds=seconds)
    settings = base_model.BaseSettings(data=str(root), styles=tuple(styles), hidden=hidden, rank=rank, epochs=1)
    dataset = base_model.build(folders.clip_specs(root, settings.styles, None), None)
    layout = PFNNLayout((dataset.inputs.shape[1] - 48) // 6)
    config = pfnn.PFNNConfig(input_size=layout.input_size, output_size=layout.output_size, hidden_size=hidden,
                             rank=rank)
    keys = jax.random.split(jax.random.PRNGKey(0), len(styles) + 1)
    params = pfnn.init_pfnn(keys[0], config)
    adapters = pfnn.stack_adapters([pfnn.init_adapter(k, config) for k in keys[1:]])
    adapters["b"] = adapters["b"] + 0.1 * jax.random.normal(keys[0], adapters["b"].shape)
    skeleton = datasets.load_clip(dataset.specs[0], fps=60.0)
    base = base_model.Base(params, adapters, dataset.normalisers(), config, dataset, skeleton, settings)
    named = {s: models.Style(s, "base", None, jax.tree.map(lambda v, i=i: v[i], adapters))
             for i, s in enumerate(dataset.styles)}
    upm = estimate_units_per_meter(skeleton)
    speed = PFNNModel.own_speed(dataset, style_rows(dataset, dataset.styles[0]), upm)
    return models.PlayModel(base, styles=named, units_per_meter=upm, speed=speed, run_dir=Path(folder))


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
def model(tmp_path_factory) -> models.PlayModel:
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
    """The session's one jitted call for all characters == ``step_fn`` per character
    (feet as the network put them; the locked feet are the next test's)."""
    s = session.Session(model, style="Neutral", foot_lock=False)
    s.add_character("Crouched")
    s.walk_to(2.0, 4.0)
    single = step_fn(PFNNModel.create(model.base.params, model.base.normalisers, s.num_joints), None)
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


def test_live_foot_locking_equals_the_batched_lock_of_the_same_frames(model):
    """Two characters drawn with their feet locked frame by frame (the default) == the unlocked
    session's frames locked afterwards in one scan (``footlock.lock_positions``) with the
    network's own contact labels: the live path is the batched one, per character."""
    from jaxstyle.output import export, footlock

    # this untrained model's feet hover and dart about: contact thresholds wide enough to lock them
    config = footlock.FootLockConfig(height_on_m=0.5, height_off_m=0.6, speed_on_m_s=3.0, label_speed_on_m_s=3.0,
                                     speed_off_m_s=4.0)
    frames = {}
    for lock in (True, False):
        s = session.Session(model, style="Neutral", foot_lock=lock, foot_lock_config=config)
        s.add_character("Crouched")
        s.walk_to(1.5, 4.0)
        frames[lock] = np.stack([s.step().positions for _ in range(90)])  # (T, C, J, 3) metres
        history = [s.recording(1.5, i) for i in range(2)]
    rig, params = footlock.leg_rig(model.skeleton), footlock.params_for(model.skeleton, config)
    for i in range(2):
        labels = export.network_contacts(history[i], s.num_joints)
        labels = None if labels is None else footlock.labels_per_point(labels)
        locked, _ = footlock.lock_positions(params, rig, frames[False][:, i] * model.units_per_meter, labels)
        np.testing.assert_allclose(frames[True][:, i], locked / model.units_per_meter, atol=1e-4)
    assert np.abs(frames[True] - frames[False]).max() > 1e-3  # the lock did move feet


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
    want = sum(wk * pfnn.apply_adapter(model.styles[n].conditioning, h, w4) for n, wk in (("Neutral", 0.75),
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


def test_many_characters_share_one_program_per_slot_count(model):
    """Characters live in power-of-two slots: adding a third and a fourth character compiles the
    frame program once (for 4 slots), removing one compiles nothing; each character's frames are
    its own (a character added later records only from when it was added), and the slot of a
    removed character starts afresh when a new one takes it (its feet unlocked, beside the first)."""
    s = session.Session(model, style="Neutral")
    s.add_character("Crouched")
    s.walk_to(0.0, 3.0)
    for _ in range(3):
        s.step()
    two = s._step._cache_size()
    s.add_character()
    for _ in range(3):
        s.step()
    assert s._slots == 4 and s._step._cache_size() == two + 1
    s.add_character("Crouched")
    s.remove_character()
    s.add_character()
    for _ in range(3):
        s.step()
    assert s._step._cache_size() == two + 1 and len(s.characters) == 4
    assert s.recording(1.0, 0).positions.shape[0] == 9 and s.recording(1.0, 3).positions.shape[0] == 3
    frame = s.step()
    assert frame.positions.shape == (4, s.num_joints, 3)
    assert np.linalg.norm(frame.origin[3] - frame.origin[0]) < 3.0  # beside the first, not at the start


def test_control_rows_of_many_characters_equal_each_alone():
    """The steering rows of characters in different modes, computed together, equal each
    character's row computed alone (no mixing between rows), and waypoints are consumed per
    character."""
    rng = np.random.default_rng(2)
    steerings = [Steering("target", [(3.0, 4.0), (0.0, 9.0)], 0.0, 1.3), Steering("direction", [], 2.0, 0.8),
                 Steering("stop"), Steering("target", [(0.1, 0.1), (5.0, -2.0)], 0.0, 2.0),
                 Steering("target", [(0.05, 0.0)], 0.0, 1.0)]
    origin, yaw = rng.normal(size=(5, 2)) * 0.1, rng.uniform(-3, 3, size=5)
    alone = [control_row(origin[i], yaw[i], copy.deepcopy(st), 50.0) for i, st in enumerate(steerings)]
    offsets, facing = control_rows(origin, yaw, steerings, 50.0)
    for i in range(5):
        np.testing.assert_allclose(offsets[i], alone[i][0], atol=1e-12)
        np.testing.assert_allclose(facing[i], alone[i][1], atol=1e-12)
    assert steerings[3].waypoints == [(5.0, -2.0)] and steerings[4].mode == "stop"
    assert np.abs(offsets[1]).max() > 0 and np.abs(offsets[2]).max() == 0


def test_recording_writes_bvh_of_the_last_seconds(model, tmp_path):
    s = session.Session(model)
    with pytest.raises(PlayError, match="nothing recorded"):
        s.recording(1.0)
    s.walk_along(0.5)
    for _ in range(90):
        s.step()
    rollout = s.recording(1.0)
    assert rollout.positions.shape[0] == 60
    files = session.save_recording(rollout, model, tmp_path / "rec", foot_lock=True, gif=True)
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


def test_clip_reader_process_reads_names_after_warming_up(model, tmp_path):
    """The reader process (spawned and warmed at start) gives the same names as reading here, and a
    malformed file's one-line error comes back from it."""
    clip = Path(model.base.settings.data) / "Neutral" / "Neutral_FW.bvh"
    text = tmp_path / "notes.bvh"
    text.write_text("these are not motion capture\n")
    reader = learn.ClipReader(timeout=60)
    try:
        reader.warm()
        assert reader._pool is not None
        assert reader.names(clip) == read_bvh(clip).names == model.base.skeleton.names
        with pytest.raises(JaxstyleError, match="notes.bvh"):
            learn.check_clip(text, model, reader.names)
    finally:
        reader.close()


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


def test_bone_transforms_of_many_characters_equal_each_alone():
    rng = np.random.default_rng(1)
    positions = rng.normal(size=(3, 5, 3))
    parents = np.array([-1, 0, 1, 2, 0])
    together = bone_transforms(positions, parents)
    for c in range(3):
        for a, b in zip(together, bone_transforms(positions[c], parents), strict=True):
            np.testing.assert_allclose(a[c], b)


def test_ground_point():
    assert ground_point((0, 2, 0), (0.6, -0.8, 0)) == pytest.approx((1.5, 0.0))
    assert ground_point((0, 2, 0), (0, 0.5, 1)) is None


def test_cli_refuses_a_bad_port(tmp_path, capsys):
    from jaxstyle.cli.main import main

    assert main(["play", "--run", str(tmp_path / "r"), "--port", "70000"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == "jaxstyle play: error: --port must be in 1 .. 65535, got 70000"


# --- the 2022 model (LPN-FiLM) -----------------------------------------------------------------

def random_params(config, seed: int = 1) -> dict:
    """Random weights in the tree of :func:`jaxstyle.nn.style_models.init_model` (its shapes, by
    ``jax.eval_shape``), drawn with numpy: scaled normal weights, zero biases. The same kind of
    model as ``init_model``'s, without compiling a random kernel per weight shape (~15 s on 2
    loaded cores)."""
    shapes = jax.eval_shape(lambda k: style_models.init_model(k, config), jax.random.PRNGKey(seed))
    rng = np.random.default_rng(seed)

    def draw(path, leaf):
        shape = leaf.shape
        if len(shape) < 2:
            return np.zeros(shape, np.float32)
        conv = "conv" in jax.tree_util.keystr(path)
        fan_in = shape[0] * shape[1] if conv else shape[-2]  # a kernel is (width, in, out)
        return (rng.normal(size=shape) / np.sqrt(fan_in)).astype(np.float32)

    return jax.tree_util.tree_map_with_path(draw, shapes)


def tiny_lpn_model(folder: Path) -> models.LPNPlayModel:
    """A :class:`LPNPlayModel` of a randomly initialised LPN-FiLM (no training) on two procedural
    training styles, and a new style "Limping" fine-tuned at two rates as
    :func:`jaxstyle.mason2022.finetune.write_finetune` leaves it (the generators: the model's shifted
    by a constant per rate, as ``tests/test_synthesis_lpn.py`` does, so the chosen one is told apart)."""
    root = procedural.write_dataset(folder / "data", ["Neutral", "Crouched", "Limping"], ["FW"], seconds=7,
                                    progress=False)
    styles, new_styles = folders.split_styles(root, ["Limping"])
    data = pipeline2022.build_data(root, styles, new_styles)
    config = pipeline2022.model_config(data.base, hidden=8, generator_hidden=16, filters=4)
    params = random_params(config)
    model = pipeline2022.Model(pipeline2022.MODEL, config, params,
                               styledata.style_data(data.base, data.skeleton))
    gens = jax.tree.map(lambda v: np.stack([np.stack([np.asarray(v) + 0.01, np.asarray(v) - 0.02])]),
                        params["style"]["generator"])
    after = {split: {"mse": np.full((1, 2), 0.5), "bll": np.full((1, 2), 0.01)} for split in finetune2022.SPLITS}
    new = styledata.style_data(data.new, data.skeleton, base=data.base)
    result = finetune2022.FinetuneResult(("Limping",), (0.1, 0.5), gens, 0, 0.0, {}, after, np.array([1]), new)
    finetune2022.write_finetune(result, folder / "lpn")
    return models.lpn_play_model(synthesis2022.Loaded(model, data, folder / "lpn", 0), folder)


@pytest.fixture(scope="module")
def lpn_model(tmp_path_factory) -> models.LPNPlayModel:
    return tiny_lpn_model(tmp_path_factory.mktemp("play_lpn"))


def _film_vector(model: models.LPNPlayModel, generator: dict, data, style: str) -> np.ndarray:
    """Independent of the session: the mean FiLM vector of ``style``'s training clips (section 4.4)."""
    s = data.styles.index(style)
    return np.mean(film_generator.clip_films(generator, data.clips[data.train_clips[s]]), axis=0)


def test_lpn_styles_are_the_film_vectors_of_the_training_and_finetuned_styles(lpn_model):
    m = lpn_model.loaded.model
    assert lpn_model.key == "lpn-film" and lpn_model.title == "2022 LPN FiLM" and not lpn_model.learnable
    assert {n: (st.kind, st.rate) for n, st in lpn_model.styles.items()} == {
        "Crouched": ("base", None), "Neutral": ("base", None), "Limping": ("fine-tuned", 0.5)}
    for name in ("Crouched", "Neutral"):
        np.testing.assert_allclose(lpn_model.styles[name].conditioning,
                                   _film_vector(lpn_model, m.params["style"]["generator"], m.data, name),
                                   rtol=1e-5, atol=1e-6)
    # the new style: under its chosen rate's generator (index 1: the model's minus 0.02)
    new = styledata.style_data(lpn_model.loaded.data.new, lpn_model.skeleton,
                                            base=lpn_model.loaded.data.base)
    tuned = jax.tree.map(lambda v: np.asarray(v) - 0.02, m.params["style"]["generator"])
    np.testing.assert_allclose(lpn_model.styles["Limping"].conditioning, _film_vector(lpn_model, tuned, new, "Limping"),
                               rtol=1e-4, atol=1e-5)
    assert lpn_model.styles["Limping"].label == "Limping (fine-tuned, rate 0.5)"


def test_lpn_session_steps_like_the_controllers_step_and_switches_styles_without_recompiling(lpn_model):
    """The session's one jitted call for all characters == ``step_fn`` per character
    with each character's FiLM vector; a switch feeds the new vector to the next step, compiling
    nothing (the jit cache stays at one entry per character count)."""
    m = lpn_model.loaded.model
    s = session.Session(lpn_model, style="Neutral", foot_lock=False)
    s.add_character("Crouched")
    s.walk_to(2.0, 4.0)
    single = step_fn(StyleNetModel.create(m.params, m.config, lpn_model.loaded.data.base.normalisers(),
                                          lpn_model.loaded.data.skeleton, foot_smooth=FOOT_SMOOTH,
                                          body_smooth=BODY_SMOOTH), None)
    states = [jax.tree.map(lambda v, i=i: v[i], s._states) for i in range(2)]
    vectors = {n: np.asarray(st.conditioning) for n, st in lpn_model.styles.items()}
    compiled = None
    for k in range(6):
        if k == 3:
            s.set_style("Limping", 0)  # from the next frame on
            s.set_blend(["Neutral", "Limping"], [1.0, 3.0], 1)
        playing = [vectors["Limping"], 0.25 * vectors["Neutral"] + 0.75 * vectors["Limping"]] if k >= 3 else \
            [vectors["Neutral"], vectors["Crouched"]]
        controls = s.controls()
        frame = s.step()
        compiled = compiled or s._step._cache_size()
        for i in range(2):
            row = (controls.offsets[i], controls.yaw[i], None, None, controls.stand[i])
            states[i], out = single(states[i], row, jax.numpy.asarray(playing[i]))
            np.testing.assert_allclose(frame.positions[i], np.asarray(out.positions)[:s.num_joints] /
                                       lpn_model.units_per_meter, rtol=1e-4, atol=1e-5)
    assert s._step._cache_size() == compiled == 1
    assert s.describe(0) == ("Limping", "0.5") and s.describe(1) == ("25% Neutral + 75% Limping", "- / 0.5")
    np.testing.assert_allclose(s.origin(), np.stack([np.asarray(st.hist_xz[-1]) for st in states]) /
                               lpn_model.units_per_meter, atol=1e-5)
    assert frame.positions.shape == (2, lpn_model.skeleton.num_joints, 3)  # the skeleton's joints, not end sites


def test_lpn_film_blend_is_the_weighted_film_vector(lpn_model):
    s = session.Session(lpn_model)
    s.add_character()  # two, as above: the step compiled there serves
    s.step()
    compiled = s._step._cache_size()
    s.set_blend(["Neutral", "Crouched", "Limping"], [1.0, 2.0, 5.0])
    w = np.array([1.0, 2.0, 5.0]) / 8.0
    want = sum(wk * np.asarray(lpn_model.styles[n].conditioning, np.float64)
               for wk, n in zip(w, ("Neutral", "Crouched", "Limping"), strict=True))
    np.testing.assert_allclose(np.asarray(s.runtime_of(s.characters[0])), want, rtol=1e-5, atol=1e-7)
    assert s.describe()[0] == "12% Neutral + 25% Crouched + 62% Limping"
    s.step()
    s.set_style("Crouched")
    np.testing.assert_array_equal(np.asarray(s.runtime_of(s.characters[0])), lpn_model.styles["Crouched"].conditioning)
    s.step()
    assert s._step._cache_size() == compiled


def test_lpn_steering_reaches_the_network_input(lpn_model, tmp_path):
    """A click target becomes the LPN's future-trajectory input: its farthest sample (where the
    user's path has full weight) points from the character at the target, in the character's
    frame; keys steer the same way; a recording of the 2022 model writes BVH and GIF."""
    s = session.Session(lpn_model)
    s.add_character()  # two, as above: the step compiled there serves
    for _ in range(5):
        s.step()
    here, yaw = s.origin()[0], float(s.yaw()[0])
    target = here + np.array([3.0, -1.0])
    s.walk_to(*target)
    controls = s.controls()
    state = jax.tree.map(lambda v: v[0], s._states)
    x = np.asarray(loop.trajectory_input(state.hist_xz, state.hist_yaw, state.future,
                                         (controls.offsets[0], controls.yaw[0])))
    fx, fz = x[11], x[23]  # x | z at the 12 samples -60 .. 50: the last of each is 50 frames ahead
    d = target - here
    want = lpn_model.units_per_meter * min(s.speed * 50 / 60, np.hypot(*d)) * d / np.hypot(*d)
    c, si = math.cos(yaw), math.sin(yaw)  # into the character frame (loop.rotate_xz by -yaw)
    np.testing.assert_allclose([fx, fz], [want[0] * c - want[1] * si, want[0] * si + want[1] * c], rtol=1e-4)
    s.key("A", 0.0)
    assert all(c.steering.mode == "direction" for c in s.characters)
    for _ in range(20):
        s.step()
    files = session.save_recording(s.recording(0.25), lpn_model, tmp_path / "rec", gif=True)
    assert {f.suffix for f in files} == {".bvh", ".npz", ".gif"}
    motion = read_bvh(tmp_path / "rec.bvh")
    assert motion.num_frames == 15 and motion.names == lpn_model.skeleton.names


def test_a_pfnn_backbone_2022_model_carries_each_characters_global_phase_rate(lpn_model):
    """Table 2's PFNN FiLM (the network evaluated at a carried global phase): each character's
    state carries its style's rate of global to local phase advance
    (:func:`jaxstyle.control.lpn_phases.phase_ratio`, computed here directly); a style switch
    replaces it, a blend's FiLM vector plays, and the step equals ``step_fn`` without recompiling."""
    data = lpn_model.loaded.data
    config = pipeline2022.model_config(data.base, "PFNN FiLM", hidden=8, generator_hidden=16, filters=4)
    model = pipeline2022.Model("PFNN FiLM", config, random_params(config, seed=2),
                               styledata.style_data(data.base, data.skeleton, backbone="pfnn"))
    m = models.lpn_play_model(synthesis2022.Loaded(model, data, lpn_model.run_dir / "pfnn", 0), lpn_model.run_dir)
    assert m.key == "pfnn-film" and set(m.styles) == {"Neutral", "Crouched"}
    x_norm, y_norm = data.base.normalisers()

    def ratio(runtime, name):
        return lpn_phases.phase_ratio(model.params, config, runtime, (x_norm, y_norm), data.base,
                                          style_rows(data.base, name))

    want = {n: ratio(m.styles[n].conditioning, n) for n in ("Neutral", "Crouched")}
    assert want["Neutral"] != want["Crouched"]
    s = session.Session(m, style="Neutral")
    s.add_character("Crouched")
    s.walk_to(1.0, 3.0)  # walking: the standing amount stays 0 (controls() below eases it as step() does)
    s.step()
    compiled = s._step._cache_size()
    np.testing.assert_allclose(s._states.phase_ratio, [want["Neutral"], want["Crouched"]], rtol=1e-6)
    s.set_style("Crouched", 0)
    s.set_blend(["Neutral", "Crouched"], [1.0, 3.0], 1)
    single = step_fn(StyleNetModel.create(model.params, config, (x_norm, y_norm), data.skeleton,
                                          foot_smooth=FOOT_SMOOTH, body_smooth=BODY_SMOOTH), None)
    controls = s.controls()
    before = jax.tree.map(lambda v: v[1], s._states)
    frame = s.step()
    blend = 0.25 * np.asarray(m.styles["Neutral"].conditioning) + 0.75 * np.asarray(m.styles["Crouched"].conditioning)
    np.testing.assert_allclose(s._states.phase_ratio, [want["Crouched"], ratio(blend, "Crouched")], rtol=1e-5)
    # character 1's step, at the blend's rate, against step_fn with the blended FiLM vector
    state = before._replace(phase_ratio=jax.numpy.float32(ratio(blend, "Crouched")))
    _, out = single(state, (controls.offsets[1], controls.yaw[1], None, None, controls.stand[1]),
                    jax.numpy.asarray(blend, jax.numpy.float32))
    np.testing.assert_allclose(frame.positions[1], np.asarray(out.positions)[:s.num_joints] / m.units_per_meter,
                               rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(s._states.global_phase[1], out.global_phase, atol=1e-6)
    assert s._step._cache_size() == compiled


def test_play_drives_a_2022_model_with_the_runtime_it_is_given(lpn_model, monkeypatch, tmp_path):
    """`jaxstyle play --phase-floor F --foot-smooth S` reaches the reloaded 2022 model (the server's
    load_any -> load_lpn_model); without them the model keeps the library's defaults."""
    from jaxstyle.train.defaults import BODY_SMOOTH, FOOT_SMOOTH, PHASE_FLOOR

    folder = tmp_path
    monkeypatch.setattr(synthesis2022, "load_model", lambda *a, **k: lpn_model.loaded)
    (folder / "lpn").mkdir()
    (folder / "lpn" / "config.json").write_text("{}")
    pipeline2022.write_data_file(lpn_model.loaded.data, folder / "lpn")
    default = models.load_any(folder, "lpn-film").loaded
    assert (default.phase_floor, default.foot_smooth, default.body_smooth) == (PHASE_FLOOR, FOOT_SMOOTH, BODY_SMOOTH)
    paper = models.load_any(folder, "lpn-film", runtime={"phase_floor": 0.0, "foot_smooth": 0.5, "body_smooth": 0.5})
    assert (paper.loaded.phase_floor, paper.loaded.foot_smooth, paper.loaded.body_smooth) == (0.0, 0.5, 0.5)
    assert paper.character_model().joint_smooth().ravel().tolist() == [0.5] * lpn_model.num_bones


def test_run_folder_models_and_bad_choices(lpn_model, tmp_path, capsys):
    folder = lpn_model.run_dir
    assert models.available_models(folder) == {}  # no config.json: this one was never trained
    (folder / "lpn" / "config.json").write_text("{}")
    pipeline2022.write_data_file(lpn_model.loaded.data, folder / "lpn")
    assert models.available_models(folder) == {"lpn-film": "2022 LPN FiLM (Mason et al. 2022)"}
    with pytest.raises(PlayError, match="no trained mann-film model"):
        models.load_any(folder, "mann-film")
    with pytest.raises(JaxstyleError, match="no base model"):
        models.load_any(tmp_path, "pfnn")
    from jaxstyle.cli.main import main

    assert main(["play", "--run", str(folder), "--model", "pfnn"]) == 1
    assert capsys.readouterr().err.strip() == (
        f"jaxstyle play: error: --model pfnn: {folder} has no trained pfnn model (it has lpn-film); train one with "
        "`jaxstyle demo`")


trained_lpn_run = test_synthesis_lpn.run_dir
"""A run folder with a tiny LPN-FiLM trained for one epoch into RUN/lpn and a fine-tuned new style:
the fixture of ``tests/test_synthesis_lpn.py``, reused (about 30 s on 2 cores: the test is slow)."""


@pytest.mark.slow
def test_play_a_trained_2022_model_from_its_run_folder(trained_lpn_run, model, tmp_path):
    """The page on a run folder with a trained 2022 model: the Model choice switches from the 2018
    model to it and back (each loaded once: the 2018 model and its learner stay the same objects);
    the 2022 model's styles in the dropdown; learning refused in one line while it plays; a target
    ahead approached (a one-epoch model walks forward whatever it is told, so only a target ahead
    is a fair check of its motion)."""
    from jaxstyle.play.guard import Serving
    from jaxstyle.play.server import PlayServer

    run = trained_lpn_run[0]
    assert models.available_models(run) == {"lpn-film": "2022 LPN FiLM (Mason et al. 2022)"}
    server = PlayServer(run, Serving(port=0)).start(model=model, loop=False)  # a 2018 model, given, and RUN/lpn
    try:
        learner = server.learner
        assert server.session.model is model and learner is not None and not server._gui["learn"].disabled
        assert server._gui["model"].options == ("2022 LPN FiLM (Mason et al. 2022)", "2018 PFNN")
        assert server._gui["model"].value == "2018 PFNN"
        assert not [t for t in threading.enumerate() if t.name == "jaxstyle-play-model"]  # refreshing loads nothing
        server._gui["model"].value = "2022 LPN FiLM (Mason et al. 2022)"  # as the page's Model choice does
        for _ in range(600):
            if server.session.model.key == "lpn-film":
                break
            time.sleep(0.1)
        s = server.session
        assert s.model.key == "lpn-film" and server.learner is learner  # the 2018 model's, kept
        assert {n: (st.kind, st.rate) for n, st in s.styles.items()} == {
            "Crouched": ("base", None), "Neutral": ("base", None), "Limping": ("fine-tuned", 0.5)}
        assert server._gui["style"].options == ("Crouched", "Neutral", "Limping")
        assert server._gui["model"].value == "2022 LPN FiLM (Mason et al. 2022)"
        assert "2018 PFNN" in server._gui["model"].options  # the given 2018 model can still be chosen
        assert server._gui["learn"].disabled and "2018 few-shot sweep" in server._gui["learn_note"].content
        with pytest.raises(PlayError, match="choose the 2018 PFNN under Model"):
            server.learn(str(tmp_path / "clip.bvh"))
        server.set_style("Limping")
        assert s.characters[0].style == "Limping"
        for _ in range(30):
            s.step()
        start = s.origin()[0].copy()
        target = start + np.array([0.0, 3.0])
        s.walk_to(*target)
        for _ in range(120):
            s.step()
        assert np.linalg.norm(s.origin()[0] - target) < 3.0 - 0.5
        assert server.load_model_key("pfnn")
        assert server.session.model is model and server.learner is learner and not server._gui["learn"].disabled
    finally:
        server.stop()
