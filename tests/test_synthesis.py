"""Synthesis along user paths: path builders, style blends, the LPN controller against the LPN
encoder, batched rollouts against single ones, the PFNN's 50-bin runtime against its continuous
phase."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.control import controller, loop, lpn_controller, paths
from jaxstyle.control.controller import PFNNModel
from jaxstyle.control.lpn_controller import StyleNetModel
from jaxstyle.control.model import rollout, rollout_batch, step_fn
from jaxstyle.data.clips import ClipSpec
from jaxstyle.data.datasets import load_clip
from jaxstyle.data.lpn_features import bone_points, foot_bones
from jaxstyle.data.normalise import Normaliser
from jaxstyle.motion import kinematics
from jaxstyle.motion.character_frame import CharacterFrames, rotate_yaw, to_local
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import pfnn, style_models

# --- paths --------------------------------------------------------------------------------------


def test_path_positions_integrate_the_velocity():
    fps = 60.0
    c = paths.circle(8.0, 1.2, 2.0, fps=fps, units_per_meter=100.0)
    # the ideal positions (sums of equal chords turning by equal angles) lie on one circle of
    # radius 2 m, its centre to the +X side (the yaw grows from +Z towards +X)
    a, b, d = c.positions[0], c.positions[100], c.positions[300]
    m = np.array([b - a, d - a])
    centre = np.linalg.solve(2 * m, [b @ b - a @ a, d @ d - a @ a])
    r = np.linalg.norm(c.positions - centre, axis=1)
    np.testing.assert_allclose(r, r[0], rtol=1e-9)
    assert r[0] == pytest.approx(200.0, abs=0.1) and centre[0] == pytest.approx(200.0, abs=1.0)
    np.testing.assert_allclose(np.linalg.norm(c.velocity, axis=1), 120.0)
    s = paths.straight(2.0, 1.5, heading=np.pi / 2)
    np.testing.assert_allclose(s.positions[-1], [1.5 * len(s.yaw) / 60.0, 0.0], atol=1e-9)


def test_stop_and_go_and_ramp_speeds():
    fps = 60.0
    s = paths.stop_and_go(6.0, 1.0, go=2.0, stop=1.0, fps=fps)
    speed = np.linalg.norm(s.velocity, axis=1)
    t = np.arange(len(speed)) / fps
    np.testing.assert_array_equal(speed > 0, np.mod(t, 3.0) < 2.0)
    assert np.ptp(s.yaw) == 0.0  # facing held while standing
    r = paths.speed_ramp(4.0, 0.5, 2.0, fps=fps)
    speed = np.linalg.norm(r.velocity, axis=1)
    assert speed[0] == pytest.approx(0.5) and speed[-1] == pytest.approx(2.0)
    assert (np.diff(speed) > 0).all()


def test_zigzag_alternates_heading():
    z = paths.zigzag(4.0, 1.0, period=2.0, angle_deg=30.0)
    deg = np.rad2deg(z.yaw)
    assert set(np.round(deg).astype(int)) == {30, -30}
    assert (deg[:60] == pytest.approx(30.0)) and (deg[60:120] == pytest.approx(-30.0))


def test_waypoints_walk_the_polyline_then_stop():
    pts = np.array([[0.0, 0.0], [0.0, 3.0], [2.0, 3.0]])
    w = paths.waypoints(pts, 1.0, fps=60.0)
    # the walk takes 5 s, then 1 s of standing; the end is the last waypoint
    assert len(w.yaw) == 360
    np.testing.assert_allclose(w.positions[-1], [2.0, 3.0], atol=1e-9)
    np.testing.assert_allclose(w.positions[179], [0.0, 3.0], atol=1e-9)
    assert np.linalg.norm(w.velocity[-60:], axis=1).max() == 0.0
    # every position lies on the polyline
    on_first = np.abs(w.positions[:180, 0]) < 1e-9
    on_second = np.abs(w.positions[179:, 1] - 3.0) < 1e-9
    assert on_first.all() and on_second.all()
    with pytest.raises(ValueError, match="differ"):
        paths.waypoints([[0, 0], [0, 0]], 1.0)
    with pytest.raises(KeyError, match="known"):
        paths.named("spiral", 2.0, 1.0)


def test_signal_controls_match_the_integrated_positions():
    sig = paths.zigzag(3.0, 1.3, units_per_meter=100.0)
    c = loop.signal_controls(sig)
    # offset k of frame t is the ideal displacement from frame t to t + 10 k (positions[t - 1] is
    # where frame t stands; frame 0 stands at the origin)
    before = np.concatenate([np.zeros((1, 2)), sig.positions])
    for t in (0, 37, 100):
        for k in range(6):
            if t + 10 * k < len(before):
                np.testing.assert_allclose(np.asarray(c.offsets[t, k]), before[t + 10 * k] - before[t], atol=1e-3)


# --- style blends -------------------------------------------------------------------------------

def test_cp_adapter_blend_equals_the_blend_of_residuals():
    config = pfnn.PFNNConfig(input_size=6, hidden_size=8, output_size=5, adapter="cp", rank=3)
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    adapters = jax.vmap(lambda k: pfnn.init_adapter(k, config))(keys)
    adapters["b"] = jax.random.normal(jax.random.PRNGKey(5), adapters["b"].shape)
    h = jax.random.normal(jax.random.PRNGKey(1), (7, 8))
    w4 = pfnn.catmull_rom_weights(jnp.linspace(0, 0.9, 7))
    weights = np.array([0.2, 0.5, 0.3])
    want = sum(weights[k] * np.asarray(pfnn.apply_adapter(jax.tree.map(lambda v, k=k: v[k], adapters), h, w4),
                                       np.float64) for k in range(3))
    blended = pfnn.blend_adapters(adapters, weights)
    assert blended["A"].shape == (9, 8)
    np.testing.assert_allclose(pfnn.apply_adapter(blended, h, w4), want, rtol=1e-5, atol=1e-5)
    # and through the 50-bin table, bin by bin
    table = pfnn.discretise(blended, 50)
    np.testing.assert_allclose(table["d"].shape, (50, 9))
    for kind in ("full", "diagonal"):
        c = pfnn.PFNNConfig(input_size=6, hidden_size=8, output_size=5, adapter=kind)
        a = jax.vmap(lambda k, c=c: pfnn.init_adapter(k, c))(keys[:2])
        a["b"] = jax.random.normal(jax.random.PRNGKey(6), a["b"].shape)
        want = sum(wk * np.asarray(pfnn.apply_adapter(jax.tree.map(lambda v, k=k: v[k], a), h, w4))
                   for k, wk in enumerate((0.4, 0.6)))
        np.testing.assert_allclose(pfnn.apply_adapter(pfnn.blend_adapters(a, [0.4, 0.6]), h, w4), want,
                                   rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="sum"):
        pfnn.blend_adapters(adapters, [0.5, 0.6, 0.1])
    # zero-padding the rank keeps the residual, so a blend stacks with single styles
    single = jax.tree.map(lambda v: v[0], adapters)
    padded = pfnn.pad_rank(single, 9)
    assert padded["A"].shape == (9, 8)
    np.testing.assert_allclose(pfnn.apply_adapter(padded, h, w4), pfnn.apply_adapter(single, h, w4), rtol=1e-6,
                               atol=1e-6)
    with pytest.raises(ValueError, match="rank"):
        pfnn.pad_rank(blended, 3)
    # stacking a rank-3 style with the rank-9 blend pads the first: each keeps its own residual
    stacked = pfnn.stack_adapters([single, blended])
    assert stacked["A"].shape == (2, 9, 8)
    for k, want_k in enumerate((pfnn.apply_adapter(single, h, w4), pfnn.apply_adapter(blended, h, w4))):
        np.testing.assert_allclose(pfnn.apply_adapter(jax.tree.map(lambda v, k=k: v[k], stacked), h, w4), want_k,
                                   rtol=1e-6, atol=1e-6)


def test_style_blends_of_every_modulation_are_linear_in_the_output_where_they_should_be():
    cfg = style_models.StyleModelConfig("lpn", "onehot", num_styles=3, input_size=10, hidden_size=8, output_size=9,
                                        gating_input=4, gating_hidden=6, num_experts=3)
    params = style_models.init_model(jax.random.PRNGKey(0), cfg)
    table = params["style"]["onehot"]
    blend = style_models.blend_styles(cfg, table[:2], [0.25, 0.75])
    np.testing.assert_allclose(blend, 0.25 * table[0] + 0.75 * table[1], rtol=1e-6)
    fcfg = style_models.StyleModelConfig("lpn", "film", num_styles=3, hidden_size=8,
                                         generator=film.FiLMConfig(16, 6, 4, 5, 8, 32))
    v = jax.random.normal(jax.random.PRNGKey(1), (3, 32))
    np.testing.assert_allclose(style_models.blend_styles(fcfg, v, [0.2, 0.3, 0.5]),
                               0.2 * v[0] + 0.3 * v[1] + 0.5 * v[2], rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="weight"):
        style_models.blend_styles(cfg, table[:2], [0.5, 0.4])


# --- the LPN controller against the encoder -----------------------------------------------------

@pytest.fixture(scope="module")
def lpn_clip(mocap):
    m = load_clip(ClipSpec(str(mocap / "100style/Drunk/Drunk_SW.bvh"), "Drunk", 0, 700), fps=60.0)
    feats = js.encode_lpn(m)
    return m, feats


def _real_controls(frames, t, n):
    t0 = t[0]
    idx = t[:n][:, None] + 10 * np.arange(6)[None]
    disp = rotate_yaw(frames.origin[idx] - frames.origin[t[:n]][:, None], np.full(idx.shape, -frames.yaw[t0]))
    return loop.Controls(jnp.asarray(disp[..., [0, 2]], jnp.float32),
                               jnp.asarray(frames.yaw[idx] - frames.yaw[t0], jnp.float32))


def test_lpn_teacher_forced_loop_reproduces_the_encoded_inputs(lpn_clip):
    """Fed the real outputs, the LPN loop must rebuild the real inputs (once its history is real),
    the real local phases and the real global positions of every LPN bone."""
    m, feats = lpn_clip
    x, y, t, p = feats.inputs, feats.outputs, feats.frames, feats.phases
    frames = js.character_frames(m)
    n = 90
    controls = _real_controls(frames, t, n)
    num_bones = len(feats.bones)
    state = lpn_controller.initial_state(x[0], p[0], num_bones)
    start = CharacterFrames(frames.origin[[t[0]]], frames.yaw[[t[0]]])
    g_rot, g_pos = kinematics.global_transforms(m)
    points = bone_points(m)[0]
    all_pos = np.concatenate([g_pos, kinematics.end_site_positions(m, g_rot, g_pos)], axis=1)[:, points]
    step = jax.jit(lambda s, yi: lpn_controller.advance(s, yi, num_bones))
    for i in range(n):
        built = np.concatenate([np.asarray(loop.trajectory_input(
            state.hist_xz, state.hist_yaw, state.future, (controls.offsets[i], controls.yaw[i]))),
            np.asarray(state.joints)])
        scale = np.abs(x[i]).max()
        if i >= loop.HISTORY - 1:
            np.testing.assert_allclose(built, x[i], atol=1e-3 * scale)
        else:
            np.testing.assert_allclose(built[24:], x[i][24:], atol=1e-3 * scale)
        np.testing.assert_allclose(np.asarray(state.phases), p[i], atol=1e-4)
        state, frame = step(state, jnp.asarray(y[i], jnp.float32))
        real = to_local(all_pos[t[i] + 1][None], start, np.array([0]))[0]
        np.testing.assert_allclose(np.asarray(frame.positions), real, atol=1e-3 * np.abs(real).max())


def _small_lpn(x, y, backbone="lpn", modulation="film"):
    config = style_models.StyleModelConfig(backbone, modulation, num_styles=2, input_size=x.shape[1], hidden_size=16,
                                           output_size=y.shape[1], gating_hidden=8, num_experts=3,
                                           gating_input=8 if backbone == "lpn" else 12,
                                           generator=film.FiLMConfig(240, 300, 4, 5, 8, 64))
    params = style_models.init_model(jax.random.PRNGKey(0), config)
    x_norm = Normaliser(x.mean(0), x.std(0) + 1e-3)
    y_norm = Normaliser(y.mean(0), y.std(0) + 1e-3)
    return config, params, x_norm, y_norm


def _blend_setup(lpn_clip):
    """A small LPN on the clip, its feet and other bones, a circle's controls, a start and a style."""
    m, feats = lpn_clip
    x, y, p = feats.inputs, feats.outputs, feats.phases
    config, params, x_norm, y_norm = _small_lpn(x, y)
    num_bones = len(feats.bones)
    feet = list(foot_bones(m)[0])
    others = [b for b in range(num_bones) if b not in feet]
    controls = loop.signal_controls(paths.circle(0.5, 0.5, 1.5, units_per_meter=100.0), follow_gain=1.0)
    state = lpn_controller.initial_state(x[10], p[10], num_bones)
    style = jnp.concatenate([0.3 * jnp.ones(16), jnp.zeros(16), 0.3 * jnp.ones(16), jnp.zeros(16)])
    return m, config, params, x_norm, y_norm, num_bones, feet, others, controls, state, style


