"""The 2022 controller (:mod:`jaxstyle.control.lpn_controller`) driving Table 2's PFNN-backbone
models at a carried global phase, and its stop handling (the 2018 controller's standing amount,
:func:`jaxstyle.control.loop.stand_damping`).

Default run: the global phase's update against a real clip's labels (teacher forced) and a
closed loop of an initialised PFNN FiLM (evaluated at the carried phase, vmap == loop). Slow: a
tiny PFNN FiLM trained on real walking and idling is reloaded from its run folder, keeps its
phase near the data's rate, stops and walks again, and synthesises through the library and the
command line."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.cli.main import main
from jaxstyle.control import loop, lpn_controller, lpn_phases, paths
from jaxstyle.control.lpn_controller import StyleNetModel
from jaxstyle.control.model import rollout, rollout_batch, step_fn
from jaxstyle.data import datasets
from jaxstyle.data.clips import ClipSpec
from jaxstyle.data.datasets import load_clip, style_rows
from jaxstyle.data.lpn_features import LPNLayout
from jaxstyle.data.normalise import Normaliser
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2022 import pipeline
from jaxstyle.mason2022 import synthesis as synthesis2022
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import style_models
from jaxstyle.output import metrics, synthesis


@pytest.fixture(scope="module")
def walk(mocap):
    """LPN features of 700 frames of Neutral_FW (consecutive rows, global and local phases)."""
    m = load_clip(ClipSpec(str(mocap / "100style/Neutral/Neutral_FW.bvh"), "Neutral", 0, 700), fps=60.0)
    return m, js.encode_lpn(m)


def test_teacher_forced_global_phase_advances_as_the_labels(walk):
    """Fed the real output rows, the derived advance (the rows' local advance times their ratio)
    adds up to the labelled global phase's advance, stays in [0, 1) and never goes back; a
    standing character neither moves nor turns and its phases advance at a tenth of the rate."""
    _, f = walk
    num_bones = len(f.bones)
    y = f.outputs
    assert np.all(np.diff(f.frames) == 1)
    omega = lpn_phases.predicted_advance(y, num_bones)
    ratio = lpn_phases.global_phase_ratio(f.global_phase, omega, np.zeros(len(y), int), f.frames)
    assert 0.3 < ratio < 1.0  # 100STYLE's local phases turn faster than the stride (module docstring)
    state = lpn_controller.initial_state(f.inputs[0], f.phases[0], num_bones, f.global_phase[0], ratio)
    step = jax.jit(lambda s, yi, stand: lpn_controller.advance(s, yi, num_bones, stand))
    phis = [float(state.global_phase)]
    for i in range(len(y) - 1):
        state, frame = step(state, jnp.asarray(y[i], jnp.float32), 0.0)
        phis.append(float(frame.global_phase))
    phis = np.asarray(phis)
    assert np.all((phis >= 0) & (phis < 1))
    adv = np.mod(np.diff(phis), 1.0)
    assert np.all(adv < 0.5)  # forwards only (a step back would read as most of a cycle)
    np.testing.assert_allclose(adv, ratio * np.maximum(omega[:-1], 0.0), rtol=1e-3, atol=1e-6)
    real = np.mod(np.diff(f.global_phase), 1.0)
    # the labels' cycles, counted by the derived phase (the ratio is fitted on these rows; the
    # last row's advance has no label pair)
    np.testing.assert_allclose(adv.sum(), real.sum(), rtol=0.02)
    # standing: no root motion, no turn, phases advance at 0.1 of their rate
    before = state
    still, frame = step(before, jnp.asarray(y[0], jnp.float32), 1.0)
    np.testing.assert_allclose(np.asarray(still.hist_xz[-1]), np.asarray(before.hist_xz[-1]), atol=1e-5)
    np.testing.assert_allclose(float(still.hist_yaw[-1]), float(before.hist_yaw[-1]), atol=1e-6)
    np.testing.assert_allclose(np.mod(float(still.global_phase) - float(before.global_phase), 1.0),
                               0.1 * ratio * omega[0], rtol=1e-3)
    np.testing.assert_allclose(np.asarray(still.phases) - np.asarray(before.phases),
                               0.1 * (0.5 * (y[0, -18:-10] + np.asarray(before.phases) + y[0, -10:-2])
                                      - np.asarray(before.phases)), atol=1e-5)


def test_carried_bones_blend_the_prediction_with_the_moved_on_bones(walk):
    """``loop.JOINT_SMOOTH``: with velocities that disagree with the positions, the drawn bones
    are ``s P + (1 - s) (p + V)`` in ``C_t`` (recomputed here with numpy, then put in the world by
    the current ground frame), the recorded outputs hold them, and ``s = 1`` is the raw prediction."""
    _, f = walk
    num_bones = len(f.bones)
    g = LPNLayout(num_bones).output_groups
    state = lpn_controller.initial_state(f.inputs[10], f.phases[10], num_bones, f.global_phase[10], 0.8)
    state = state._replace(hist_xz=state.hist_xz + jnp.asarray([1.5, -4.0]), hist_yaw=state.hist_yaw - 0.4)
    y = np.array(f.outputs[10], dtype=np.float64)
    y[g["joint_velocity"]] += np.random.default_rng(1).normal(scale=1.5, size=3 * num_bones)
    origin, yaw = np.asarray(state.hist_xz[-1], np.float64), float(state.hist_yaw[-1])
    now = np.asarray(state.joints, np.float64).reshape(4, num_bones, 3)[0]
    for s in (0.5, 0.2, 1.0):
        _, frame = lpn_controller.advance(state, jnp.asarray(y, jnp.float32), num_bones, 0.0, s)
        local = s * y[g["joint_position"]].reshape(num_bones, 3) + (1 - s) * (now + y[g["joint_velocity"]].reshape(
            num_bones, 3))
        c, sn = np.cos(yaw), np.sin(yaw)
        want = np.stack([local[:, 0] * c + local[:, 2] * sn + origin[0], local[:, 1],
                         -local[:, 0] * sn + local[:, 2] * c + origin[1]], axis=-1)
        np.testing.assert_allclose(np.asarray(frame.positions), want, atol=1e-3 * np.abs(want).max())
        np.testing.assert_allclose(np.asarray(frame.outputs)[g["joint_position"]], local.reshape(-1),
                                   atol=1e-3 * np.abs(local).max())


def test_damped_output_moves_the_next_frame_and_the_body_rigidly(walk):
    """:func:`lpn_controller.damp_output` with ``move``: the next ground frame moves ``move`` times
    the step and turns ``move`` times the turn; the pose is the same in that frame (distances
    between bones kept, the local pose relative to the damped frame unchanged)."""
    _, f = walk
    num_bones = len(f.bones)
    g = LPNLayout(num_bones).output_groups
    n = 6
    i = int(np.argmax(np.abs(np.arctan2(f.outputs[:, 2 * n], f.outputs[:, 3 * n]))))  # the sharpest turn
    y = jnp.asarray(f.outputs[i], jnp.float32)
    np.testing.assert_allclose(np.asarray(lpn_controller.damp_output(y, 1.0, num_bones)), np.asarray(y), atol=1e-5)
    d = np.asarray(lpn_controller.damp_output(y, 0.25, num_bones), np.float64)
    yy = np.asarray(y, np.float64)
    np.testing.assert_allclose(d[[0, n]], 0.25 * yy[[0, n]], rtol=1e-5, atol=1e-7)
    turn = np.arctan2(yy[2 * n], yy[3 * n])
    np.testing.assert_allclose(np.arctan2(d[2 * n], d[3 * n]), 0.25 * turn, rtol=1e-4, atol=1e-7)

    def in_next_frame(row, a):  # bone positions relative to the next ground frame (x z shift, turn a)
        p = row[g["joint_position"]].reshape(num_bones, 3)
        x, z = np.asarray(loop.rotate_xz(p[:, 0] - row[0], p[:, 2] - row[n], -a))
        return np.stack([x, p[:, 1], z], axis=-1)

    np.testing.assert_allclose(in_next_frame(d, 0.25 * turn), in_next_frame(yy, turn), atol=1e-4)


def _pfnn_film(x, y):
    """An initialised PFNN FiLM on rows ``x``/``y`` (hidden 16) and their statistics."""
    config = style_models.StyleModelConfig("pfnn", "film", num_styles=2, input_size=x.shape[1], hidden_size=16,
                                           output_size=y.shape[1], gating_input=1,
                                           generator=film.FiLMConfig(240, 300, 4, 5, 8, 64))
    params = style_models.init_model(jax.random.PRNGKey(0), config)
    return config, params, Normaliser(x.mean(0), x.std(0) + 1e-3), Normaliser(y.mean(0), y.std(0) + 1e-3)


def test_pfnn_backbone_is_evaluated_at_the_carried_global_phase(walk):
    """Closed loop with a PFNN FiLM: frame 0 is the network at the start row's global phase (an
    independent evaluation; another phase gives another output), every frame's phase advance is
    the ratio times the recorded output's local advance, the phase stays in [0, 1), and a batch
    of characters equals one rollout each."""
    _, f = walk
    x, y = f.inputs, f.outputs
    num_bones = len(f.bones)
    config, params, x_norm, y_norm = _pfnn_film(x, y)
    # an untrained network predicts no local advance: its statistics pin the local phases (std
    # 1e-4) at phases 0.01 cycles apart (previous ``P~ - dP`` and next ``P~``), an advance of 0.01
    g = LPNLayout(num_bones).output_groups
    a = 2 * np.pi * np.array([0.1, 0.35, 0.6, 0.85])
    nxt = np.stack([np.sin(a + 0.02 * np.pi), np.cos(a + 0.02 * np.pi)], -1).ravel()
    prev = np.stack([np.sin(a), np.cos(a)], -1).ravel()
    mean, std = y_norm.mean.copy(), y_norm.std.copy()
    mean[g["local_phase"]], mean[g["local_phase_update"]] = nxt, nxt - prev
    std[g["local_phase"]] = std[g["local_phase_update"]] = 1e-4
    y_norm = Normaliser(mean, std)
    # gamma near 0.3: FiLM damps the untrained network, so the closed loop stays tame (see test_synthesis.py)
    styles = jax.random.normal(jax.random.PRNGKey(3), (3, 64)) * 0.1 + jnp.tile(
        jnp.concatenate([0.3 * jnp.ones(16), jnp.zeros(16)]), 2)
    starts = (0, 200, 400)  # 3 characters: straight, circle, zigzag
    states = [lpn_controller.initial_state(x[i], f.phases[i], num_bones, f.global_phase[i], 0.8) for i in starts]
    controls = [loop.signal_controls(s) for s in (paths.straight(0.5, 1.0, units_per_meter=100.0),
                                                  paths.circle(0.5, 1.0, 1.5, units_per_meter=100.0),
                                                  paths.zigzag(0.5, 1.2, units_per_meter=100.0))]
    model = StyleNetModel.create(params, config, (x_norm, y_norm))
    one = rollout(model, styles[0], states[0], controls[0])
    st = states[0]
    row0 = loop.steer(st.hist_xz[-1], tuple(r[0] for r in controls[0]))
    x0 = jnp.concatenate([loop.trajectory_input(st.hist_xz, st.hist_yaw, st.future, row0), st.joints])
    x_n = ((x0 - x_norm.mean) / x_norm.std)[None].astype(jnp.float32)
    at = style_models.model_apply(params, config, x_n, jnp.full((1, 1), f.global_phase[0]), styles[0])[0]
    away = style_models.model_apply(params, config, x_n, jnp.full((1, 1), f.global_phase[0] + 0.5), styles[0])[0]
    expect = np.asarray(at) * y_norm.std + y_norm.mean
    # the recorded bone positions are the blend with the moved-on bones (loop.JOINT_SMOOTH)
    jp, jv = g["joint_position"], g["joint_velocity"]
    expect[jp] = loop.JOINT_SMOOTH * expect[jp] + (1 - loop.JOINT_SMOOTH) * (
        np.asarray(st.joints)[:3 * num_bones] + expect[jv])
    np.testing.assert_allclose(np.asarray(one.outputs[0]), expect, rtol=1e-4, atol=1e-4 * np.abs(expect).max())
    assert np.abs(np.asarray(away - at)).max() > 1e-2  # the phase matters
    phi = np.concatenate([[float(st.global_phase)], np.asarray(one.global_phase)])
    assert np.all((phi >= 0) & (phi < 1))
    adv = np.mod(np.diff(phi), 1.0)
    omega = np.asarray(lpn_phases.predicted_advance(one.outputs, num_bones))
    np.testing.assert_allclose(adv, 0.8 * np.maximum(omega, 0.0), atol=1e-5)
    np.testing.assert_allclose(adv, 0.8 * 0.01, rtol=0.05)  # it advances at the ratio times the local advance
    stack = lambda items: jax.tree.map(lambda *v: jnp.stack([jnp.asarray(a) for a in v]), *items)  # noqa: E731
    many = rollout_batch(model, styles, stack(states), stack(controls))
    scale = np.abs(np.asarray(many.positions)).max()
    for c in (0, 2):
        single = one if c == 0 else rollout(model, styles[c], states[c], controls[c])
        np.testing.assert_allclose(np.asarray(many.positions[c, :5]), np.asarray(single.positions[:5]),
                                   atol=1e-5 * scale)
        np.testing.assert_allclose(np.asarray(many.positions[c]), np.asarray(single.positions), atol=2e-3 * scale)
        np.testing.assert_allclose(np.asarray(many.global_phase[c]), np.asarray(single.global_phase), atol=1e-3)
    # the live step (one frame, weights compiled in) makes the same first frame
    live = step_fn(model, styles[0])
    _, f0 = live(states[0], tuple(r[0] for r in controls[0]))
    np.testing.assert_allclose(float(f0.global_phase), float(one.global_phase[0]), atol=1e-6)


# --- a tiny trained model (slow: training and the data take ~40 s) ------------------------------

@pytest.fixture(scope="module")
def run_dir(mocap, tmp_path_factory):
    """RUN/lpn as ``jaxstyle lpn`` leaves it: a tiny PFNN FiLM (hidden 64, 8 epochs) trained on 20 s
    each of Neutral FW and ID (walking and idling)."""
    specs = [ClipSpec(str(mocap / f"100style/Neutral/Neutral_{g}.bvh"), "Neutral", 0, 1200, gait=g)
             for g in ("FW", "ID")]
    run = tmp_path_factory.mktemp("run")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        base = datasets.build_lpn_dataset(specs, cache_dir=run / "cache", skip_short=True)
    data = pipeline.LPNData(base, None, load_clip(specs[0]))
    config = pipeline.model_config(base, "PFNN FiLM", hidden=64, generator_hidden=32, filters=8)
    model = pipeline.train_model(data, config, run / "lpn", name="PFNN FiLM", epochs=8, progress=False,
                                 learning_rate=1e-3, dropout_rate=0.1)
    return run, model, data


@pytest.fixture(scope="module")
def loaded(run_dir):
    run, _, _ = run_dir
    return synthesis2022.load_model(run / "lpn", cache=run / "cache")


def _neutral(loaded):
    """What the trained-model tests share: the model, its rows, the Neutral character, the
    skeleton's units per metre, Neutral's rows, its own speed and the start row at that speed."""
    model, data = loaded.model, loaded.data
    ds = data.base
    (char,) = synthesis2022.characters(loaded, styles=["Neutral"])
    upm = estimate_units_per_meter(data.skeleton)
    rows = style_rows(ds, "Neutral")
    speed = StyleNetModel.own_speed(ds, rows, upm)
    return model, ds, char, upm, rows, speed, loop.start_row(ds.inputs, speed, units_per_meter=upm, rows=rows)


@pytest.mark.slow
def test_trained_pfnn_backbone_keeps_its_phase_near_the_data_rate(loaded):
    """Closed loop on a straight walk at the style's speed, the phase's rate fitted on the style's
    rows (:func:`lpn_phases.phase_ratio`): the global phase advances every frame at 0.5-1.5
    times the labelled walk's rate (a tiny model runs at ~0.6; the trained Table 2 PFNN FiLM of
    docs/mason2022.md at 0.8-1.05)."""
    model, ds, char, upm, rows, speed, row = _neutral(loaded)
    x_norm, y_norm = ds.normalisers()
    ratio = lpn_phases.phase_ratio(model.params, model.config, char.conditioning, (x_norm, y_norm), ds, rows)
    character = loaded.character_model()
    state = character.initial_state(ds, row, char.conditioning)
    assert float(state.phase_ratio) == pytest.approx(ratio, rel=1e-6)  # the character's start fits the same rate
    out = rollout(character, char.conditioning, state,
                  loop.signal_controls(paths.straight(4.0, speed, units_per_meter=upm)))
    phi = np.concatenate([[float(state.global_phase)], np.asarray(out.global_phase)])
    assert np.all((phi >= 0) & (phi < 1))
    adv = np.mod(np.diff(phi), 1.0)
    assert np.all(adv < 0.1)
    r = rows[np.lexsort((ds.frame[rows], ds.clip[rows]))]
    pair = (np.diff(ds.frame[r]) == 1) & (np.diff(ds.clip[r]) == 0)
    data_rate = np.mod(np.diff(ds.global_phase[r]), 1.0)[pair].mean()
    assert 0.5 * data_rate < adv.mean() < 1.5 * data_rate, (adv.mean(), data_rate)


@pytest.mark.slow
def test_stop_and_go_stops_within_half_a_second_and_walks_again(loaded):
    """The stop-and-go target with the 2022 controller: root speed below 0.1 m/s within 0.5 s of each
    stop command (the standing amount of the controls), walking again after it; without the
    standing amount the same model does not stop."""
    model, ds, char, upm, rows, speed, row = _neutral(loaded)
    character = loaded.character_model()
    state = character.initial_state(ds, row)
    sig = paths.stop_and_go(6.0, speed, units_per_meter=upm)
    full = loop.signal_controls(sig)
    out = rollout(character, char.conditioning, state, full)
    origin = np.asarray(out.origin)
    stops = metrics.stop_times(origin, sig.velocity, 60.0, units_per_meter=upm)
    assert len(stops) == 2 and np.all(stops <= 0.5), stops
    v = metrics.ground_speed(origin, 60.0, units_per_meter=upm)
    assert v[int(3.5 * 60):int(4.5 * 60)].mean() > 0.5 * speed  # it walks again
    free = rollout(character, char.conditioning, state, loop.Controls(*full[:4]))
    late = metrics.stop_times(np.asarray(free.origin), sig.velocity, 60.0, units_per_meter=upm)
    assert not np.all(late <= 0.5), late


@pytest.mark.slow
def test_reloaded_pfnn_model_synthesizes_through_the_library_and_the_cli(run_dir, loaded, tmp_path, capsys):
    run, model, _ = run_dir
    assert loaded.model.name == "PFNN FiLM" and loaded.model.config == model.config
    (char,) = synthesis2022.characters(loaded, styles=["Neutral"])
    out = synthesis.synthesize(loaded.character_model(), [char], loaded.data.skeleton, tmp_path,
                               synthesis.SynthesisOptions(path_names=("straight",), seconds=1.0, gif=False))
    assert out.frames == 60 and (tmp_path / "quality.csv").is_file()
    with np.load(tmp_path / "bvh" / "Neutral_straight.npz") as z:
        assert np.isfinite(z["positions"]).all()
    args = ["synthesize", "--model", "pfnn-film", "--run", str(run), "--paths", "straight", "--synth-seconds", "1",
            "--every", "30", "--quiet"]
    assert main(args) == 0
    assert "synthesis with PFNN FiLM (8 epochs" in capsys.readouterr().out
    assert (run / "synthesis" / "pfnn-film" / "straight.gif").is_file()
