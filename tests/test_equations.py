"""The papers' equations as named functions (docs/equations.md), each against an independent NumPy
reference written here from the paper's formula, plus identities between them.

Every check is a helper that the correct function passes; the ``*_rejects_*`` tests show each
helper fails on a plausible wrong formula, so the checks can fail. The last tests show the network
code calls these functions (replacing one changes the networks' outputs).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxstyle.nn import lpn, pfnn, style_models

RNG = np.random.default_rng(2018)
B, H, R, OUT = 5, 6, 3, 4
TOL = dict(rtol=1e-5, atol=1e-5)


# --- NumPy references, from the papers' formulas ------------------------------------------------

def np_catmull_rom(alphas_4x, phase_cycles):
    """Mason et al. 2018, Eq. 1a-1c as printed (phase ``p`` in radians), one phase at a time."""
    out = []
    for cycles in np.atleast_1d(phase_cycles):
        p = 2.0 * np.pi * float(cycles)
        d = (4.0 * p / (2.0 * np.pi)) % 1.0                                             # Eq. 1b
        k = [(int(np.floor(4.0 * p / (2.0 * np.pi))) + n - 1) % 4 for n in range(4)]   # Eq. 1c
        a0, a1, a2, a3 = (alphas_4x[i] for i in k)
        out.append(a1 + d * (0.5 * a2 - 0.5 * a0)                                       # Eq. 1a
                   + d ** 2 * (a0 - 2.5 * a1 + 2.0 * a2 - 0.5 * a3)
                   + d ** 3 * (1.5 * a1 - 1.5 * a2 + 0.5 * a3 - 0.5 * a0))
    return np.array(out)


def np_weights(phase_cycles):
    """``(B, 4)`` control-point weights: Eq. 1a applied to the unit control points."""
    return np_catmull_rom(np.eye(4), phase_cycles)


def np_layer_norm(f, eps):
    f = np.asarray(f, np.float64)
    mu = f.sum(-1, keepdims=True) / f.shape[-1]
    sigma = np.sqrt(((f - mu) ** 2).sum(-1, keepdims=True) / f.shape[-1] + eps)
    return (f - mu) / sigma


def f64(x):
    return np.asarray(x, np.float64)


# --- checks (each returns normally for a correct function, raises AssertionError otherwise) -----

PHASES = np.concatenate([RNG.uniform(s / 4, (s + 1) / 4, 25) for s in range(4)] + [[0.0, 0.25, 0.5, 0.75, 0.999]])


def check_weights(weights_fn):
    np.testing.assert_allclose(weights_fn(PHASES), np_weights(PHASES), **TOL)
    np.testing.assert_allclose(weights_fn(PHASES + 3.0), np_weights(PHASES), **TOL)     # periodic
    np.testing.assert_allclose(weights_fn(PHASES - 1.0), np_weights(PHASES), **TOL)


def check_cp(cp_fn):
    h, a, d, b_, bias = (RNG.normal(size=s) for s in ((B, H), (R, H), (B, R), (H, R), (H,)))
    want = np.stack([b_ @ np.diag(d[i]) @ a @ h[i] + bias for i in range(B)])  # B diag(d) A h + b
    got = cp_fn(*(jnp.asarray(v, jnp.float32) for v in (h, a, d, b_, bias)))
    np.testing.assert_allclose(got, want, **TOL)


def check_diag(diag_fn):
    h, d, b = (RNG.normal(size=(B, H)) for _ in range(3))
    want = np.stack([np.diag(d[i]) @ h[i] + b[i] for i in range(B)])
    np.testing.assert_allclose(diag_fn(*(jnp.asarray(v, jnp.float32) for v in (h, d, b))), want, **TOL)


def check_full(full_fn):
    h, w, b = RNG.normal(size=(B, H)), RNG.normal(size=(H, OUT)), RNG.normal(size=(OUT,))
    want = np.stack([w.T @ h[i] + b for i in range(B)])  # the paper's W h + b, W = w.T (O x H)
    np.testing.assert_allclose(full_fn(*(jnp.asarray(v, jnp.float32) for v in (h, w, b))), want, **TOL)


def check_film(film_fn):
    h, g, b = (RNG.normal(size=(B, H)) for _ in range(3))
    want = np.stack([np.diag(g[i]) @ h[i] + b[i] for i in range(B)])
    np.testing.assert_allclose(film_fn(*(jnp.asarray(v, jnp.float32) for v in (h, g, b))), want, **TOL)
    g1, b1 = RNG.normal(size=H), RNG.normal(size=H)  # one (H,) vector shared by the batch
    np.testing.assert_allclose(film_fn(jnp.asarray(h, jnp.float32), jnp.asarray(g1, jnp.float32),
                                       jnp.asarray(b1, jnp.float32)), h * g1 + b1, **TOL)


def check_layer_norm(ln_fn):
    f = RNG.normal(loc=3.0, scale=2.5, size=(B, 16))
    np.testing.assert_allclose(ln_fn(jnp.asarray(f, jnp.float32)), np_layer_norm(f, lpn.LAYER_NORM_EPS), **TOL)
    tiny = np.full((1, 16), 7.0)  # no variation: (F - mu) / sqrt(eps) = 0, not NaN
    np.testing.assert_allclose(ln_fn(jnp.asarray(tiny, jnp.float32)), np.zeros((1, 16)), atol=1e-6)


# --- Mason et al. 2018, Eq. 1a-1c: the Catmull-Rom phase function ------------------------------

def test_catmull_rom_weights_match_eq_1a_1c():
    check_weights(pfnn.catmull_rom_weights)


def test_catmull_rom_weights_sum_to_one_and_interpolate_the_knots():
    w = np.asarray(pfnn.catmull_rom_weights(PHASES))
    assert w.shape == (len(PHASES), 4)
    np.testing.assert_allclose(w.sum(-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(pfnn.catmull_rom_weights(np.arange(4) / 4), np.eye(4), atol=1e-7)
    points = RNG.normal(size=(4, 7))  # the blended spline passes through control point k at p = k / 4
    knots = pfnn.catmull_rom_weights(np.arange(4) / 4)
    np.testing.assert_allclose(pfnn.blend(jnp.asarray(points, jnp.float32), knots), points, atol=1e-6)


def test_catmull_rom_weights_are_c1_at_the_knots():
    """The derivative in ``p`` (exact, by forward-mode differentiation) is the same on both sides of
    each knot and is Catmull-Rom's tangent ``(P[k+1] - P[k-1]) / 2`` per unit of ``mu = 4 p``."""
    slope = jax.vmap(jax.jacfwd(lambda p: pfnn.catmull_rom_weights(p[None])[0]))
    for k in range(4):
        left, right = np.asarray(slope(jnp.asarray([k / 4 - 1e-6, k / 4], jnp.float32)))
        tangent = np.zeros(4)
        tangent[(k + 1) % 4], tangent[(k - 1) % 4] = 2.0, -2.0
        np.testing.assert_allclose(left, tangent, atol=1e-3)
        np.testing.assert_allclose(right, tangent, atol=1e-3)


