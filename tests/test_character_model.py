"""A third model family needs only its own code: a toy :class:`jaxstyle.control.model.CharacterModel`
written here (it replays a capture's poses and walks where the path asks, its style conditioning a
speed factor) is driven by the shared rollouts, the synthesis (GIF, BVH, quality table) and the
quality benchmark, with no change to jaxstyle. Also: the two papers' models satisfy the protocol."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from jaxstyle.control import loop, paths
from jaxstyle.control.controller import PFNNModel
from jaxstyle.control.lpn_controller import StyleNetModel
from jaxstyle.control.model import CharacterModel, Frames, rollout, rollout_batch
from jaxstyle.data import datasets, folders, procedural
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2018 import base_model
from jaxstyle.motion.bvh import read_bvh
from jaxstyle.motion.kinematics import global_positions
from jaxstyle.output import drive, quality, synthesis
from jaxstyle.train import defaults

# --- the toy family: everything a model family provides, in this file ----------------------------


class ToyState(NamedTuple):
    hist_xz: jax.Array  # (61, 2): the loop steers from hist_xz[-1]
    yaw: jax.Array
    t: jax.Array  # the capture frame played


class ToyFrames(NamedTuple):
    positions: jax.Array
    origin: jax.Array
    yaw: jax.Array
    outputs: jax.Array  # (origin x, origin z, capture frame)

    def decode(self, skeleton):
        t = np.asarray(self.outputs[:, 2]).astype(int) % skeleton.num_frames
        local = skeleton.local_positions[t].copy()
        local[:, 0, [0, 2]] = np.asarray(self.origin, np.float64)
        return skeleton.replace(rotations=skeleton.rotations[t], local_positions=local, source=None)

    def predicted_contacts(self, num_joints):
        return None

    def arrays(self):
        return {"positions": self.positions, "origin": self.origin, "yaw": self.yaw, "outputs": self.outputs}


@struct.dataclass
class ToyModel:
    poses: jax.Array  # (T, J, 3): the capture's joints, root over the origin

    def step(self, speed, state, control):
        move = speed * control[0][1] / 10.0  # a tenth of the 10-frame sample: the path's step per frame
        origin = state.hist_xz[-1] + move
        t = state.t + 1
        pose = self.poses[t % self.poses.shape[0]] + jnp.stack([origin[0], 0.0, origin[1]])
        yaw = jnp.arctan2(move[0], move[1])
        frame = ToyFrames(pose, origin, yaw, jnp.stack([origin[0], origin[1], t.astype(jnp.float32)]))
        return ToyState(jnp.concatenate([state.hist_xz[1:], origin[None]]), yaw, t), frame

    def initial_state(self, dataset, row, style):
        return ToyState(jnp.zeros((loop.HISTORY, 2)), jnp.zeros(()), jnp.asarray(int(dataset.frame[row])))

    @staticmethod
    def own_speed(dataset, rows, units_per_meter, fps=60.0):
        return float(np.median(np.linalg.norm(dataset.outputs[rows, :2], axis=1)) * fps / units_per_meter)

    def stack_styles(self, styles):
        return jnp.asarray(styles, jnp.float32)

    def blend_styles(self, styles, weights):
        return jnp.dot(jnp.asarray(weights, jnp.float32), jnp.asarray(styles, jnp.float32))


def toy_model(skeleton) -> ToyModel:
    pos = global_positions(skeleton)
    pos[:, :, [0, 2]] -= pos[:, :1, [0, 2]]
    return ToyModel(jnp.asarray(pos, jnp.float32))


# --- the shared code drives it -------------------------------------------------------------------


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = procedural.write_dataset(tmp_path_factory.mktemp("toy") / "data", ["Neutral", "Crouched"], ["FW"],
                                    seconds=6.0, progress=False)
    dataset = base_model.build(folders.clip_specs(root, ("Neutral", "Crouched"), None), None)
    skeleton = datasets.load_clip(dataset.specs[0], fps=60.0)
    chars = [drive.Character(f"{s} toy", s, 1.0, dataset, s) for s in dataset.styles]
    return dataset, skeleton, chars


def test_the_papers_models_and_the_toy_satisfy_the_protocol(data):
    _, skeleton, _ = data
    assert isinstance(toy_model(skeleton), CharacterModel)
    for cls in (PFNNModel, StyleNetModel, ToyModel):
        assert all(callable(getattr(cls, m, None)) for m in
                   ("step", "initial_state", "own_speed", "stack_styles", "blend_styles")), cls
    frames = ToyFrames(*(np.zeros(1),) * 4)
    assert isinstance(frames, Frames)


def test_a_toy_model_family_rolls_out_follows_paths_and_batches_like_single_rollouts(data):
    dataset, skeleton, chars = data
    model = toy_model(skeleton)
    upm = estimate_units_per_meter(skeleton)
    driven = drive.drive(model, chars, drive.Course(("straight", "circle"), 2.0), units_per_meter=upm, fps=60.0)
    assert [p for _, p in driven.pairs] == ["straight", "circle"] * 2
    assert driven.rollouts.positions.shape == (4, 120, skeleton.num_joints, 3)
    for k, sig in enumerate(driven.signals):  # the path-following law closes the error of a tracker
        err = np.linalg.norm(np.asarray(driven.rollouts.origin[k]) - sig.positions, axis=1) / upm
        assert err[-1] < 0.05, (k, err[-1])
    start = model.initial_state(dataset, 0, 1.0)
    controls = loop.signal_controls(driven.signals[1])
    one = rollout(model, jnp.float32(1.0), start, controls)
    batch = rollout_batch(model, jnp.float32(1.0), jax.tree.map(lambda v: v[None], start),
                          jax.tree.map(lambda v: v[None], controls), shared_style=True)
    np.testing.assert_allclose(np.asarray(batch.origin[0]), np.asarray(one.origin), atol=1e-5)
    mixed = drive.blend_character(model, [c._replace(conditioning=s) for c, s in zip(chars, (0.5, 1.5), strict=True)],
                                  (0.25, 0.75))
    assert float(mixed.conditioning) == pytest.approx(0.25 * 0.5 + 0.75 * 1.5)
    assert mixed.title == f"25% {chars[0].label} + 75% {chars[1].label}" and mixed.dataset is chars[0].dataset
    half = rollout(model, jnp.float32(0.5), start, loop.signal_controls(driven.signals[0], follow_seconds=None))
    full = rollout(model, jnp.float32(1.0), start, loop.signal_controls(driven.signals[0], follow_seconds=None))
    walked = [np.linalg.norm(np.asarray(r.origin[-1])) for r in (half, full)]
    assert walked[0] == pytest.approx(0.5 * walked[1], rel=1e-3)  # its conditioning is its style


def test_a_toy_model_family_is_synthesized_and_measured_by_the_shared_code(data, tmp_path):
    dataset, skeleton, chars = data
    model = toy_model(skeleton)
    out = synthesis.synthesize(model, chars, skeleton, tmp_path,
                               synthesis.SynthesisOptions(path_names=("straight",), seconds=2.0))
    assert out.frames == 2 * 120 and {f.name for f in out.files} >= {"straight.gif", "quality.csv"}
    bvh = read_bvh(tmp_path / "bvh" / "Neutral_straight.bvh")
    assert bvh.num_frames == 120 and bvh.names == skeleton.names
    rows, drawn = quality.run(model, [quality.subject(c, "base", "toy") for c in chars], skeleton,
                              path_names=("straight", "stop_and_go"), seconds=3.5)
    assert [(r["model"], r["path"]) for r in rows] == [("toy", p) for p in ("straight", "stop_and_go") * 2] + [
        ("toy", "capture")] * 2
    for r in rows[:4]:
        assert r["finite"] and r["bone_error_bvh_max"] < 1e-9 and np.isfinite(r["foot_skating_locked_m_s"])
        assert r["path_error_final_m"] < 0.05 or r["path"] == "stop_and_go"
    assert drawn[(chars[0].title, "straight")][0].shape == (210, skeleton.num_joints, 3)
    for r, c in ((rows[0], chars[0]), (rows[2], chars[1])):  # each walks at its own style's speed
        own = model.own_speed(dataset, datasets.style_rows(dataset, c.style), estimate_units_per_meter(skeleton))
        assert r["style"] == c.title and r["speed_m_s"] == pytest.approx(own)
    assert paths.PATHS  # the toy used the shared paths only


def test_a_toy_model_family_is_checked_like_a_fine_tuning_sweep_by_the_shared_code(data):
    """The closed-loop check both papers' sweeps call: each (style, conditioning) character of the
    one batched rollout is measured as its own single rollout (:func:`rollout_measures`), and the
    check tells a conditioning that walks the path from one that stands still."""
    from jaxstyle.labels.contacts import FootJoints, floor_heights
    from jaxstyle.motion.kinematics import UP_AXIS
    from jaxstyle.output import check as check_lib

    dataset, skeleton, _ = data
    model = toy_model(skeleton)
    fps, upm = 60.0, estimate_units_per_meter(skeleton)
    pos = global_positions(skeleton)
    feet = list(FootJoints.find(skeleton).ankles) + list(FootJoints.find(skeleton).toes)
    floor = floor_heights(pos[:, feet, UP_AXIS])
    check = defaults.RolloutCheck(seconds=2.0, turn_deg_per_s=30.0)
    judging = check_lib.Judging(skeleton, fps, upm, check)
    speed = 1.2 * upm
    starts = [check_lib.StyleStart(model.initial_state(dataset, row, 1.0), speed, floor, 0.6) for row in (0, 40)]
    styles = [[1.0, 0.0, 1.0], [0.9, 1.0, 1.0]]  # per style: two "rates", then the model before fine-tuning
    out, base = check_lib.check_pairs(model, styles, starts, judging)
    assert out["passed"].shape == (2, 2) and base["base_skating_m_s"].shape == (2,)
    controls = loop.turning_path(120, speed, np.deg2rad(30.0), fps)
    for s, start in enumerate(starts):
        for r, style in enumerate(styles[s]):
            one = rollout(model, jnp.float32(style), start.state, controls)
            ref = check_lib.rollout_measures(np.asarray(one.positions), np.asarray(one.origin), True, judging,
                                             floor, speed)
            got = {k: out[k][s, r] if r < 2 else base[f"base_{k}"][s] for k in
                   (("progress", "skating_m_s", "bone_error") if r < 2 else ("skating_m_s", "bone_error"))}
            for k, v in got.items():
                np.testing.assert_allclose(v, ref[k], rtol=1e-5, atol=1e-7, err_msg=f"{s} {r} {k}")
    assert out["progress"][0, 0] == pytest.approx(1.0, abs=0.05) and out["progress"][0, 1] < 0.01
    np.testing.assert_array_equal(out["passed"], [[1.0, 0.0], [1.0, 1.0]])  # standing still fails
    with pytest.raises(ValueError, match="one row of the same length"):
        check_lib.check_pairs(model, [[1.0, 1.0], [1.0]], starts, judging)
