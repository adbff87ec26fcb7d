"""The closed-loop PFNN controller: its inputs and root updates agree with the feature encoder."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.control import controller, loop
from jaxstyle.control.controller import PFNNModel
from jaxstyle.control.model import rollout
from jaxstyle.data.clips import ClipSpec
from jaxstyle.data.datasets import load_clip
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.motion import kinematics
from jaxstyle.motion.character_frame import CharacterFrames, rotate_yaw, to_local
from jaxstyle.nn import pfnn
from jaxstyle.output import metrics


def test_path_controls_of_a_straight_walk():
    fps, speed = 60.0, 1.5
    c = loop.turning_path(100, speed, 0.0, fps, start_yaw=np.pi / 2)  # walk along +X
    offsets = np.asarray(c.offsets)
    want = speed * 10 * np.arange(6) / fps
    np.testing.assert_allclose(offsets[:, :, 0], np.broadcast_to(want, (100, 6)), atol=1e-5)
    np.testing.assert_allclose(offsets[:, :, 1], 0.0, atol=1e-5)
    np.testing.assert_allclose(np.asarray(c.yaw), np.pi / 2, atol=1e-6)
    with pytest.raises(ValueError, match="finite"):
        loop.path_controls(np.full((5, 2), np.nan), np.zeros(5))


def test_turning_path_integrates_an_arc():
    fps, speed, rate = 60.0, 1.2, np.deg2rad(45)
    c = loop.turning_path(200, speed, rate, fps)
    # offset 50 frames ahead of frame 0 on a circle of radius speed / rate (first-order integration)
    t = 50 / fps
    r = speed / rate
    want = np.array([r * (1 - np.cos(rate * t)), r * np.sin(rate * t)])
    np.testing.assert_allclose(np.asarray(c.offsets[0, 5]), want, rtol=0.02)


@pytest.fixture(scope="module")
def clip(mocap):
    m = load_clip(ClipSpec(str(mocap / "100style/Drunk/Drunk_SW.bvh"), "Drunk", 0, 900), fps=60.0)
    phase = js.global_phase(m)
    x, y, t = js.encode_pfnn(m, phase)
    return m, phase, x, y, t


def test_teacher_forced_loop_reproduces_the_encoded_inputs(clip):
    """Fed the real outputs, the loop must rebuild the real inputs (once its 60-frame history is
    real) and the real global joint positions: the controller and encoder agree exactly."""
    m, phase, x, y, t = clip
    frames = js.character_frames(m)
    t0, n = t[0], 100
    idx = t[:n][:, None] + 10 * np.arange(6)[None]
    disp = rotate_yaw(frames.origin[idx] - frames.origin[t[:n]][:, None], np.full(idx.shape, -frames.yaw[t0]))
    controls = loop.Controls(jnp.asarray(disp[..., [0, 2]], jnp.float32),
                                   jnp.asarray(frames.yaw[idx] - frames.yaw[t0], jnp.float32))
    state = controller.initial_state(x[0], phase[t0], m.num_joints)
    start = CharacterFrames(frames.origin[[t0]], frames.yaw[[t0]])
    g_pos = kinematics.global_positions(m)
    for i in range(n):
        built = np.asarray(controller.assemble_input(state, (controls.offsets[i], controls.yaw[i])))
        if i >= loop.HISTORY - 1:
            np.testing.assert_allclose(built, x[i], atol=1e-3 * np.abs(x[i]).max())
        else:  # before that the history is interpolated between the 10-frame samples
            np.testing.assert_allclose(built[24:], x[i][24:], atol=1e-3 * np.abs(x[i]).max())  # all but past x/z
        state, frame = controller.advance(state, jnp.asarray(y[i], jnp.float32), m.num_joints)
        real = to_local(g_pos[t[i] + 1][None], start, np.array([0]))[0]
        np.testing.assert_allclose(np.asarray(frame.positions), real, atol=1e-3 * np.abs(real).max())


def test_carried_joints_are_the_pfnn_demos_blend_in_world_space(clip):
    """The carried joints (controller module docstring): in world space, ``s`` times the predicted
    positions plus ``1 - s`` times the previous positions moved on by the predicted velocities
    (the PFNN demo's ``mix(p + v, P, s)``), recomputed here with numpy from the world transforms
    of the two character frames; ``s = 1`` is the raw prediction; standing still blends too."""
    m, phase, x, y, t = clip
    rng = np.random.default_rng(0)
    J = m.num_joints
    g = PFNNLayout(J).output_groups
    state = controller.initial_state(x[5], phase[t[5]], J)
    state = state._replace(hist_xz=state.hist_xz + jnp.asarray([3.0, -2.0]), hist_yaw=state.hist_yaw + 0.7)
    out = np.array(y[5], dtype=np.float64)
    out[:3] = [4.0, 9.0, 0.3]  # a step and a visible turn
    out[g["joint_velocity"]] += rng.normal(scale=2.0, size=3 * J)  # velocities that disagree with the positions

    def world(points_Jx3, origin, yaw):
        return rotate_yaw(points_Jx3, np.full(len(points_Jx3), yaw)) + np.array([origin[0], 0.0, origin[1]])

    for s, stand in ((0.5, 0.0), (0.3, 0.0), (1.0, 0.0), (0.5, 0.6)):
        new, frame = controller.advance(state, jnp.asarray(out, jnp.float32), J, stand, s)
        o0, a0 = np.asarray(state.hist_xz[-1], np.float64), float(state.hist_yaw[-1])
        o1, a1 = np.asarray(new.hist_xz[-1], np.float64), float(new.hist_yaw[-1])
        prev = world(np.asarray(state.joint_pos, np.float64).reshape(J, 3), o0, a0)
        pred = world(out[g["joint_position"]].reshape(J, 3), o1, a1)
        vel = rotate_yaw(out[g["joint_velocity"]].reshape(J, 3), np.full(J, a1))
        want = s * pred + (1 - s) * (prev + vel)
        np.testing.assert_allclose(np.asarray(frame.positions), want, atol=1e-3 * np.abs(want).max())
        # the carried state and the recorded outputs hold the same blended joints, in C_{t+1}
        np.testing.assert_allclose(np.asarray(new.joint_pos), np.asarray(frame.outputs)[g["joint_position"]])
        local = rotate_yaw(want - np.array([o1[0], 0.0, o1[1]]), np.full(J, -a1))
        np.testing.assert_allclose(np.asarray(new.joint_pos).reshape(J, 3), local, atol=1e-3 * np.abs(local).max())


@pytest.mark.slow  # python -m pytest -m slow; the default run covers the same code more cheaply
def test_rollout_vmaps_over_adapters_and_is_finite(clip):
    m, phase, x, y, t = clip
    config = pfnn.PFNNConfig(input_size=x.shape[1], hidden_size=32, output_size=y.shape[1], rank=4)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
    adapters = jax.vmap(lambda k: pfnn.init_adapter(k, config))(jax.random.split(jax.random.PRNGKey(1), 3))
    x_norm = Normaliser(x.mean(0), x.std(0) + 1e-3)
    y_norm = Normaliser(y.mean(0), y.std(0) + 1e-3)
    state = controller.initial_state(x[0], phase[t[0]], m.num_joints)
    path = loop.turning_path(40, 100.0, np.deg2rad(30))
    model = PFNNModel.create(params, (x_norm, y_norm), m.num_joints)
    many = jax.vmap(lambda a: rollout(model, a, state, path))(adapters)
    assert many.positions.shape == (3, 40, m.num_joints, 3)
    assert np.isfinite(np.asarray(many.positions)).all()
    for k in (0, 2):
        one = rollout(model, jax.tree.map(lambda v, k=k: v[k], adapters), state, path)
        np.testing.assert_allclose(np.asarray(many.positions[k]), np.asarray(one.positions), rtol=1e-4, atol=1e-2)
    # the recorded outputs decode (numpy decode_pfnn, the reference) to the same root path
    decoded, _ = js.decode_pfnn(np.asarray(one.outputs), m)
    np.testing.assert_allclose(np.asarray(one.positions)[:, 0], kinematics.global_positions(decoded)[:, 0],
                               atol=1e-2 * np.abs(np.asarray(one.positions)).max())


def test_a_zero_adapter_drives_like_the_base_alone(clip):
    """The closed-loop check's column of the base (:func:`jaxstyle.mason2018.selection.check_rollouts`)
    is a zero adapter stacked with the fine-tuned ones: its residual is exactly zero, so its rollout
    is the base's without an adapter."""
    m, phase, x, y, t = clip
    config = pfnn.PFNNConfig(input_size=x.shape[1], hidden_size=32, output_size=y.shape[1], rank=4)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
    adapter = pfnn.init_adapter(jax.random.PRNGKey(1), config)
    model = PFNNModel.create(params, (Normaliser(x.mean(0), x.std(0) + 1e-3), Normaliser(y.mean(0), y.std(0) + 1e-3)),
                             m.num_joints)
    state = controller.initial_state(x[0], phase[t[0]], m.num_joints)
    path = loop.turning_path(30, 100.0, np.deg2rad(30))
    base = rollout(model, None, state, path)
    zero = rollout(model, jax.tree.map(jnp.zeros_like, adapter), state, path)
    np.testing.assert_array_equal(np.asarray(zero.positions), np.asarray(base.positions))
    moved = rollout(model, adapter, state, path)  # a random adapter changes the motion
    assert np.abs(np.asarray(moved.positions) - np.asarray(base.positions)).max() > 1e-3


def test_real_motion_metrics_are_plausible(clip):
    m, phase, x, y, t = clip
    g_pos = kinematics.global_positions(m)
    err = metrics.bone_length_errors(g_pos, m)
    assert err.max() < 1e-6  # forward kinematics keeps bone lengths exactly
    stretched = g_pos.copy()
    stretched[:, 1:] *= 1.2
    assert metrics.bone_length_errors(stretched, m).mean() > 0.01
    upm = js.estimate_units_per_meter(m)
    real, floor = metrics.reference_foot_stats(y, m, 60.0, units_per_meter=upm)
    assert real.contact_fraction > 0.9 and real.skating < 0.3
    same = metrics.positions_foot_stats(g_pos[t[0] + 1:t[-1] + 2], m, 60.0, floor, units_per_meter=upm)
    assert abs(same.contact_fraction - real.contact_fraction) < 0.02
    assert abs(same.skating - real.skating) < 0.02
    # a character gliding forward at 1 m/s with the same poses skates at about 1 m/s more
    glide = g_pos.copy()
    glide[:, :, 2] += upm * np.arange(len(g_pos))[:, None] / 60.0
    slid = metrics.positions_foot_stats(glide, m, 60.0, floor, units_per_meter=upm)
    assert slid.skating > real.skating + 0.5


@pytest.fixture(scope="module")
def tiny_walker(mocap):
    """A tiny PFNN (hidden 64, rank 4, contact outputs) trained briefly on Neutral walking and
    idling: 20 s each of FW and ID."""
    import warnings

    from jaxstyle.data import datasets
    from jaxstyle.mason2018.train import TrainConfig, data_from_dataset, train, with_contacts

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        specs = [ClipSpec(str(mocap / f"100style/Neutral/Neutral_{g}.bvh"), "Neutral", 0, 1200) for g in ("FW", "ID")]
        dataset = with_contacts(datasets.build_pfnn_dataset(specs, skip_short=True))
    num_joints = (dataset.inputs.shape[1] - 48) // 6
    layout = js.PFNNLayout(num_joints, contacts=True)
    assert dataset.outputs.shape[1] == layout.output_size
    model = pfnn.PFNNConfig(input_size=layout.input_size, hidden_size=64, output_size=layout.output_size, rank=4)
    state = train(data_from_dataset(dataset), TrainConfig(model=model, epochs=6, dropout_rate=0.1), None,
                  progress=False)
    return state.params, dataset, load_clip(specs[0], fps=60.0)


def test_stop_and_go_stops_and_starts_again(tiny_walker):
    """A trained tiny model on stop_and_go (2 s walk, 1 s stand): root speed below 0.1 m/s within
    0.5 s of each stop command, walking again after it, and near the path at the end."""
    from jaxstyle.control import paths

    params, dataset, skeleton = tiny_walker
    upm = js.estimate_units_per_meter(skeleton)
    speed = 1.0
    sig = paths.stop_and_go(6.0, speed, units_per_meter=upm)
    row = loop.start_row(dataset.inputs, speed, units_per_meter=upm)
    state = controller.initial_state(dataset.inputs[row], float(dataset.phases[row, 0]), skeleton.num_joints)
    model = PFNNModel.create(params, dataset.normalisers(), skeleton.num_joints)
    out = rollout(model, None, state, loop.signal_controls(sig))
    origin = np.asarray(out.origin)
    assert np.isfinite(origin).all()
    stops = metrics.stop_times(origin, sig.velocity, 60.0, units_per_meter=upm)
    assert len(stops) == 2 and np.all(stops <= 0.5), stops
    speed_t = metrics.ground_speed(origin, 60.0, units_per_meter=upm)
    assert speed_t[int(3.5 * 60):int(4.5 * 60)].mean() > 0.5 * speed  # it walks again
    # the benchmark's measures of the same rollout: the exported skeleton follows the same root path
    # (the applied root motion is what the outputs record) with exact bones, and the IK uses the
    # network's own heel and toe contacts
    from jaxstyle.output import measure

    assert js.data.pfnn_features.output_contacts(np.asarray(out.outputs), skeleton.num_joints).shape == (360, 4)
    row = measure.measure(jax.tree.map(np.asarray, out), skeleton, sig, units_per_meter=upm)
    assert row["bone_error_bvh_max"] < 1e-9 and row["stop_time_s"] <= 0.5
    decoded_root = js.global_positions(js.decode_pfnn(np.asarray(out.outputs), skeleton)[0])[:, 0, [0, 2]]
    np.testing.assert_allclose(decoded_root, np.asarray(out.positions)[:, 0, [0, 2]], atol=0.05 * upm)
    # open loop (no stand amount, no following) the same model does not stop within 0.5 s
    open_loop = rollout(model, None, state,
                        loop.Controls(*loop.signal_controls(sig, follow_seconds=None)[:2]))
    late = metrics.stop_times(np.asarray(open_loop.origin), sig.velocity, 60.0, units_per_meter=upm)
    assert not np.all(late <= 0.5), late