def _first_frame_blend(half, other, style, state, controls, num_bones):
    """One frame of a model blending every bone at 0.5 and of ``other``: the predicted positions
    ``P`` (from ``0.5 P + 0.5 (p + V)``), ``p + V`` and both models' carried positions, in ``C_t``."""
    control = (controls.offsets[0], controls.yaw[0])
    _, f_half = half.step(style, state, control)
    _, f_other = other.step(style, state, control)
    g = js.LPNLayout(num_bones).output_groups
    moved_on = (np.asarray(state.joints[:3 * num_bones]).reshape(num_bones, 3)
                + np.asarray(f_half.outputs[g["joint_velocity"]]).reshape(num_bones, 3))  # p + V in C_t
    half_pos = np.asarray(f_half.outputs[g["joint_position"]]).reshape(num_bones, 3)
    other_pos = np.asarray(f_other.outputs[g["joint_position"]]).reshape(num_bones, 3)
    return 2 * half_pos - moved_on, moved_on, half_pos, other_pos


def test_foot_smooth_blends_only_the_feet(lpn_clip):
    """StyleNetModel's foot_smooth: the ankles and toes carry s P + (1 - s)(p + V) with their own
    s, every other joint the default 0.5; foot_smooth 0.5 is the paper's runtime exactly."""
    m, config, params, x_norm, y_norm, num_bones, feet, others, controls, state, style = _blend_setup(lpn_clip)
    paper = StyleNetModel.create(params, config, (x_norm, y_norm))
    half = StyleNetModel.create(params, config, (x_norm, y_norm), m, foot_smooth=0.5)
    low = StyleNetModel.create(params, config, (x_norm, y_norm), m, foot_smooth=0.1)
    s = low.joint_smooth()
    assert s.shape == (num_bones, 1) and np.all(s[feet] == np.float32(0.1)) and np.all(s[others] == 0.5)
    np.testing.assert_array_equal(np.asarray(rollout(paper, style, state, controls).positions),
                                  np.asarray(rollout(half, style, state, controls).positions))
    predicted, moved_on, half_pos, low_pos = _first_frame_blend(half, low, style, state, controls, num_bones)
    np.testing.assert_allclose(low_pos[feet], 0.1 * predicted[feet] + 0.9 * moved_on[feet], atol=1e-3)
    np.testing.assert_array_equal(low_pos[others], half_pos[others])
    assert np.abs(low_pos[feet] - half_pos[feet]).max() > 1e-3
    with pytest.raises(ValueError, match="foot_smooth"):
        StyleNetModel.create(params, config, (x_norm, y_norm), foot_smooth=0.1)
    with pytest.raises(ValueError, match="foot_smooth"):
        StyleNetModel.create(params, config, (x_norm, y_norm), m, foot_smooth=1.5)


