"""The few-shot sweep: one vmapped program equals training each (style, rate) alone."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxstyle.mason2018 import fewshot
from jaxstyle.nn import pfnn
from jaxstyle.train import scan

SMALL = pfnn.PFNNConfig(input_size=6, hidden_size=16, output_size=5, rank=4)


def _data(seed=0):
    rng = np.random.default_rng(seed)
    sizes = [70, 37, 12]  # ragged styles, one smaller than a batch
    n = sum(sizes)
    x = rng.normal(size=(n, 6)).astype(np.float32)
    y = rng.normal(size=(n, 5)).astype(np.float32)
    phase = rng.uniform(size=n).astype(np.float32)
    offsets = np.cumsum([0] + sizes)
    rows = [np.arange(offsets[s], offsets[s + 1]) for s in range(3)]
    return jnp.asarray(x), jnp.asarray(y), jnp.asarray(phase), rows


def test_sweep_batches_are_ragged_with_masks():
    _, _, _, rows = _data()
    batches, mask = scan.sweep_batches(rows, epochs=3, batch_size=16)
    assert batches.shape == (3, 3 * (70 // 16), 16)
    np.testing.assert_array_equal(mask.sum(1), [3 * 4, 3 * 2, 3 * 1])
    for s in range(3):
        assert np.isin(batches[s][mask[s]], rows[s]).all()


def _assert_pair_equals_single_run(params, x, y, phase, batches, mask, config, adapters, s, r):
    """The sweep's adapter of pair (s, r) equals :func:`finetune_one` with the same key and data
    order (relative difference <= 1e-4); returns the single run's per-step losses."""
    single, single_losses = fewshot.finetune_one(params, x, y, phase, batches[s], mask[s], config.rates[r],
                                                 scan.pair_key(config.seed, s, r), config)
    for got, want in zip(jax.tree.leaves(adapters), jax.tree.leaves(single), strict=True):
        scale = np.abs(np.asarray(want)).max() + 1e-12
        assert np.abs(np.asarray(got[s, r]) - np.asarray(want)).max() / scale <= 1e-4
    return single_losses


def test_vmapped_sweep_equals_single_runs():
    x, y, phase, rows = _data()
    config = fewshot.SweepConfig(model=SMALL, epochs=4, batch_size=16, learning_rate=3e-3, rates=(0.0, 0.3, 0.6))
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), SMALL)
    batches, mask = scan.sweep_batches(rows, config.epochs, config.batch_size)
    adapters, losses = fewshot.adapter_sweep(params, x, y, phase, batches, mask, config)
    assert losses.shape == (3, 3, batches.shape[1])
    for s in range(3):
        for r in range(len(config.rates)):
            single_losses = _assert_pair_equals_single_run(params, x, y, phase, batches, mask, config, adapters, s, r)
            np.testing.assert_allclose(losses[s, r], single_losses, rtol=1e-4, atol=1e-6)
    # masked (padding) steps change nothing and report NaN
    assert np.isnan(np.asarray(losses[2, 0, int(mask[2].sum()):])).all()


def test_sweep_lowers_the_training_loss_and_leaves_the_base_alone():
    x, y, phase, rows = _data(1)
    config = fewshot.SweepConfig(model=SMALL, epochs=30, batch_size=8, learning_rate=1e-2, rates=(0.0,))
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), SMALL)
    before = jax.tree.map(np.asarray, params)
    batches, mask = scan.sweep_batches(rows, config.epochs, config.batch_size)
    _, losses = fewshot.adapter_sweep(params, x, y, phase, batches, mask, config)
    first, last = np.asarray(losses[:, 0, :2]).mean(), np.nanmean(np.asarray(losses[0, 0, -5:]))
    assert last < 0.8 * first
    for a, b in zip(jax.tree.leaves(before), jax.tree.leaves(params), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow  # python -m pytest -m slow; the default run covers the same code more cheaply
def test_adapter_dropout_only_mode_matches_its_definition():
    """Cached frozen activations give the forward of pfnn_apply with dropout on the adapter path
    only, and the sweep in that mode still equals single runs."""
    x, y, phase, rows = _data(2)
    config = fewshot.SweepConfig(model=SMALL, epochs=3, batch_size=16, learning_rate=3e-3, rates=(0.0, 0.5),
                                 adapter_dropout_only=True)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), SMALL)
    adapter = pfnn.init_adapter(jax.random.PRNGKey(1), SMALL)
    cache = fewshot.frozen_activations(params, x, phase)
    idx = jnp.arange(20)
    key = jax.random.PRNGKey(3)
    cached = fewshot._cached_loss(params, adapter, cache, y, idx, key, 0.5, 0.0)
    # the definition: frozen layers without dropout, the adapter's input dropped with `key`
    w = pfnn.catmull_rom_weights(phase[idx])
    h1 = jax.nn.elu(pfnn.pf_dense(params["l0"], x[idx], w))
    pre = pfnn.pf_dense(params["l1"], h1, w) + pfnn.apply_adapter(adapter, pfnn.dropout(key, h1, 0.5), w)
    want = jnp.mean((pfnn.pf_dense(params["l2"], jax.nn.elu(pre), w) - y[idx]) ** 2)
    np.testing.assert_allclose(cached, want, rtol=1e-5)
    no_drop = fewshot._cached_loss(params, adapter, cache, y, idx, key, 0.0, 0.0)
    full = jnp.mean((pfnn.pfnn_apply(params, x[idx], phase[idx], adapter=adapter) - y[idx]) ** 2)
    np.testing.assert_allclose(no_drop, full, rtol=1e-5)

    batches, mask = scan.sweep_batches(rows, config.epochs, config.batch_size)
    adapters, _ = fewshot.adapter_sweep(params, x, y, phase, batches, mask, config)
    _assert_pair_equals_single_run(params, x, y, phase, batches, mask, config, adapters, 1, 1)