def test_weights_check_rejects_a_cubic_b_spline():
    def b_spline(phase):  # uniform cubic B-spline: smooth, sums to 1, but does not interpolate
        t = 4.0 * np.mod(np.asarray(phase, np.float64), 1.0)
        k, mu = np.floor(t).astype(int), t - np.floor(t)
        coef = np.stack([(1 - mu) ** 3, 3 * mu ** 3 - 6 * mu ** 2 + 4, -3 * mu ** 3 + 3 * mu ** 2 + 3 * mu + 1,
                         mu ** 3], -1) / 6.0
        out = np.zeros(coef.shape)
        for j, off in enumerate(range(-1, 3)):
            np.add.at(out, (np.arange(len(k)), (k + off) % 4), coef[:, j])
        return out

    np.testing.assert_allclose(b_spline(PHASES).sum(-1), 1.0)
    with pytest.raises(AssertionError):
        check_weights(b_spline)


# --- Mason et al. 2018, Eq. 4: full and diagonal residual adapters -----------------------------

def test_full_residual_is_w_h_plus_b():
    check_full(pfnn.full_residual)


def test_diag_residual_is_diag_d_h_plus_b():
    check_diag(pfnn.diag_residual)


def test_full_residual_of_a_diagonal_matrix_is_the_diag_residual():
    h, d, b = RNG.normal(size=(B, H)), RNG.normal(size=H), RNG.normal(size=H)
    h, d, b = (jnp.asarray(v, jnp.float32) for v in (h, d, b))
    np.testing.assert_allclose(pfnn.full_residual(h, jnp.diag(d), b), pfnn.diag_residual(h, d, b), **TOL)