def test_body_smooth_blends_every_other_bone(lpn_clip):
    """StyleNetModel's body_smooth: every bone without foot_smooth carries s P + (1 - s)(p + V)
    with s = body_smooth (the feet keep foot_smooth); body_smooth 0.5 is the paper's runtime exactly."""
    m, config, params, x_norm, y_norm, num_bones, feet, others, controls, state, style = _blend_setup(lpn_clip)
    paper = StyleNetModel.create(params, config, (x_norm, y_norm))
    half = StyleNetModel.create(params, config, (x_norm, y_norm), body_smooth=0.5)
    assert half.bone_smooth is None
    np.testing.assert_array_equal(np.asarray(rollout(paper, style, state, controls).positions),
                                  np.asarray(rollout(half, style, state, controls).positions))
    body = StyleNetModel.create(params, config, (x_norm, y_norm), body_smooth=0.2)
    both = StyleNetModel.create(params, config, (x_norm, y_norm), m, foot_smooth=0.1, body_smooth=0.2)
    assert np.all(body.joint_smooth() == np.float32(0.2))
    s = both.joint_smooth()
    assert np.all(s[feet] == np.float32(0.1)) and np.all(s[others] == np.float32(0.2))
    predicted, moved_on, _, got = _first_frame_blend(half, both, style, state, controls, num_bones)
    np.testing.assert_allclose(got[others], 0.2 * predicted[others] + 0.8 * moved_on[others], atol=1e-3)
    np.testing.assert_allclose(got[feet], 0.1 * predicted[feet] + 0.9 * moved_on[feet], atol=1e-3)
    assert np.abs(got[others] - (predicted[others] + moved_on[others]) / 2).max() > 1e-3
    for bad in (1.5, -0.1, float("nan")):
        with pytest.raises(ValueError, match="body_smooth"):
            StyleNetModel.create(params, config, (x_norm, y_norm), body_smooth=bad)


