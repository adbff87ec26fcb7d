"""The fast LPN training path against the plain one, on tiny sizes: the donated
scan without a step mask equals :func:`jaxstyle.train.scan.train_scan` (the pre-change driver);
the im2col convolution of the FiLM generator equals XLA's convolution in values and gradients;
bfloat16 products stay within bfloat16's precision of float32; the batch-size rule."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxstyle.mason2022 import loss as lpn_loss
from jaxstyle.mason2022 import styledata
from jaxstyle.mason2022 import train as train_lpn
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import style_models
from jaxstyle.train import scan
from tests.test_lpn import small_config, synthetic_data


def _inputs(data, config, steps):
    batches, styles, clips = train_lpn.epoch_batches(data, config, 0)
    keys = jax.random.split(jax.random.PRNGKey(3), steps)
    return jnp.asarray(batches[:steps]), jnp.asarray(styles[:steps]), jnp.asarray(clips[:steps]), keys


def _reference_steps(params, config, data, steps):
    """The steps through the masked :func:`scan.train_scan` driver, nothing donated (the code
    before the fast path)."""
    arrays, bones = styledata.device_arrays(data), data.bones
    b, s, c, keys = _inputs(data, config, steps)

    def loss_fn(p, inputs, key):
        idx, style, clip = inputs
        return lpn_loss.batch_loss(p, config.model, arrays, lpn_loss.Batch(idx, style, clip), key,
                                   lpn_loss.LossWeights(jnp.float32(config.dropout_rate),
                                                        jnp.float32(config.bone_loss_weight)), bones)

    opt = train_lpn.init_state(jax.random.PRNGKey(0), config).opt_state
    out = jax.jit(lambda p, o: scan.train_scan(loss_fn, p, o, scan.Steps((b, s, c), jnp.ones(steps, bool), keys),
                                               optimizer=config.learning_rate, has_aux=True))(params, opt)
    return out[0], np.asarray(out[2][0])


def _fast_steps(params, config, data, steps, compute_dtype="float32"):
    opt = train_lpn.init_state(jax.random.PRNGKey(0), config).opt_state
    copy = jax.tree.map(jnp.copy, params)  # donated
    p, _, out = train_lpn._train_chunk(
        copy, opt, styledata.device_arrays(data), *_inputs(data, config, steps),
        jnp.float32(config.dropout_rate), jnp.float32(config.bone_loss_weight), config=config.model,
        bones=styledata.StaticBones(data.bones), learning_rate=config.learning_rate, compute_dtype=compute_dtype)
    assert all(v.is_deleted() for v in jax.tree.leaves(copy))  # donated: updated in place, not copied
    return p, np.asarray(out[:, 0])


def _config(**kw):
    return train_lpn.LPNTrainConfig(model=small_config(), batch_size=8, learning_rate=1e-3, **kw)


def _max_diff(a, b):
    return max(float(jnp.max(jnp.abs(x - y))) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def test_donated_unmasked_steps_equal_the_train_scan_driver():
    data, config = synthetic_data(), _config()
    params = train_lpn.init_state(jax.random.PRNGKey(0), config).params
    ref_p, ref_loss = _reference_steps(params, config, data, 3)
    fast_p, fast_loss = _fast_steps(params, config, data, 3)
    np.testing.assert_allclose(fast_loss, ref_loss, rtol=1e-6, atol=1e-6)
    assert _max_diff(fast_p, ref_p) <= 1e-6
    assert _max_diff(fast_p, params) > 1e-4  # the steps did change the weights


@pytest.mark.slow
def test_train_one_epoch_equals_the_reference_steps():
    """:func:`train` (donated chunks of 5 steps, the last one shorter) equals the epoch's steps run
    through the reference driver in one scan, with the same batches, clips and keys."""
    data, config = synthetic_data(), _config(epochs=1, log_every=5)
    init = train_lpn.init_state(jax.random.PRNGKey(config.seed), config).params
    state = train_lpn.train(data, config, progress=False)
    batches, styles, clips = train_lpn.epoch_batches(data, config, 0)
    keys = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(config.seed), 0), len(batches))
    arrays = styledata.device_arrays(data)

    def loss_fn(p, inputs, key):
        idx, style, clip = inputs
        return lpn_loss.batch_loss(p, config.model, arrays, lpn_loss.Batch(idx, style, clip), key,
                                   lpn_loss.LossWeights(jnp.float32(0.3), jnp.float32(1.0)), data.bones)

    opt = train_lpn.init_state(jax.random.PRNGKey(0), config).opt_state
    steps = scan.Steps((jnp.asarray(batches), jnp.asarray(styles), jnp.asarray(clips)), jnp.ones(len(batches), bool),
                       keys)
    ref, _, _ = scan.train_scan(loss_fn, init, opt, steps, optimizer=config.learning_rate, has_aux=True)
    assert len(batches) > 5
    assert _max_diff(state.params, ref) <= 1e-6


@pytest.mark.parametrize("width", [5, 4])
def test_im2col_convolution_equals_xla_convolution(width):
    """Values and both gradients (kernel, input) of :func:`film._conv`'s patch product against
    ``lax.conv_general_dilated`` with 'SAME' padding, odd and even widths."""
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(0), 3)
    layer = {"W": jax.random.normal(k1, (width, 6, 4)), "b": jax.random.normal(k2, (4,))}
    x = jax.random.normal(k3, (2, 16, 6))
    probe = jax.random.normal(jax.random.PRNGKey(4), (2, 16, 4))

    def xla(layer, x):
        out = jax.lax.conv_general_dilated(x, layer["W"], (1,), "SAME", dimension_numbers=("NWC", "WIO", "NWC"))
        return jnp.sum((out + layer["b"]) * probe)

    def ours(layer, x):
        return jnp.sum(film._conv(layer, x) * probe)

    np.testing.assert_allclose(ours(layer, x), xla(layer, x), rtol=1e-5)
    g_ours, g_xla = jax.grad(ours, argnums=(0, 1))(layer, x), jax.grad(xla, argnums=(0, 1))(layer, x)
    for a, b in zip(jax.tree.leaves(g_ours), jax.tree.leaves(g_xla), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)


def test_a_large_batch_of_clips_takes_xla_convolution_with_the_same_values(monkeypatch):
    layer = {"W": jax.random.normal(jax.random.PRNGKey(0), (5, 6, 4)), "b": jnp.zeros(4)}
    x = jax.random.normal(jax.random.PRNGKey(1), (3, 16, 6))
    small = film._conv(layer, x)
    monkeypatch.setattr(film, "IM2COL_VALUES", 10)
    np.testing.assert_allclose(film._conv(layer, x), small, rtol=1e-5, atol=1e-5)


@pytest.mark.slow  # 26 s of the default run's budget; the donated/unmasked test covers the fast path's equality
def test_bfloat16_products_stay_within_bfloat16_precision():
    """bfloat16 keeps 8 significant bits (relative rounding 2^-9 = 0.2% per operand); the products
    accumulate in float32 and the network is 3 layers plus a 4-layer generator deep, so on these
    tiny sizes the loss and the gradient may differ from float32 by ~1% and no more: loss within
    1e-2 relative, gradient within 3e-2 relative (L2). A no-op option (float32 everywhere) would
    pass too, so the test also checks the compiled step holds bfloat16 products."""
    data, config = synthetic_data(), _config()
    params = train_lpn.init_state(jax.random.PRNGKey(0), config).params
    arrays, bones = styledata.device_arrays(data), styledata.StaticBones(data.bones)
    b, s, c, keys = _inputs(data, config, 1)

    def loss(p, dtype):
        return train_lpn._step_loss(p, config.model, arrays, (b[0], s[0], c[0]), keys[0], jnp.float32(0.0),
                                    jnp.float32(1.0), bones, dtype)[0]

    (l32, g32), (l16, g16) = (jax.value_and_grad(loss)(params, d) for d in ("float32", "bfloat16"))
    np.testing.assert_allclose(l16, l32, rtol=1e-2)
    flat32, flat16 = (jnp.concatenate([v.ravel() for v in jax.tree.leaves(g)]) for g in (g32, g16))
    assert jnp.all(jnp.isfinite(flat16))
    assert float(jnp.linalg.norm(flat16 - flat32) / jnp.linalg.norm(flat32)) < 3e-2
    jaxpr = str(jax.make_jaxpr(lambda p: loss(p, "bfloat16"))(params))
    assert "bf16" in jaxpr and "preferred_element_type=float32" in jaxpr


@pytest.mark.slow
def test_one_bfloat16_training_step_stays_within_two_learning_rates():
    data, config = synthetic_data(), _config()
    params = train_lpn.init_state(jax.random.PRNGKey(0), config).params
    # one training step: Adam's first update is about -lr * sign(g) per weight, so the two paths'
    # weights differ by at most 2 lr, and differ at all only where a gradient's sign flipped
    p32, _ = _fast_steps(params, config, data, 1)
    p16, _ = _fast_steps(params, config, data, 1, compute_dtype="bfloat16")
    assert _max_diff(p16, p32) <= 2 * config.learning_rate * 1.001
    assert all(v.dtype == jnp.float32 for v in jax.tree.leaves(p16))  # float32 master weights


def test_batch_size_rule_scales_adams_rate_by_the_square_root():
    config = train_lpn.LPNTrainConfig()
    assert (config.batch_size, config.learning_rate) == (32, 1e-4)  # the paper's defaults stay
    big = train_lpn.with_batch_size(config, 128)
    assert big.batch_size == 128 and big.learning_rate == pytest.approx(2e-4)
    assert train_lpn.with_batch_size(config, 8).learning_rate == pytest.approx(5e-5)
    assert dataclasses.replace(big, batch_size=32, learning_rate=1e-4) == config
    with pytest.raises(ValueError, match="batch_size"):
        train_lpn.with_batch_size(config, 0)


def test_unknown_compute_dtype_is_refused():
    with pytest.raises(ValueError, match="compute_dtype"):
        train_lpn.train(synthetic_data(), _config(epochs=1), compute_dtype="float16", progress=False)


def test_a_paper_sized_generator_has_its_parameter_count():
    params = jax.eval_shape(lambda: film.init_generator(jax.random.PRNGKey(0)))
    assert style_models.tree_size(params) == film.generator_size() == 39_214_592