@pytest.mark.slow  # python -m pytest -m slow; the default run covers the same code more cheaply
def test_sharded_grid_matches_one_device():
    """2 forced host devices (the flag must precede importing jax, hence a subprocess)."""
    import os
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(f"""
        import sys, numpy as np, jax
        sys.path.insert(0, {os.getcwd()!r})
        assert jax.device_count() == 2
        from tests.test_fewshot import _data, SMALL
        from jaxstyle.mason2018 import fewshot
        from jaxstyle.nn import pfnn
        from jaxstyle.train import scan
        x, y, phase, rows = _data()
        config = fewshot.SweepConfig(model=SMALL, epochs=3, batch_size=16, learning_rate=3e-3, rates=(0.0, 0.5))
        params = pfnn.init_pfnn(jax.random.PRNGKey(0), SMALL)
        b, m = scan.sweep_batches(rows, config.epochs, config.batch_size)
        one, _ = fewshot.adapter_sweep(params, x, y, phase, b, m, config)
        # 3 styles padded to 4
        two, _ = fewshot.adapter_sweep(params, x, y, phase, b, m, config, run=scan.GridRun(shard=True))
        for a, c in zip(jax.tree.leaves(one), jax.tree.leaves(two)):
            assert a.shape == c.shape
            np.testing.assert_allclose(a, c, rtol=1e-4, atol=1e-6)
        print("ok")
    """)
    env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-3000:]


def test_bfloat16_matmuls_round_only_the_frozen_products():
    """``cast_weights`` + ``pf_dense``: the product of bfloat16-rounded inputs and weights,
    accumulated in float32 (numpy float64 reference on the rounded values)."""
    rng = np.random.default_rng(5)
    layer = {"W": jnp.asarray(rng.normal(size=(4, 6, 5)), jnp.float32), "b": jnp.asarray(rng.normal(size=(4, 5)),
                                                                                         jnp.float32)}
    h = jnp.asarray(rng.normal(size=(7, 6)), jnp.float32)
    w = pfnn.catmull_rom_weights(jnp.asarray(rng.uniform(size=7), jnp.float32))
    low = pfnn.cast_weights({"l": layer}, jnp.bfloat16)["l"]
    assert low["W"].dtype == jnp.bfloat16 and low["b"].dtype == jnp.float32
    got = pfnn.pf_dense(low, h, w)
    assert got.dtype == jnp.float32
    rh = np.asarray(h.astype(jnp.bfloat16).astype(jnp.float32), np.float64)
    rw = np.asarray(low["W"].astype(jnp.float32), np.float64)
    want = np.einsum("bk,bko->bo", np.asarray(w, np.float64),
                     np.einsum("bi,kio->bko", rh, rw) + np.asarray(layer["b"], np.float64))
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-5, atol=1e-5)
    assert np.abs(np.asarray(got) - np.asarray(pfnn.pf_dense(layer, h, w))).max() > 1e-4  # it did round


def test_bfloat16_sweep_equals_its_single_runs():
    x, y, phase, rows = _data(4)
    config = fewshot.SweepConfig(model=SMALL, epochs=2, batch_size=16, learning_rate=3e-3, rates=(0.0, 0.5),
                                 matmul_dtype="bfloat16")
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), SMALL)
    batches, mask = scan.sweep_batches(rows, config.epochs, config.batch_size)
    adapters, _ = fewshot.adapter_sweep(params, x, y, phase, batches, mask, config)
    _assert_pair_equals_single_run(params, x, y, phase, batches, mask, config, adapters, 2, 1)
    with pytest.raises(ValueError, match="matmul_dtype"):
        fewshot.SweepConfig(matmul_dtype="float16")