def test_partly_forced_reads_the_clip_or_its_own_loop(lpn_clip):
    """partly_forced: with the clip's joints and phases every frame's output is the network applied
    to the clip's rows (a batch call); with neither, frame 1 reads what advance() carried from frame 0."""
    from jaxstyle.control.lpn_phases import gate_input

    m, feats = lpn_clip
    x, y, p = feats.inputs, feats.outputs, feats.phases
    config, params, x_norm, y_norm = _small_lpn(x, y)
    model = StyleNetModel.create(params, config, (x_norm, y_norm), m, foot_smooth=0.1, body_smooth=0.2)
    style = jnp.concatenate([0.3 * jnp.ones(16), jnp.zeros(16), 0.3 * jnp.ones(16), jnp.zeros(16)])
    state = lpn_controller.initial_state(x[10], p[10], len(feats.bones))
    rows = slice(10, 40)
    forced, _ = lpn_controller.partly_forced(model, style, state, x[rows], p[rows], np.array([True, True]))
    (mu, sd), (y_mu, y_sd) = (tuple(np.asarray(v) for v in n) for n in (model.x_norm, model.y_norm))
    x_n = (x[rows] - mu) / sd
    gate = gate_input(config, jnp.asarray(p[rows], jnp.float32), jnp.zeros(30), jnp.asarray(x_n, jnp.float32), None)
    direct = style_models.model_apply(params, config, jnp.asarray(x_n, jnp.float32), gate, style)
    np.testing.assert_allclose(np.asarray(forced), np.asarray(direct) * y_sd + y_mu,
                               rtol=1e-4, atol=1e-4)
    own, frames = lpn_controller.partly_forced(model, style, state, x[rows], p[rows], np.array([False, False]))
    np.testing.assert_allclose(np.asarray(own[0]), np.asarray(forced[0]), rtol=1e-5, atol=1e-5)
    carried, _ = lpn_controller.advance(state, own[0], model.num_bones, 0.0, model.joint_smooth())
    x1 = np.concatenate([x[11][:48], np.asarray(carried.joints)])
    x1_n = jnp.asarray(((x1 - mu) / sd)[None], jnp.float32)
    gate1 = gate_input(config, carried.phases[None], carried.global_phase[None], x1_n, None)
    want = style_models.model_apply(params, config, x1_n, gate1, style)[0] * y_sd + y_mu
    np.testing.assert_allclose(np.asarray(own[1]), np.asarray(want), rtol=1e-4, atol=1e-4)
    assert np.abs(np.asarray(own[1]) - np.asarray(forced[1])).max() > 1e-3
    np.testing.assert_allclose(np.asarray(frames.phases[0]), np.asarray(carried.phases), atol=1e-6)