def test_phase_functioned_full_adapter_of_diagonal_control_points_is_the_diagonal_adapter():
    """Through :func:`pfnn.apply_adapter` (full: output blend of the control points, never a matrix
    per sample) and the Eq. 1a weights, against NumPy's per-sample ``diag(d(p)) h + b(p)``."""
    d4, b4 = RNG.normal(size=(4, H)), RNG.normal(size=(4, H))
    h, phase = RNG.normal(size=(B, H)), RNG.uniform(size=B)
    w = pfnn.catmull_rom_weights(jnp.asarray(phase, jnp.float32))
    full = {"W": jnp.asarray(np.stack([np.diag(v) for v in d4]), jnp.float32), "b": jnp.asarray(b4, jnp.float32)}
    diag = {"d": jnp.asarray(d4, jnp.float32), "b": jnp.asarray(b4, jnp.float32)}
    dp, bp = np_catmull_rom(d4, phase), np_catmull_rom(b4, phase)
    want = np.stack([np.diag(dp[i]) @ h[i] + bp[i] for i in range(B)])
    hj = jnp.asarray(h, jnp.float32)
    np.testing.assert_allclose(pfnn.apply_adapter(full, hj, w), want, **TOL)
    np.testing.assert_allclose(pfnn.apply_adapter(diag, hj, w), want, **TOL)


def test_residual_checks_reject_wrong_formulas():
    with pytest.raises(AssertionError):
        check_full(lambda h, w, b: h @ w)  # bias forgotten
    with pytest.raises(AssertionError):
        check_diag(lambda h, d, b: d * (h + b))  # bias inside the scaling


# --- Mason et al. 2018, Eq. 6: the CP-factored adapter -----------------------------------------

def test_cp_residual_is_b_diag_d_a_h_plus_b():
    check_cp(pfnn.cp_residual)


def test_cp_residual_with_identity_factors_is_the_diag_residual():
    h, d, b = (jnp.asarray(RNG.normal(size=s), jnp.float32) for s in ((B, H), (B, H), (H,)))
    eye = jnp.eye(H)
    np.testing.assert_allclose(pfnn.cp_residual(h, eye, d, eye, b), pfnn.diag_residual(h, d, b), **TOL)


def test_cp_residual_is_the_full_residual_of_its_eq_6_slice():
    """``X_k = A D^(k) B^T`` (paper's names): the full adapter of the slice at each phase bin."""
    a, b_, bias = RNG.normal(size=(R, H)), RNG.normal(size=(H, R)), RNG.normal(size=H)
    d4, h = RNG.normal(size=(4, R)), RNG.normal(size=(B, H))
    adapter = {k: jnp.asarray(v, jnp.float32) for k, v in dict(A=a, d=d4, B=b_, b=bias).items()}
    table = pfnn.discretise(adapter, num_bins=8)
    for k in range(8):
        x_k = b_ @ np.diag(np.asarray(table["d"][k], np.float64)) @ a  # (H_out, H_in), the paper's W_res
        want = np.asarray(pfnn.full_residual(jnp.asarray(h, jnp.float32), jnp.asarray(x_k.T, jnp.float32),
                                             jnp.asarray(bias, jnp.float32)))
        got = pfnn.cp_residual(jnp.asarray(h, jnp.float32), table["A"], table["d"][k], table["B"], table["b"])
        np.testing.assert_allclose(got, want, **TOL)