@pytest.mark.parametrize("kind", [pytest.param("full", marks=pytest.mark.slow), "diagonal"])
def test_sweep_with_full_and_diagonal_adapters_equals_single_runs(kind):
    """CP is the default; the other two adapter kinds of the 2018 paper sweep the same way."""
    model = dataclasses.replace(SMALL, adapter=kind)
    x, y, phase, rows = _data(2)
    config = fewshot.SweepConfig(model=model, epochs=2, batch_size=16, learning_rate=3e-3, rates=(0.2, 0.6))
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), model)
    batches, mask = scan.sweep_batches(rows, config.epochs, config.batch_size)
    adapters, losses = fewshot.adapter_sweep(params, x, y, phase, batches, mask, config)
    assert pfnn.adapter_kind(jax.tree.map(lambda v: v[0, 0], adapters)) == kind
    assert np.isfinite(np.asarray(losses[:, :, 0])).all()
    for s, r in ((0, 1), (1, 0)):
        _assert_pair_equals_single_run(params, x, y, phase, batches, mask, config, adapters, s, r)


def test_rows_beyond_the_batches_change_nothing_and_lengths_share_a_program():
    """The data is padded to a row bucket: rows the batches do not index (the padding, or another
    clip's rows) change no result, and data of another length in the same bucket reuses the
    compiled program."""
    x, y, phase, rows = _data()  # 119 rows: padded to 128
    config = fewshot.SweepConfig(model=SMALL, epochs=2, batch_size=16, learning_rate=3e-3, rates=(0.3,))
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), SMALL)
    batches, mask = scan.sweep_batches(rows[:2], config.epochs, config.batch_size)  # rows < 107
    key = scan.pair_key(config.seed, 0, 0)
    assert fewshot.frozen_inputs(params, x, y, phase)["x"].shape == (128, 6)
    want, want_losses = fewshot.finetune_one(params, x, y, phase, batches[0], mask[0], 0.3, key, config)
    compiled = scan.run_pair._cache_size()
    got, losses = fewshot.finetune_one(params, x[:107], y[:107], phase[:107], batches[0], mask[0], 0.3, key, config)
    assert scan.run_pair._cache_size() == compiled  # 107 rows: the same 128-row program
    np.testing.assert_allclose(losses, want_losses, rtol=1e-6)
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    noise = np.random.default_rng(1).normal(size=(40, 6)).astype(np.float32)  # 147 rows: 256
    bigger, _ = fewshot.finetune_one(params, jnp.concatenate([x, noise]), jnp.concatenate([y, noise[:, :5]]),
                                     jnp.concatenate([phase, noise[:, 0]]), batches[0], mask[0], 0.3, key, config)
    for a, b in zip(jax.tree.leaves(bigger), jax.tree.leaves(want), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.bfloat16])
def test_frozen_layer_layout_equals_pf_dense_and_its_input_gradient(dtype):
    """``freeze_weights`` + ``pf_dense``: the ``(I, K*O)`` layout gives the ``(K, I, O)`` layer's
    output and input gradient (float32: to float rounding; bfloat16: against a float64 numpy
    reference of the bfloat16-rounded operands, the cotangent rounded too), and no weight gradient."""
    rng = np.random.default_rng(7)
    layer = {"W": jnp.asarray(rng.normal(size=(4, 6, 5)), jnp.float32),
             "b": jnp.asarray(rng.normal(size=(4, 5)), jnp.float32)}
    h = jnp.asarray(rng.normal(size=(9, 6)), jnp.float32)
    w = pfnn.catmull_rom_weights(jnp.asarray(rng.uniform(size=9), jnp.float32))
    g = jnp.asarray(rng.normal(size=(9, 5)), jnp.float32)
    frozen = pfnn.freeze_weights({"l": layer}, dtype)["l"]
    assert frozen["W"].shape == (6, 20) and frozen["W"].dtype == dtype
    out, vjp = jax.vjp(lambda x: pfnn.pf_dense(frozen, x, w), h)
    (dh,) = vjp(g)
    assert out.dtype == jnp.float32 and dh.dtype == jnp.float32

    def r(a):  # the operand as the product sees it, in float64
        return np.asarray(jnp.asarray(a).astype(dtype).astype(jnp.float32), np.float64)
    w64, W64 = np.asarray(w, np.float64), r(layer["W"])
    want = np.einsum("bk,bko->bo", w64, np.einsum("bi,kio->bko", r(h), W64) + np.asarray(layer["b"], np.float64))
    g_wide = np.asarray(w, np.float32)[:, :, None] * np.asarray(g)[:, None, :]  # the blend's cotangent
    want_dh = np.einsum("bko,kio->bi", r(g_wide), W64)
    np.testing.assert_allclose(np.asarray(out), want, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(dh), want_dh, rtol=1e-5, atol=1e-5)
    if dtype == jnp.float32:  # and equal to automatic differentiation of the (K, I, O) layer
        ref, ref_vjp = jax.vjp(lambda x: pfnn.pf_dense(layer, x, w), h)
        np.testing.assert_allclose(np.asarray(out), np.asarray(ref), rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(np.asarray(dh), np.asarray(ref_vjp(g)[0]), rtol=1e-5, atol=1e-5)
    assert np.all(np.asarray(jax.grad(lambda W: pfnn.pf_dense({**frozen, "W": W}, h, w).sum())(frozen["W"])) == 0)