def test_lpn_batch_equals_single_rollouts_and_decodes(lpn_clip):
    m, feats = lpn_clip
    x, y, p = feats.inputs, feats.outputs, feats.phases
    config, params, x_norm, y_norm = _small_lpn(x, y)
    num_bones = len(feats.bones)
    signals = [paths.straight(0.5, 1.0, units_per_meter=100.0), paths.circle(0.5, 1.0, 1.5, units_per_meter=100.0),
               paths.zigzag(0.5, 1.2, units_per_meter=100.0)]
    # gain 1: the untrained network's closed loop amplifies rounding, the more the higher the gain
    controls = [loop.signal_controls(s, follow_gain=1.0) for s in signals]
    states = [lpn_controller.initial_state(x[i], p[i], num_bones) for i in (0, 50, 100)]
    # gamma near 0.3, beta near 0: FiLM damps the untrained network, so its closed loop does not
    # amplify float32 rounding (with gamma near 1 batched and single rollouts part after ~18 frames)
    styles = jax.random.normal(jax.random.PRNGKey(3), (3, 64)) * 0.1 + jnp.tile(
        jnp.concatenate([0.3 * jnp.ones(16), jnp.zeros(16)]), 2)
    stack = lambda items: jax.tree.map(lambda *v: jnp.stack(v), *items)  # noqa: E731
    model = StyleNetModel.create(params, config, (x_norm, y_norm))
    many = rollout_batch(model, styles, stack(states), stack(controls))
    assert many.positions.shape == (3, 30, num_bones, 3)
    assert np.isfinite(np.asarray(many.outputs)).all()
    # an untrained network in a closed loop amplifies float32 rounding (batched products sum in
    # another order), so the first frames must agree to rounding and the rest to 0.2% of the scale
    scale = np.abs(np.asarray(many.positions)).max()
    for c in (0, 2):
        one = rollout(model, styles[c], states[c], controls[c])
        np.testing.assert_allclose(np.asarray(many.positions[c, :5]), np.asarray(one.positions[:5]), atol=1e-5 * scale)
        np.testing.assert_allclose(np.asarray(many.positions[c]), np.asarray(one.positions), atol=2e-3 * scale)
    # the live step (weights compiled in, style an argument) makes the same first frames
    step = step_fn(model, styles[0])
    s0, f0 = step(states[2], (controls[2].offsets[0], controls[2].yaw[0]), styles[2])
    _, f1 = step(s0, (controls[2].offsets[1], controls[2].yaw[1]), styles[2])
    np.testing.assert_allclose(np.asarray(f1.positions), np.asarray(one.positions[1]), atol=1e-4 * scale)
    # the recorded outputs decode (numpy decode_lpn) to the same root path
    decoded = js.decode_lpn(np.asarray(one.outputs), m)
    np.testing.assert_allclose(np.asarray(one.positions)[:, 0], kinematics.global_positions(decoded)[:, 0],
                               atol=1e-3 * np.abs(np.asarray(one.positions)).max())
    # the MANN backbone gates on end-effector columns, and says so when they are missing
    mcfg, mparams, _, _ = _small_lpn(x, y, backbone="mann")
    out = rollout(StyleNetModel.create(mparams, mcfg, (x_norm, y_norm), m), styles[0], states[0], controls[0])
    assert np.isfinite(np.asarray(out.positions)).all()
    with pytest.raises(ValueError, match="gate_columns"):
        StyleNetModel.create(mparams, mcfg, (x_norm, y_norm))
    with pytest.raises(ValueError, match="shape"):
        lpn_controller.initial_state(x[0][:-1], p[0], num_bones)