def test_cp_adapter_at_per_sample_phases_matches_numpy():
    a, b_, bias = RNG.normal(size=(R, H)), RNG.normal(size=(H, R)), RNG.normal(size=H)
    d4, h, phase = RNG.normal(size=(4, R)), RNG.normal(size=(B, H)), RNG.uniform(size=B)
    adapter = {k: jnp.asarray(v, jnp.float32) for k, v in dict(A=a, d=d4, B=b_, b=bias).items()}
    dp = np_catmull_rom(d4, phase)
    want = np.stack([b_ @ np.diag(dp[i]) @ a @ h[i] + bias for i in range(B)])
    got = pfnn.apply_adapter(adapter, jnp.asarray(h, jnp.float32), pfnn.catmull_rom_weights(phase))
    np.testing.assert_allclose(got, want, **TOL)


def test_cp_check_rejects_wrong_formulas():
    with pytest.raises(AssertionError):
        check_cp(lambda h, a, d, b_, bias: (h @ a.T) @ b_.T + bias)  # core d ignored
    with pytest.raises(AssertionError):
        check_cp(lambda h, a, d, b_, bias: (d * (h @ a.T)) @ b_.T)  # bias forgotten


# --- Mason, Starke & Komura 2022, Eq. 3 (and Eq. 8): LayerNorm and FiLM -------------------------

def test_layer_norm_is_the_eq_3_normalisation():
    check_layer_norm(lpn.layer_norm)
    out = np.asarray(lpn.layer_norm(jnp.asarray(RNG.normal(loc=-2.0, scale=4.0, size=(B, 64)), jnp.float32)))
    np.testing.assert_allclose(out.mean(-1), 0.0, atol=1e-5)
    np.testing.assert_allclose(out.std(-1), 1.0, atol=1e-4)


def test_film_is_gamma_h_plus_beta():
    check_film(lpn.film)
    h = jnp.asarray(RNG.normal(size=(B, H)), jnp.float32)
    np.testing.assert_allclose(lpn.film(h, jnp.ones(H), jnp.zeros(H)), h)  # identity FiLM


def test_film_of_a_dense_layer_is_a_new_dense_layer_eq_8():
    """2022, Eq. 8: ``diag(gamma) (W h + b) + beta = W' h + b'`` with ``W' = diag(gamma) W`` and
    ``b' = diag(gamma) b + beta`` (in jaxstyle's row-vector layout ``W' = W diag(gamma)``)."""
    h, w, b = RNG.normal(size=(B, H)), RNG.normal(size=(H, OUT)), RNG.normal(size=OUT)
    g, beta = RNG.normal(size=OUT), RNG.normal(size=OUT)
    j = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    lhs = lpn.film(pfnn.full_residual(j(h), j(w), j(b)), j(g), j(beta))
    rhs = pfnn.full_residual(j(h), j(w * g[None]), j(g * b + beta))
    np.testing.assert_allclose(lhs, rhs, **TOL)


def test_eq_3_hidden_layer_matches_numpy():
    """``h = ELU(gamma o (F - mu) / sigma + beta)`` composed from the two functions."""
    f, g, beta = RNG.normal(size=(B, 16)), RNG.normal(size=16), RNG.normal(size=16)
    want = g * np_layer_norm(f, lpn.LAYER_NORM_EPS) + beta
    want = np.where(want > 0, want, np.expm1(np.minimum(want, 0)))
    j = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    np.testing.assert_allclose(jax.nn.elu(lpn.film(lpn.layer_norm(j(f)), j(g), j(beta))), want, **TOL)


def test_film_and_layer_norm_checks_reject_wrong_formulas():
    with pytest.raises(AssertionError):
        check_film(lambda h, g, b: (1.0 + g) * h + b)  # the "1 + gamma" FiLM variant, not the authors'
    with pytest.raises(AssertionError):
        check_layer_norm(lambda f: f - jnp.mean(f, axis=-1, keepdims=True))  # centred, not scaled
    with pytest.raises(AssertionError):
        check_layer_norm(lambda f: (f - jnp.mean(f, axis=0)) / jnp.std(f, axis=0))  # over the batch (BatchNorm)


# --- the networks call these functions ----------------------------------------------------------

def _small_pfnn():
    config = pfnn.PFNNConfig(input_size=5, hidden_size=H, output_size=OUT, rank=R)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
    x = jnp.asarray(RNG.normal(size=(B, 5)), jnp.float32)
    return config, params, x


