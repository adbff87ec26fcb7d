"""The path-following law of the shared closed loop (:func:`jaxstyle.control.loop.steer`), on
synthetic kinematics: a unicycle and a point that track the future trajectory the loop hands
them, run through the same ``lax.scan`` (:func:`jaxstyle.control.loop.scan_frames`) as the
networks. The law must bring them onto the path and keep them there without oscillating; open
loop (no target) they keep any initial error."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxstyle.control import loop, paths

FPS = 60.0


class KinState(NamedTuple):
    hist_xz: jax.Array
    hist_yaw: jax.Array


def _start(offset_xz=(0.0, 0.0), yaw=0.0) -> KinState:
    xz = jnp.broadcast_to(jnp.asarray(offset_xz, jnp.float32), (loop.HISTORY, 2))
    return KinState(xz, jnp.full((loop.HISTORY,), yaw, jnp.float32))


def unicycle_step(max_speed: float, max_turn: float):
    """A unicycle that heads for its future trajectory sample 2 (1/3 s ahead) at the speed that
    reaches it in that time, with bounded speed (m/s) and turn rate (rad/s)."""

    def step(style, state, control):
        offsets = control[0]
        origin, yaw = state.hist_xz[-1], state.hist_yaw[-1]
        aim = offsets[2]
        want_yaw = jnp.arctan2(aim[0], aim[1])
        dist = jnp.linalg.norm(aim)
        turn = jnp.clip(jnp.angle(jnp.exp(1j * (want_yaw - yaw))), -max_turn / FPS, max_turn / FPS)
        new_yaw = jnp.where(dist > 1e-6, yaw + turn, yaw)
        speed = jnp.minimum(dist / (20 / FPS), max_speed)
        new = origin + speed / FPS * jnp.stack([jnp.sin(new_yaw), jnp.cos(new_yaw)])
        s = KinState(jnp.concatenate([state.hist_xz[1:], new[None]]), jnp.concatenate([state.hist_yaw[1:],
                                                                                        new_yaw[None]]))
        return s, new

    return step




def _point(style, state, control):
    offsets, yaw = control[0], control[1]
    new = state.hist_xz[-1] + offsets[1] / 10.0
    s = KinState(jnp.concatenate([state.hist_xz[1:], new[None]]), jnp.concatenate([state.hist_yaw[1:], yaw[:1]]))
    return s, new


def _run(step, signal, start, follow):
    # gain 1: these ideal trackers go where they are told (loop.FOLLOW_GAIN is for the networks)
    controls = loop.signal_controls(signal, follow_seconds=follow, follow_gain=1.0)
    return np.asarray(jax.jit(lambda s, c: loop.scan_frames(step, None, s, c))(start, controls))


def _errors(origins, signal):
    return np.linalg.norm(origins - signal.positions, axis=1)


def test_gains_grow_with_the_look_ahead_and_vanish_open_loop():
    g = loop.follow_gains(0.5)
    np.testing.assert_allclose(g, np.minimum(1.0, np.arange(6) / 6 / 0.5))
    assert g[0] == 0 and np.all(np.diff(g) >= 0) and g[-1] == 1.0
    np.testing.assert_array_equal(loop.follow_gains(None), 0.0)
    with pytest.raises(ValueError, match="follow_seconds"):
        loop.follow_gains(-1.0)


def test_the_follow_gain_scales_every_sample_and_must_be_finite():
    sig = paths.zigzag(2.0, 1.2, fps=FPS)
    one = loop.signal_controls(sig, follow_gain=1.0)
    four = loop.signal_controls(sig, follow_gain=4.0)
    np.testing.assert_allclose(np.asarray(four.gain), 4.0 * np.asarray(one.gain), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(one.gain[0]), loop.follow_gains(loop.FOLLOW_SECONDS), rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(loop.signal_controls(sig).gain), np.asarray(
        loop.signal_controls(sig, follow_gain=loop.FOLLOW_GAIN).gain))
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="follow_gain"):
            loop.signal_controls(sig, follow_gain=bad)


def test_steer_adds_the_position_error_with_the_gains():
    offsets = jnp.asarray(np.random.default_rng(0).normal(size=(6, 2)), jnp.float32)
    gain = jnp.asarray(loop.follow_gains(0.5), jnp.float32)
    target, origin = jnp.asarray([1.0, 2.0]), jnp.asarray([0.5, -1.0])
    got, _, stand = loop.steer(origin, (offsets, jnp.zeros(6), target, gain))
    assert float(stand) == 0.0
    want = np.asarray(offsets) + np.asarray(gain)[:, None] * np.array([0.5, 3.0])[None]
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-6)
    same = loop.steer(origin, (offsets, jnp.zeros(6)))[0]
    np.testing.assert_array_equal(np.asarray(same), np.asarray(offsets))


@pytest.mark.parametrize("name", ["straight", "circle", "zigzag"])
def test_point_model_reaches_the_path_from_one_metre_off(name):
    sig = paths.named(name, 8.0, 1.2, fps=FPS)
    out = _run(_point, sig, _start((1.0, 0.0)), 0.5)
    err = _errors(out, sig)
    assert err[-1] < 0.05, err[-1]
    assert err[int(2 * FPS)] < 0.15 * err[0]
    open_loop = _errors(_run(_point, sig, _start((1.0, 0.0)), None), sig)
    assert open_loop[-1] > 0.8  # without the law the initial error stays (less what the lag turns into)


@pytest.mark.parametrize("name", ["straight", "circle", "zigzag"])
def test_unicycle_reaches_the_path_without_oscillating(name):
    """From 1 m beside the path and facing 60 degrees off, with a 2 m/s top speed and 3 rad/s turn
    rate: after 3 s within 5 cm of the error of the same unicycle started on the path (its
    cornering error on the zigzag), no overshoot past the path by more than 10 cm, and the error
    falls (after the first second it never grows by more than 2 cm over its running maximum)."""
    sig = paths.named(name, 8.0, 1.2, fps=FPS)
    out = _run(unicycle_step(2.0, 3.0), sig, _start((1.0, 0.0), yaw=np.deg2rad(60)), 0.5)
    err = _errors(out, sig)
    on_path = _errors(_run(unicycle_step(2.0, 3.0), sig, _start(), 0.5), sig)
    assert err[-1] < 0.1, err[-1]
    late = slice(int(3 * FPS), None)
    assert np.all(err[late] <= on_path[late] + 0.05), (err[late] - on_path[late]).max()
    if name == "straight":  # signed lateral offset: it must not cross to the other side by much
        assert out[:, 0].min() > -0.1, out[:, 0].min()
    late = err[int(FPS):]
    assert np.all(late[1:] <= np.maximum.accumulate(late)[:-1] + 0.02)
    open_loop = _errors(_run(unicycle_step(2.0, 3.0), sig, _start((1.0, 0.0), yaw=np.deg2rad(60)), None), sig)
    assert open_loop[-1] > 0.5


def test_point_model_stops_when_the_path_stops():
    sig = paths.stop_and_go(6.0, 1.2, fps=FPS, go=2.0, stop=1.0)
    out = _run(_point, sig, _start(), 0.5)
    speed = np.linalg.norm(np.diff(out, axis=0), axis=1) * FPS
    stop = int(2 * FPS)
    # stopped 0.5 s after the command, until it anticipates the restart 1/6 s ahead
    assert speed[stop + int(0.5 * FPS):stop + int(0.8 * FPS)].max() < 0.1
    assert speed[int(3.5 * FPS):int(4.5 * FPS)].mean() > 1.0  # and starts again
    assert _errors(out, sig)[-1] < 0.05


def test_stand_amount_ramps_in_before_a_stop():
    v = np.zeros((100, 2))
    v[:50, 1] = 1.5
    stand = loop.stand_amount(v, 60.0)
    np.testing.assert_array_equal(stand[:41], 0.0)
    np.testing.assert_allclose(stand[41:51], np.arange(1, 11) / 10)  # frames t .. t + 9, counted ahead
    np.testing.assert_array_equal(stand[50:], 1.0)
    np.testing.assert_array_equal(loop.stand_amount(np.zeros((5, 2))), 1.0)


def test_live_step_follows_like_the_scan():
    sig = paths.circle(2.0, 1.2, 2.0, fps=FPS)
    controls = loop.signal_controls(sig, follow_gain=1.0)
    step = loop.live_step(_point, None)
    state, start = _start((0.5, 0.0)), _start((0.5, 0.0))
    got = []
    for t in range(len(sig.positions)):
        state, frame = step(state, jax.tree.map(lambda v, t=t: v[t], tuple(controls)))
        got.append(np.asarray(frame))
    np.testing.assert_allclose(np.stack(got), _run(_point, sig, start, loop.FOLLOW_SECONDS), atol=1e-5)