def test_pfnn_table_rollout_matches_the_continuous_phase(mocap):
    """The runtime's 50-bin table and the continuous Catmull-Rom phase agree closely over a rollout
    (the table's largest phase error is 1/100 of a cycle)."""
    m = load_clip(ClipSpec(str(mocap / "100style/Neutral/Neutral_FW.bvh"), "Neutral", 0, 400), fps=60.0)
    phase = js.global_phase(m)
    x, y, t = js.encode_pfnn(m, phase)
    config = pfnn.PFNNConfig(input_size=x.shape[1], hidden_size=32, output_size=y.shape[1], rank=4)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
    adapter = pfnn.init_adapter(jax.random.PRNGKey(1), config)
    x_norm = Normaliser(x.mean(0), x.std(0) + 1e-3)
    y_norm = Normaliser(y.mean(0), y.std(0) + 1e-3)
    state = controller.initial_state(x[0], phase[t[0]], m.num_joints)
    c = loop.signal_controls(paths.straight(0.2, 1.0, units_per_meter=100.0))
    tabled = PFNNModel.create(pfnn.discretise(params), (x_norm, y_norm), m.num_joints, table=True)
    cont = rollout(PFNNModel.create(params, (x_norm, y_norm), m.num_joints), adapter, state, c)
    tab = rollout(tabled, pfnn.discretise(adapter), state, c)
    # the same frames, to within the table's phase resolution over a dozen frames of feedback
    err = np.abs(np.asarray(cont.positions) - np.asarray(tab.positions)).max(axis=(1, 2))
    scale = np.abs(np.asarray(cont.positions)).max()
    assert err[0] < 0.02 * scale
    assert np.isfinite(np.asarray(tab.positions)).all()
    # the live step of the table runtime makes the rollout's first frame
    step = step_fn(tabled, pfnn.discretise(adapter))
    _, frame = step(state, (c.offsets[0], c.yaw[0]))
    np.testing.assert_allclose(np.asarray(frame.positions), np.asarray(tab.positions[0]), atol=1e-4 * scale)


