"""PFNN math: the phase spline, output blending, adapters, dropout, gradients, runtime table."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxstyle.nn import pfnn

SMALL = dict(input_size=6, hidden_size=8, output_size=5, rank=3)


def _reference_cubic(points, phase):
    """The 2018 code's cubic, written independently in numpy, one phase at a time."""
    out = []
    for p in phase:
        t = 4.0 * (p % 1.0)
        k = int(np.floor(t)) % 4
        mu = t - np.floor(t)
        y0, y1, y2, y3 = (points[(k + i) % 4] for i in (-1, 0, 1, 2))
        out.append((-0.5 * y0 + 1.5 * y1 - 1.5 * y2 + 0.5 * y3) * mu ** 3
                   + (y0 - 2.5 * y1 + 2 * y2 - 0.5 * y3) * mu ** 2 + (-0.5 * y0 + 0.5 * y2) * mu + y1)
    return np.array(out)


def test_spline_matches_the_reference_cubic_in_all_segments():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(4, 7))
    phase = np.concatenate([rng.uniform(s / 4, (s + 1) / 4, 50) for s in range(4)])
    got = pfnn.blend(jnp.asarray(points, jnp.float32), pfnn.catmull_rom_weights(phase))
    np.testing.assert_allclose(got, _reference_cubic(points, phase), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(pfnn.catmull_rom_weights(np.arange(4) / 4), np.eye(4), atol=1e-7)  # interpolates


def test_spline_is_periodic_and_c1_at_control_points():
    rng = np.random.default_rng(1)
    points = jnp.asarray(rng.normal(size=(4, 3)))
    f = lambda p: pfnn.blend(points, pfnn.catmull_rom_weights(jnp.asarray(p, jnp.float32)))  # noqa: E731
    phases = np.linspace(0, 1, 37, endpoint=False)
    np.testing.assert_allclose(f(phases), f(phases + 1.0), atol=1e-5)
    h = 1e-3
    for k in range(4):
        p = k / 4
        left, right = (f([p]) - f([p - h])) / h, (f([p + h]) - f([p])) / h
        np.testing.assert_allclose(left, right, atol=0.05 * float(jnp.abs(right).max()) + 0.02)
        np.testing.assert_allclose(f([p - 1e-5]), f([p]), atol=1e-3)


def _explicit_forward(params, adapter, x, phase):
    """Weight-blended forward: a weight matrix per sample (what the library never does)."""
    w = np.asarray(pfnn.catmull_rom_weights(phase))
    out = []
    for i in range(len(x)):
        W = {k: {n: np.tensordot(w[i], np.asarray(v), axes=1) for n, v in layer.items()} for k, layer in params.items()}
        elu = lambda z: np.where(z > 0, z, np.expm1(np.minimum(z, 0)))  # noqa: E731
        h1 = elu(x[i] @ W["l0"]["W"] + W["l0"]["b"])
        pre = h1 @ W["l1"]["W"] + W["l1"]["b"]
        if adapter is not None:
            kind = pfnn.adapter_kind(adapter)
            a = {n: np.asarray(v) for n, v in adapter.items()}
            if kind == "full":
                pre = pre + h1 @ np.tensordot(w[i], a["W"], 1) + np.tensordot(w[i], a["b"], 1)
            elif kind == "diagonal":
                pre = pre + np.tensordot(w[i], a["d"], 1) * h1 + np.tensordot(w[i], a["b"], 1)
            else:
                pre = pre + a["B"] @ (np.tensordot(w[i], a["d"], 1) * (a["A"] @ h1)) + a["b"]
        out.append(elu(pre) @ W["l2"]["W"] + W["l2"]["b"])
    return np.array(out)


@pytest.mark.parametrize("kind", [None, "full", "diagonal", "cp"])
def test_output_blending_equals_weight_blending(kind):
    config = pfnn.PFNNConfig(**SMALL, adapter=kind or "cp")
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
    adapter = None if kind is None else pfnn.init_adapter(jax.random.PRNGKey(1), config)
    if adapter is not None:  # non-zero biases, so they are tested too
        adapter = {n: v + 0.1 if n == "b" else v for n, v in adapter.items()}
    x = jax.random.normal(jax.random.PRNGKey(2), (16, 6))
    phase = jnp.linspace(0, 1, 16, endpoint=False) + 0.01
    got = pfnn.pfnn_apply(params, x, phase, adapter=adapter)
    np.testing.assert_allclose(got, _explicit_forward(params, adapter, np.asarray(x), phase), rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("kind", [pytest.param("full", marks=pytest.mark.slow), "diagonal", "cp"])
def test_gradients_pass_finite_differences(kind):
    config = pfnn.PFNNConfig(**SMALL, adapter=kind)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
    adapter = pfnn.init_adapter(jax.random.PRNGKey(1), config)
    x = jax.random.normal(jax.random.PRNGKey(2), (4, 6))
    y = jax.random.normal(jax.random.PRNGKey(3), (4, 5))
    phase = jnp.array([0.1, 0.3, 0.6, 0.9])
    f = lambda p, a: pfnn.loss(p, a, x, y, phase, lambda_ag=0.0, lambda_s=0.0)  # noqa: E731  (L1 is not smooth at 0)
    check_grads(f, (params, adapter), order=1, modes=["rev"], eps=1e-2, atol=5e-2, rtol=5e-2)


@pytest.mark.parametrize("kind", ["full", "diagonal", "cp"])
def test_adapter_sizes_match_the_formulas(kind):
    for h, r in ((512, 30), (64, 7)):
        config = pfnn.PFNNConfig(hidden_size=h, rank=r, adapter=kind)
        adapter = pfnn.init_adapter(jax.random.PRNGKey(0), config)
        assert sum(v.size for v in jax.tree.leaves(adapter)) == pfnn.adapter_size(config)
    assert pfnn.adapter_size(pfnn.PFNNConfig(adapter="full")) == 4 * 512 * 512 + 4 * 512
    assert pfnn.adapter_size(pfnn.PFNNConfig(adapter="cp")) == 2 * 30 * 512 + 4 * 30 + 512


@pytest.mark.parametrize("kind", [pytest.param("full", marks=pytest.mark.slow), "diagonal", "cp"])
def test_discretised_table_matches_at_bin_centres(kind):
    config = pfnn.PFNNConfig(**SMALL, adapter=kind)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
    adapter = pfnn.init_adapter(jax.random.PRNGKey(1), config)
    table, adapter_table = pfnn.discretise(params), pfnn.discretise(adapter)
    assert table["l1"]["W"].shape == (50, 8, 8)
    x = jax.random.normal(jax.random.PRNGKey(2), (3, 6))
    for i in (0, 13, 37, 49):
        centre = (i + 0.5) / 50
        want = pfnn.pfnn_apply(params, x, jnp.full(3, centre), adapter=adapter)
        got = pfnn.pfnn_apply_table(table, x, centre, adapter_table=adapter_table)
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)
        # any phase in the bin reads the same entry
        np.testing.assert_allclose(pfnn.pfnn_apply_table(table, x, i / 50 + 1e-4, adapter_table=adapter_table), got)


def test_dropout_rate_is_an_array_and_vmaps():
    x = jnp.ones((1000,))
    key = jax.random.PRNGKey(0)
    np.testing.assert_array_equal(pfnn.dropout(key, x, 0.0), x)
    rates = jnp.array([0.0, 0.3, 0.7])
    out = jax.vmap(lambda r: pfnn.dropout(key, x, r))(rates)
    np.testing.assert_allclose((out == 0).mean(1), rates, atol=0.05)
    np.testing.assert_allclose(out.mean(1), 1.0, atol=0.15)  # inverted dropout keeps the mean


def test_dropout_rate_resolution_and_odd_shapes():
    """8 bits per unit: the dropped fraction is the rate rounded to 1/256 (binomial bounds on
    200,000 units), kept units scaled by the rounded keep probability; odd sizes work."""
    key = jax.random.PRNGKey(3)
    x = jnp.ones((400, 500))
    for rate in (0.3, 0.5, 0.123, 1.0):
        out = np.asarray(pfnn.dropout(key, x, rate))
        q = round(rate * 256) / 256
        dropped = (out == 0).mean()
        assert abs(dropped - q) <= 5 * np.sqrt(q * (1 - q) / x.size) + 1e-12
        if q < 1:
            np.testing.assert_allclose(out[out != 0], 1.0 / (1.0 - q), rtol=1e-6)
    odd = jnp.arange(7 * 33, dtype=jnp.float32).reshape(7, 33)
    out = pfnn.dropout(key, odd, 0.5)
    assert out.shape == odd.shape
    kept = np.asarray(out) != 0
    np.testing.assert_allclose(np.asarray(out)[kept], 2 * np.asarray(odd)[kept])
    # different keys, different masks; the same key, the same mask
    a, b = pfnn.dropout(key, x, 0.5), pfnn.dropout(jax.random.PRNGKey(4), x, 0.5)
    assert (np.asarray(a) != np.asarray(b)).mean() > 0.4
    np.testing.assert_array_equal(a, pfnn.dropout(key, x, 0.5))


def test_adapter_path_has_its_own_mask_and_none_is_the_average_motion():
    config = pfnn.PFNNConfig(**SMALL, adapter="cp")
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
    adapter = pfnn.init_adapter(jax.random.PRNGKey(1), config)
    x = jax.random.normal(jax.random.PRNGKey(2), (8, 6))
    phase = jnp.full(8, 0.4)
    zero = jax.tree.map(jnp.zeros_like, adapter)
    np.testing.assert_allclose(pfnn.pfnn_apply(params, x, phase, adapter=zero), pfnn.pfnn_apply(params, x, phase))
    assert not np.allclose(pfnn.pfnn_apply(params, x, phase, adapter=adapter), pfnn.pfnn_apply(params, x, phase))
    key = jax.random.PRNGKey(5)
    only_adapter = pfnn.pfnn_apply(params, x, phase, adapter=adapter, key=key, dropout_rate=0.0,
                                   adapter_dropout_rate=0.5)
    clean = pfnn.pfnn_apply(params, x, phase, adapter=adapter)
    assert not np.allclose(only_adapter, clean)  # the adapter's mask acts alone
    np.testing.assert_allclose(pfnn.pfnn_apply(params, x, phase, key=key, dropout_rate=0.0, adapter_dropout_rate=0.5),
                               pfnn.pfnn_apply(params, x, phase))


def test_l1_penalty_skips_biases_and_config_checks():
    tree = {"W": jnp.full((2, 2), -2.0), "b": jnp.full((2,), 100.0), "A": jnp.ones((3,))}
    assert float(pfnn.l1_penalty(tree)) == pytest.approx(1.5)  # mean of 2 and 1
    with pytest.raises(ValueError, match="adapter"):
        pfnn.PFNNConfig(adapter="lora")


@pytest.mark.parametrize("kind", ["full", "diagonal", "cp"])
def test_adapter_bytes_match_the_arrays(kind):
    config = pfnn.PFNNConfig(adapter=kind)
    adapter = pfnn.init_adapter(jax.random.PRNGKey(0), config)
    nbytes = lambda t: sum(v.size * v.dtype.itemsize for v in jax.tree.leaves(t))  # noqa: E731
    assert nbytes(adapter) == pfnn.adapter_bytes(config)
    assert nbytes(pfnn.discretise(adapter)) == pfnn.adapter_bytes(config, num_bins=50)
    # the paper's Table 1 in MiB: full 4.01 / 50.1, diagonal 0.016 / 0.20
    mib = 2.0 ** 20
    if kind == "full":
        assert round(pfnn.adapter_bytes(config) / mib, 2) == 4.01
        assert round(pfnn.adapter_bytes(config, 50) / mib, 1) == 50.1
    if kind == "diagonal":
        assert round(pfnn.adapter_bytes(config) / mib, 3) == 0.016


def test_pf_dense_gives_the_same_result_whether_its_weights_are_traced_or_constant():
    """Small batches with traced weights multiply per control point; constant weights or large
    batches use one product over all control points (see pfnn.SMALL_BATCH): same values."""
    k0, k1, k2 = jax.random.split(jax.random.PRNGKey(3), 3)
    layer = {"W": jax.random.normal(k0, (4, 7, 5)), "b": jax.random.normal(k1, (4, 5))}
    for batch in (1, pfnn.SMALL_BATCH, pfnn.SMALL_BATCH + 1):
        h = jax.random.normal(k2, (batch, 7))
        w = pfnn.catmull_rom_weights(jnp.linspace(0.0, 0.95, batch))
        want = np.einsum("bk,bko->bo", np.asarray(w, np.float64),
                         np.einsum("bi,kio->bko", np.asarray(h, np.float64), np.asarray(layer["W"], np.float64))
                         + np.asarray(layer["b"], np.float64))
        np.testing.assert_allclose(pfnn.pf_dense(layer, h, w), want, rtol=1e-5, atol=1e-5)           # constant W
        np.testing.assert_allclose(jax.jit(pfnn.pf_dense)(layer, h, w), want, rtol=1e-5, atol=1e-5)  # traced W