@pytest.mark.parametrize("kind, name", [("cp", "cp_residual"), ("diagonal", "diag_residual"),
                                        ("full", "full_residual")])
def test_the_pfnn_runtime_table_calls_the_residual_functions(monkeypatch, kind, name):
    config, params, x = _small_pfnn()
    adapter = pfnn.init_adapter(jax.random.PRNGKey(1), pfnn.PFNNConfig(5, H, OUT, adapter=kind, rank=R))
    table, adapter_table = pfnn.discretise(params), pfnn.discretise(adapter)
    centre = 15.5 / 50  # a bin centre: the table equals the continuous network there
    before = np.asarray(pfnn.pfnn_apply_table(table, x, centre, adapter_table=adapter_table))
    np.testing.assert_allclose(before, pfnn.pfnn_apply(params, x, jnp.full(B, centre), adapter=adapter), **TOL)
    calls = []
    original = getattr(pfnn, name)
    monkeypatch.setattr(pfnn, name, lambda *a: calls.append(1) or original(*a) + 1.0)
    after = np.asarray(pfnn.pfnn_apply_table(table, x, centre, adapter_table=adapter_table))
    assert calls and not np.allclose(before, after)


@pytest.mark.parametrize("kind, name", [("cp", "cp_residual"), ("diagonal", "diag_residual")])
def test_the_pfnn_forward_calls_the_residual_functions(monkeypatch, kind, name):
    config, params, x = _small_pfnn()
    adapter = pfnn.init_adapter(jax.random.PRNGKey(1), pfnn.PFNNConfig(5, H, OUT, adapter=kind, rank=R))
    phase = jnp.asarray(RNG.uniform(size=B), jnp.float32)
    before = np.asarray(pfnn.pfnn_apply(params, x, phase, adapter=adapter))
    original = getattr(pfnn, name)
    monkeypatch.setattr(pfnn, name, lambda *a: original(*a) + 1.0)
    assert not np.allclose(before, pfnn.pfnn_apply(params, x, phase, adapter=adapter))


def test_the_pfnn_forward_calls_catmull_rom_weights(monkeypatch):
    config, params, x = _small_pfnn()
    phase = jnp.asarray(RNG.uniform(size=B), jnp.float32)
    before = np.asarray(pfnn.pfnn_apply(params, x, phase))
    monkeypatch.setattr(pfnn, "catmull_rom_weights", lambda p: jnp.full((len(p), 4), 0.25))
    assert not np.allclose(before, pfnn.pfnn_apply(params, x, phase))


@pytest.mark.parametrize("name", ["film", "layer_norm"])
def test_the_synthesis_network_calls_film_and_layer_norm(monkeypatch, name):
    params = lpn.init_synthesis(jax.random.PRNGKey(0), 3, (5, H, H, OUT))
    x = jnp.asarray(RNG.normal(size=(B, 5)), jnp.float32)
    alpha = jax.nn.softmax(jnp.asarray(RNG.normal(size=(B, 3)), jnp.float32))
    films = jnp.asarray(RNG.normal(size=4 * H), jnp.float32)
    before = np.asarray(lpn.synthesis_apply(params, x, alpha, film_params=films))
    original = getattr(lpn, name)
    monkeypatch.setattr(lpn, name, lambda *a: original(*a) * 2.0)
    assert not np.allclose(before, lpn.synthesis_apply(params, x, alpha, film_params=films))


def test_the_lpn_resad_baseline_calls_full_residual(monkeypatch):
    config = style_models.StyleModelConfig("lpn", "resad", num_styles=2, input_size=5, hidden_size=H,
                                           output_size=OUT, gating_input=4, gating_hidden=6, num_experts=3)
    params = style_models.init_model(jax.random.PRNGKey(0), config)
    style = style_models.style_runtime(params, config, 1)
    x = jnp.asarray(RNG.normal(size=(B, 5)), jnp.float32)
    gate = jnp.asarray(RNG.normal(size=(B, 4)), jnp.float32)
    before = np.asarray(style_models.model_apply(params, config, x, gate, style))
    monkeypatch.setattr(pfnn, "full_residual", lambda h, w, b: h @ w + b + 1.0)
    assert not np.allclose(before, style_models.model_apply(params, config, x, gate, style))