# --- a trained model along user paths (the acceptance test) -------------------------------------

@pytest.fixture(scope="module")
def trained_pfnn(mocap):
    """A small PFNN (hidden 128, CP rank 8) trained for 10 epochs on the shared Neutral clips
    (walk, run, turns, idle, mirrored): about 4,300 rows, under a minute on 2 CPU cores."""
    import warnings

    from jaxstyle.data import clips, datasets
    from jaxstyle.mason2018.train import TrainConfig, data_from_dataset, train

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # short clips are skipped with a warning
        specs = clips.specs_100style(mocap / "100style", styles=["Neutral"])
        dataset = datasets.build_pfnn_dataset(specs, skip_short=True)
    layout = js.PFNNLayout((dataset.inputs.shape[1] - 48) // 6)
    model = pfnn.PFNNConfig(input_size=layout.input_size, hidden_size=128, output_size=layout.output_size, rank=8)
    state = train(data_from_dataset(dataset), TrainConfig(model=model, epochs=10, half_mirrored=True,
                                                          dropout_rate=0.1), None, progress=False)
    skeleton = datasets.load_clip(specs[0], fps=60.0)
    return state.params, dataset, skeleton


def test_four_characters_follow_their_paths(trained_pfnn, tmp_path):
    """300 frames (5 s) for 4 characters at once along different paths: all finite, bones within
    5% of their length, and the straight walker within 0.5 m of where the path wants it."""
    params, dataset, skeleton = trained_pfnn
    upm = js.estimate_units_per_meter(skeleton)
    speed = 1.0
    signals = [paths.straight(5.0, speed, units_per_meter=upm), paths.circle(5.0, speed, 2.5, units_per_meter=upm),
               paths.zigzag(5.0, speed, units_per_meter=upm), paths.stop_and_go(5.0, speed, units_per_meter=upm)]
    row = loop.start_row(dataset.inputs, speed, units_per_meter=upm,
                               rows=dataset.rows_of_style("Neutral", "train"))
    state = controller.initial_state(dataset.inputs[row], float(dataset.phases[row, 0]), skeleton.num_joints)
    stack = lambda items: jax.tree.map(lambda *v: jnp.stack(v), *items)  # noqa: E731
    model = PFNNModel.create(params, dataset.normalisers(), skeleton.num_joints)
    out = rollout_batch(model, None, stack([state] * 4), stack([loop.signal_controls(s) for s in signals]),
                        shared_style=True)
    assert out.positions.shape == (4, 300, skeleton.num_joints, 3)
    assert np.isfinite(np.asarray(out.outputs)).all()
    for c in range(len(signals)):
        bone = js.output.metrics.bone_length_errors(np.asarray(out.positions[c]), skeleton)
        assert bone.mean() < 0.05, (c, bone.mean())
    straight = js.output.metrics.path_error(np.asarray(out.origin[0]), signals[0].positions, units_per_meter=upm)
    assert straight[-1] < 0.5, straight[-1]
    # the walker really walked: at least 4 of the 5 m requested
    assert np.linalg.norm(np.asarray(out.origin[0, -1])) / upm > 4.0

    # export: the BVH reads back with the skeleton's bone lengths and the rollout's root path
    from jaxstyle.output import export, footlock

    one = jax.tree.map(lambda v: v[1], out)
    written = export.save_rollout(tmp_path / "circle", one, skeleton, foot_lock=True)
    back = js.read_bvh(written["bvh"])
    assert back.num_frames == 300 and back.names == skeleton.names
    errors = js.output.metrics.bone_length_errors(js.global_positions(back), skeleton)
    np.testing.assert_allclose(errors, 0.0, atol=1e-4)
    root = js.global_positions(back)[:, 0]
    np.testing.assert_allclose(root[:, [0, 2]], np.asarray(one.positions)[:, 0, [0, 2]], atol=0.5)  # cm; BVH precision
    arrays = np.load(written["npz"])
    np.testing.assert_array_equal(arrays["positions"], np.asarray(one.positions))
    assert arrays["fps"] == 60.0 and list(arrays["names"]) == list(skeleton.names)
    # foot_lock=False writes the decoded motion as generated; the default locks it: the same
    # motion except hip, knee and ankle rotations, feet moved no more than the 0.15 m limit
    raw = js.read_bvh(export.save_rollout(tmp_path / "raw", one, skeleton, foot_lock=False)["bvh"])
    decoded = export.rollout_motion(one, skeleton)
    np.testing.assert_allclose(js.global_positions(raw), js.global_positions(decoded), atol=1e-3)
    legs = footlock.leg_rig(skeleton)
    others = [j for j in range(skeleton.num_joints) if j not in (*legs.hip, *legs.knee, *legs.ankle)]
    np.testing.assert_allclose(back.rotations[:, others], raw.rotations[:, others], atol=1e-5)
    moved = np.linalg.norm(js.global_positions(back) - js.global_positions(raw), axis=-1).max() / upm
    assert moved <= 0.15
