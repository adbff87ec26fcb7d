"""Local motion phases: sinusoid fit, source functions, and whole clips."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.labels import local_phase as lp
from jaxstyle.labels import sinusoid

from .conftest import all_bvh
from .reference_sinusoid import fit_window


def _circ(a, b):
    d = np.mod(np.asarray(a) - np.asarray(b), 1.0)
    return np.minimum(d, 1.0 - d)


@pytest.mark.parametrize("fps", [30.0, 60.0, 120.0])
def test_synthetic_sinusoids_are_recovered(fps):
    rng = np.random.default_rng(int(fps))
    t = np.arange(int(6 * fps)) / fps
    params = [(rng.uniform(0.1, 3), f, rng.uniform(), rng.uniform(-2, 2)) for f in (0.5, 0.8, 1.3, 2.2, 3.1, 3.9)]
    signal = np.stack([a * np.sin(2 * np.pi * (f * t - s)) + b for a, f, s, b in params], -1)
    fit = sinusoid.fit_sinusoids(signal, fps)
    half = sinusoid.window_frames(fps) // 2
    whole = slice(half, len(t) - half)  # frames whose window lies inside the clip
    for i, (a, f, s, b) in enumerate(params):
        assert _circ(fit.phase[:, i], f * t - s).max() <= 0.01, (fps, f)  # clip ends included
        np.testing.assert_allclose(fit.frequency[whole, i], f, rtol=0.01)
        np.testing.assert_allclose(fit.amplitude[whole, i], a, rtol=0.01)
        np.testing.assert_allclose(fit.offset[whole, i], b, atol=0.01 * a)


def test_fit_of_a_constant_is_zero_amplitude_not_nan():
    fit = sinusoid.fit_sinusoids(np.full((90, 2), 3.0), 60.0)
    assert np.isfinite(fit.phase).all() and (fit.amplitude == 0).all() and (fit.phase == 0).all()
    np.testing.assert_allclose(fit.offset, 3.0, rtol=1e-6)


def test_fit_windows_vmaps_like_a_loop():
    rng = np.random.default_rng(1)
    tau_np = (np.arange(31) - 15) / 60.0
    f = rng.uniform(0.5, 4.0, size=(3, 40, 2, 1))
    s = rng.uniform(size=(3, 40, 2, 1))
    y = np.sin(2 * np.pi * (f * tau_np - s)) + 0.05 * rng.normal(size=(3, 40, 2, 31))
    y = jnp.asarray(y, jnp.float32)
    w = jnp.ones((40, 31))
    tau = jnp.asarray(tau_np, jnp.float32)
    freqs = jnp.linspace(0.25, 4.0, 64)
    batched = jax.vmap(lambda yy: sinusoid.fit_windows(yy, w, tau, freqs))(y)
    # float32 sums are ordered differently when batched, and the residual is flat near its
    # minimum, so the refined frequency may move by a few mHz: compare the fitted curves and
    # their residuals, which is what the fit is defined by.
    def curve(amp, freq, ph, off):
        return amp[..., None] * np.sin(2 * np.pi * (freq[..., None] * tau_np + ph[..., None])) + off[..., None]

    for i in range(3):
        single = curve(*map(np.asarray, sinusoid.fit_windows(y[i], w, tau, freqs)))
        both = curve(*(np.asarray(r[i]) for r in batched))
        assert np.abs(both - single).max() <= 0.01  # the noise is 0.05
        sse_single, sse_both = ((single - y[i]) ** 2).sum(-1), ((both - y[i]) ** 2).sum(-1)
        np.testing.assert_allclose(sse_both, sse_single, rtol=1e-3)


def test_short_clip_shorter_than_the_window():
    t = np.arange(12) / 60.0
    fit = sinusoid.fit_sinusoids(np.sin(2 * np.pi * 3.0 * t), 60.0)
    assert np.isfinite(fit.phase).all() and fit.phase.shape == (12,)


def test_fit_agrees_with_curve_fit_on_real_windows(mocap):
    """Where curve_fit's best fit (same bounds) is good (R^2 > 0.9, F and A inside their bounds) the phases
    agree within 0.01 cycles, and the vectorised fit is never meaningfully worse anywhere."""
    motion = js.read_bvh(mocap / "100style/Angry/Angry_FW.bvh")
    res = lp.local_phases(motion)
    rng = np.random.default_rng(0)
    tau = (np.arange(31) - 15) / 60.0
    checked = 0
    for t in rng.integers(600, 4800, 60):
        for b in range(4):  # hands (contact-free) and feet (contact-based)
            y = res.source[t - 15:t + 16, b]
            a, f, ph, _, sse = fit_window(tau, y, a_max=lp.MAX_AMPLITUDE)
            angle = 2 * np.pi * (res.frequency[t, b] * tau + res.phase[t, b])
            ours = res.amplitude[t, b] * np.sin(angle) + res.offset[t, b]
            ours_sse, total = np.sum((ours - y) ** 2), np.sum((y - y.mean()) ** 2)
            assert ours_sse - sse <= 1e-3 * total  # R^2 at most 0.001 below curve_fit's
            if 1 - sse / total > 0.9 and 0.3 < f < 3.9 and 0.1 < a < 0.99 * lp.MAX_AMPLITUDE:
                assert _circ(res.phase[t, b], ph) <= 0.01
                checked += 1
    assert checked >= 100


def test_window_normalise_matches_a_loop():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(50, 2)).cumsum(0)
    got = lp.window_normalise(x, fps=10.0)  # 10-frame window
    for t in range(50):
        idx = np.clip(np.arange(t - 5, t + 5), 0, 49)  # uniform_filter1d centring for even sizes
        win = x[idx]
        np.testing.assert_allclose(got[t], (x[t] - win.mean(0)) / win.std(0), rtol=1e-8)
    assert (lp.window_normalise(np.ones((30, 1)), 10.0) == 0).all()


def test_butterworth_is_zero_phase_low_pass():
    fps = 60.0
    t = np.arange(600) / fps
    slow, fast = np.sin(2 * np.pi * 1.0 * t), np.sin(2 * np.pi * 12.0 * t)
    out = lp.butterworth(np.stack([slow, fast], -1), fps)
    mid = slice(100, 500)
    np.testing.assert_allclose(out[mid, 0], slow[mid], atol=0.01)  # no lag, unit gain at 1 Hz
    assert np.abs(out[mid, 1]).max() < 0.15  # 12 Hz is 3 octaves above the cutoff
    np.testing.assert_array_equal(lp.butterworth(slow[:, None], 6.0), slow[:, None])  # cutoff above Nyquist


def test_principal_direction_points_forward():
    t = np.linspace(0, 4 * np.pi, 200)
    local = np.zeros((200, 2, 3))
    local[:, 0, 2] = np.sin(t)          # swings along Z
    local[:, 1, 2] = -0.5 * np.sin(t)   # in antiphase, same axis
    local[:, 1, 1] = 0.1 * np.sin(t)
    _, pc = lp.principal_direction(local)
    assert pc[0, 2] > 0.99 and pc[1, 2] > 0.9
    src = lp.contact_free_source(local)
    assert np.corrcoef(src[:, 0], src[:, 1])[0, 1] < -0.99  # antiphase stays visible


def test_phase_features_are_eq1():
    amp, ph, vel = np.array([[2.0]]), np.array([[0.125]]), np.array([[0.5]])
    np.testing.assert_allclose(lp.phase_features(amp, ph, vel)[0, 0], [np.sqrt(0.5), np.sqrt(0.5)])


def test_local_phases_of_a_walk(mocap):
    motion = js.read_bvh(mocap / "100style/Angry/Angry_FW.bvh")
    res = lp.local_phases(motion)
    assert res.bones == ("RightWrist", "LeftWrist", "RightAnkle", "LeftAnkle")
    assert res.sources == ("free", "free", "contact", "contact")
    assert res.features.shape == (motion.num_frames, 4, 2)
    walk = slice(700, 4300)  # Frame_Cuts: FW_START 569, FW_STOP 4407
    # walking: every bone cycles at about one stride per second, feet in antiphase
    assert 0.7 < np.median(res.frequency[walk]) < 1.5
    d = _circ(res.phase[walk, 2], res.phase[walk, 3])
    assert np.median(d) > 0.4
    assert 0.2 < res.contacts[walk].mean() < 0.6


def test_still_clip_has_zero_amplitude_and_constant_phase(mocap):
    motion = js.read_bvh(mocap / "100style/Neutral/Neutral_ID.bvh")
    still = motion.replace(rotations=np.repeat(motion.rotations[300:301], 200, 0),
                           local_positions=np.repeat(motion.local_positions[300:301], 200, 0))
    res = lp.local_phases(still)
    for arr in (res.phase, res.amplitude, res.features, res.velocity):
        assert np.isfinite(arr).all()
    assert (res.amplitude == 0).all() and np.ptp(res.phase) == 0 and (res.features == 0).all()


@pytest.mark.slow  # python -m pytest -m slow; the default run covers the same code more cheaply
def test_every_shared_clip_is_labelled(mocap):
    paths = [p for p in all_bvh(mocap) if p.parent.name != "pfnn_excerpt"]
    assert len(paths) > 60
    for path in paths:
        motion = js.read_bvh(path)
        res = lp.local_phases(motion)
        assert np.isfinite(res.features).all(), path
        assert ((res.phase >= 0) & (res.phase < 1)).all(), path


def test_foot_sources_and_errors(mocap):
    motion = js.read_bvh(mocap / "100style/Angry/Angry_FW.bvh").frames(600, 1200)
    free = lp.local_phases(motion, lp.LocalPhaseConfig(foot_source="free"))
    assert free.sources == ("free",) * 4
    mixed = lp.local_phases(motion, lp.LocalPhaseConfig(sources={"LeftAnkle": "free"}))
    assert mixed.sources == ("free", "free", "contact", "free")
    auto = lp.local_phases(motion, lp.LocalPhaseConfig(foot_source="auto"))
    assert auto.sources[2:] == ("contact", "contact")  # a walk: both feet touch down
    with pytest.raises(ValueError, match="foot_source"):
        lp.local_phases(motion, lp.LocalPhaseConfig(foot_source="hop"))
    with pytest.raises(ValueError, match="no contact source"):
        lp.local_phases(motion, lp.LocalPhaseConfig(sources={"RightWrist": "contact"}))
    with pytest.raises(js.MotionDataError, match="unknown joint"):
        lp.local_phases(motion, lp.LocalPhaseConfig(bones=["RightWrist", "Tail"]))


def test_auto_uses_contact_free_source_for_a_lifted_foot(mocap):
    motion = js.read_bvh(mocap / "100style/Angry/Angry_FW.bvh").frames(600, 1800)
    rot = motion.rotations.copy()
    knee = motion.joint_index("LeftKnee")
    # bend the left knee 90 degrees all along: the left foot never touches down (a hop on the right)
    rot[:, knee] = js.motion.quat.mul(rot[:, knee], js.motion.quat.from_axis_angle(np.array([1.0, 0, 0]), np.pi / 2))
    hop = motion.replace(rotations=rot)
    res = lp.local_phases(hop, lp.LocalPhaseConfig(foot_source="auto"))
    assert res.sources[2:] == ("contact", "free")


def test_figure_script_writes_a_png(mocap, tmp_path):
    from experiments.plot_local_phases import Config, run

    out = run(Config(clip="100style/Neutral/Neutral_FW.bvh", start=300, seconds=2.0, out=tmp_path / "f.png"))
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000
