"""The Flax NNX modules are a façade: same outputs, gradients and optimiser steps as the pure functions,
and exact round trips of the pure parameter pytrees."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax import nnx

import jaxstyle
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import modules, pfnn, style_models

# Small networks whose layers share a few shapes: every new shape costs JAX a compile (mostly the random
# initialisers), and the shapes here keep the file at a few seconds of CPU time.
PFNN_CONFIG = pfnn.PFNNConfig(input_size=8, hidden_size=8, output_size=8, adapter="cp", rank=8)
NUM_STYLES = 3
FILM_CONFIG = style_models.StyleModelConfig(
    "lpn", "film", num_styles=2, input_size=8, hidden_size=8, output_size=8, gating_input=4, gating_hidden=4,
    num_experts=4, generator=film.FiLMConfig(clip_frames=8, clip_features=8, filters=8, width=3, hidden=16,
                                             film_size=32))
B = 7
KEY = jax.random.PRNGKey(42)


def _equal_trees(a, b):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(x, y)


def _close_trees(a, b, rtol=1e-5, atol=1e-6):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(x, y, rtol=rtol, atol=atol)


def _as_params(module, state, getter):
    """A gradient (or any) ``nnx.State`` of ``module`` as the pure pytree ``getter`` returns."""
    graphdef, _ = nnx.split(module)
    return getter(nnx.merge(graphdef, state))


@pytest.fixture(scope="module")
def pfnn_data():
    rng = np.random.default_rng(1)
    return (jnp.asarray(rng.normal(size=(B, PFNN_CONFIG.input_size)), jnp.float32),
            jnp.asarray(rng.uniform(size=B), jnp.float32),
            jnp.asarray(rng.normal(size=(B, PFNN_CONFIG.output_size)), jnp.float32))


@pytest.fixture(scope="module")
def film_data():
    rng = np.random.default_rng(2)
    g = FILM_CONFIG.generator
    return tuple(jnp.asarray(a, jnp.float32) for a in (
        rng.normal(size=(B, FILM_CONFIG.input_size)), rng.uniform(size=(B, FILM_CONFIG.gating_input)),
        rng.normal(size=(1, g.clip_frames, g.clip_features)), rng.normal(size=(B, FILM_CONFIG.output_size))))


@pytest.fixture(scope="module")
def pfnn_model():
    return modules.PFNNModule(PFNN_CONFIG, num_styles=NUM_STYLES, rngs=nnx.Rngs(0))


@pytest.fixture(scope="module")
def film_model():
    return modules.LPNFiLMModule(FILM_CONFIG, rngs=nnx.Rngs(0))


# --- PFNN ---------------------------------------------------------------------------------------

def test_pfnn_initialises_as_the_pure_functions(pfnn_model):
    m = pfnn_model
    kp, ka = jax.random.split(nnx.Rngs(0).params())
    _equal_trees(m.params(), pfnn.init_pfnn(kp, PFNN_CONFIG))  # as jaxstyle.mason2018.train.init_state
    _equal_trees(m.adapters(), jax.vmap(lambda k: pfnn.init_adapter(k, PFNN_CONFIG))(jax.random.split(ka, NUM_STYLES)))
    assert m.num_styles == NUM_STYLES
    assert modules.PFNNModule(PFNN_CONFIG, rngs=nnx.Rngs(0)).adapters() is None
    assert len(jax.tree.leaves(nnx.state(m, nnx.Param))) == len(jax.tree.leaves((m.params(), m.adapters())))


@pytest.mark.parametrize("rate", [0.0, 0.3])
@pytest.mark.parametrize("which", ["none", "style", "external"])
def test_pfnn_module_output_equals_pfnn_apply(pfnn_data, pfnn_model, rate, which):
    x, phase, _ = pfnn_data
    m = pfnn_model
    external = pfnn.init_adapter(jax.random.PRNGKey(9), PFNN_CONFIG)
    kwargs = {"none": {}, "style": {"style": 1}, "external": {"adapter": external}}[which]
    adapter = {"none": None, "style": jax.tree.map(lambda v: v[1], m.adapters()), "external": external}[which]
    got = m(x, phase, dropout_rate=rate, key=KEY, **kwargs)
    want = pfnn.pfnn_apply(m.params(), x, phase, adapter=adapter, key=KEY, dropout_rate=rate)
    np.testing.assert_array_equal(got, want)
    if rate:  # dropout really is on, and the same key gives the same masks
        assert not np.allclose(got, m(x, phase, **kwargs))
    # the rngs= path draws the key from the dropout stream
    got_rngs = m(x, phase, dropout_rate=rate, rngs=nnx.Rngs(dropout=5), **kwargs)
    want_rngs = pfnn.pfnn_apply(m.params(), x, phase, adapter=adapter, key=nnx.Rngs(dropout=5).dropout(),
                                dropout_rate=rate)
    np.testing.assert_array_equal(got_rngs, want_rngs)


def test_pfnn_module_under_nnx_jit_equals_pure_jit(pfnn_data, pfnn_model):
    x, phase, _ = pfnn_data
    m = pfnn_model
    got = nnx.jit(lambda m, x, p, s: m(x, p, style=s, dropout_rate=0.3, key=KEY))(m, x, phase, 2)
    want = jax.jit(lambda p, a, x, ph: pfnn.pfnn_apply(p, x, ph, adapter=jax.tree.map(lambda v: v[2], a), key=KEY,
                                                       dropout_rate=0.3))(m.params(), m.adapters(), x, phase)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


def _pfnn_pure_loss(trainable, x, phase, y, style, rate):
    params, adapters = trainable
    adapter = jax.tree.map(lambda v: v[style], adapters)
    return jnp.mean((pfnn.pfnn_apply(params, x, phase, adapter=adapter, key=KEY, dropout_rate=rate) - y) ** 2)


def _pfnn_module_loss(m, x, phase, y, style, rate):
    return jnp.mean((m(x, phase, style=style, dropout_rate=rate, key=KEY) - y) ** 2)


RATES = (0.0, 0.3)
STYLE = 1


@pytest.fixture(scope="module")
def pfnn_grads(pfnn_data, pfnn_model):
    """``{rate: ((value, grads) of the module by nnx.value_and_grad, (value, grads) of the pure
    function by jax.value_and_grad)}``, computed once for the gradient and the optimiser tests (eagerly:
    the pure function then reuses the module's compiled operations)."""
    x, phase, y = pfnn_data
    m = pfnn_model
    module_vg = nnx.value_and_grad(_pfnn_module_loss)
    pure_vg = jax.value_and_grad(_pfnn_pure_loss)
    return {rate: (module_vg(m, x, phase, y, STYLE, rate),
                   pure_vg((m.params(), m.adapters()), x, phase, y, STYLE, rate)) for rate in RATES}


@pytest.mark.parametrize("rate", RATES)
def test_pfnn_module_gradients_equal_the_pure_gradients(pfnn_grads, pfnn_model, rate):
    m = pfnn_model
    (value, grads), (want_value, (g_params, g_adapters)) = pfnn_grads[rate]
    np.testing.assert_allclose(value, want_value, rtol=1e-6)
    _close_trees(_as_params(m, grads, lambda g: g.params()), g_params)
    _close_trees(_as_params(m, grads, lambda g: g.adapters()), g_adapters)
    # only the chosen style's adapter gets a gradient
    assert float(jnp.abs(g_adapters["A"][0]).max()) == 0.0 < float(jnp.abs(g_adapters["A"][STYLE]).max())
    if rate:
        assert not np.allclose(value, pfnn_grads[0.0][0][0])


def _adam_step(params, grads):
    """One pure optax Adam step (lr 1e-2) from fresh optimiser state."""
    opt = optax.adam(1e-2)
    updates, _ = opt.update(grads, opt.init(params), params)
    return optax.apply_updates(params, updates)


def test_pfnn_nnx_optimizer_step_equals_the_optax_step(pfnn_grads, pfnn_model):
    before = (pfnn_model.params(), pfnn_model.adapters())
    m = modules.PFNNModule.from_params(PFNN_CONFIG, *before)  # a copy: the shared fixture stays as it is
    optimizer = nnx.Optimizer(m, optax.adam(1e-2), wrt=nnx.Param)
    (_, grads), (_, pure_grads) = pfnn_grads[0.3]
    optimizer.update(m, grads)
    after = (m.params(), m.adapters())
    assert not np.allclose(after[0]["l0"]["W"], before[0]["l0"]["W"])
    assert not np.allclose(after[1]["A"][STYLE], before[1]["A"][STYLE])
    np.testing.assert_array_equal(after[1]["A"][0], before[1]["A"][0])  # other styles' adapters untouched
    _close_trees(after, _adam_step(before, pure_grads))
    _equal_trees(pfnn_model.params(), before[0])


def test_pfnn_round_trip_is_exact(pfnn_data, pfnn_model):
    x, phase, _ = pfnn_data
    m = pfnn_model
    m2 = modules.PFNNModule.from_params(PFNN_CONFIG, m.params(), m.adapters())
    _equal_trees(m2.params(), m.params())
    _equal_trees(m2.adapters(), m.adapters())
    np.testing.assert_array_equal(m2(x, phase, style=0), m(x, phase, style=0))
    # pure weights in: a base cast to bfloat16 keeps its dtype, numpy arrays become jax arrays
    base = pfnn.cast_weights(m.params(), jnp.bfloat16)
    _equal_trees(modules.PFNNModule.from_params(PFNN_CONFIG, base).params(), base)
    as_numpy = jax.tree.map(np.asarray, m.params())
    _equal_trees(modules.PFNNModule.from_params(PFNN_CONFIG, as_numpy).params(), m.params())


def test_pfnn_module_errors(pfnn_data, pfnn_model):
    x, phase, _ = pfnn_data
    m = modules.PFNNModule.from_params(PFNN_CONFIG, pfnn_model.params())
    with pytest.raises(ValueError, match="key= or rngs="):
        m(x, phase, dropout_rate=0.3)
    with pytest.raises(ValueError, match="holds no adapters"):
        m(x, phase, style=0)
    with pytest.raises(ValueError, match="not both"):
        m(x, phase, style=0, adapter=pfnn_model.adapter(0))
    with pytest.raises(ValueError, match="rngs"):
        modules.PFNNModule(PFNN_CONFIG)
    wrong = dict(m.params(), l0={"W": jnp.zeros((4, 7, 8)), "b": jnp.zeros((4, 8))})  # input_size 7, not 8
    with pytest.raises(ValueError, match=r"'l0'\]\['W'\]"):
        modules.PFNNModule.from_params(PFNN_CONFIG, wrong)
    one = pfnn_model.adapter(0)  # not stacked
    with pytest.raises(ValueError, match="stacked"):
        modules.PFNNModule.from_params(PFNN_CONFIG, m.params(), one)


# --- LPN FiLM -----------------------------------------------------------------------------------

def _film_pure(params, x, gate, clip, key, rate):
    """The training composition of jaxstyle.mason2022.loss.batch_loss: the generator on the clip,
    then the model, the key split between them."""
    k_style, k_model = jax.random.split(key)
    st = film.generator_apply(params["style"]["generator"], clip, key=k_style, dropout_rate=rate)
    return style_models.model_apply(params, FILM_CONFIG, x, gate, st, key=k_model, dropout_rate=rate)


def test_lpn_film_initialises_as_init_model(film_model):
    m = film_model
    _equal_trees(m.params(), style_models.init_model(nnx.Rngs(0).params(), FILM_CONFIG))
    assert isinstance(m.params()["gating"], list)


@pytest.mark.parametrize("rate", [0.0, 0.3])
def test_lpn_film_module_output_equals_model_apply(film_data, film_model, rate):
    x, gate, clip, _ = film_data
    m = film_model
    got = m(x, gate, clip=clip, dropout_rate=rate, key=KEY)
    np.testing.assert_array_equal(got, _film_pure(m.params(), x, gate, clip, KEY, rate))
    if rate:
        assert not np.allclose(got, m(x, gate, clip=clip))
    # a precomputed FiLM vector (the runtime path)
    vector = film.generator_apply(m.params()["style"]["generator"], clip)[0]
    np.testing.assert_array_equal(m.film(clip)[0], vector)
    got = m(x, gate, film_params=vector, dropout_rate=rate, key=KEY)
    want = style_models.model_apply(m.params(), FILM_CONFIG, x, gate, vector, key=KEY, dropout_rate=rate)
    np.testing.assert_array_equal(got, want)


def _film_module_loss(m, x, gate, clip, y, rate):
    return jnp.mean((m(x, gate, clip=clip, dropout_rate=rate, key=KEY) - y) ** 2)


def _film_pure_loss(params, x, gate, clip, y, rate):
    return jnp.mean((_film_pure(params, x, gate, clip, KEY, rate) - y) ** 2)


@pytest.fixture(scope="module")
def film_grads(film_data, film_model):
    """As ``pfnn_grads``, for the LPN FiLM module and the training composition of the pure functions."""
    x, gate, clip, y = film_data
    module_vg = nnx.value_and_grad(_film_module_loss)
    pure_vg = jax.value_and_grad(_film_pure_loss)
    return {rate: (module_vg(film_model, x, gate, clip, y, rate),
                   pure_vg(film_model.params(), x, gate, clip, y, rate)) for rate in RATES}


@pytest.mark.parametrize("rate", RATES)
def test_lpn_film_module_gradients_equal_the_pure_gradients(film_grads, film_model, rate):
    (value, grads), (want_value, want) = film_grads[rate]
    np.testing.assert_allclose(value, want_value, rtol=1e-6)
    got = _as_params(film_model, grads, lambda g: g.params())
    _close_trees(got, want)
    for part in (got["gating"][0]["W"], got["style"]["generator"]["conv1"]["W"], got["synthesis"]["l2"]["W"]):
        assert float(jnp.abs(part).max()) > 0  # gradients reach the gating, the generator and the experts
    if rate:
        assert not np.allclose(value, film_grads[0.0][0][0])


def test_lpn_film_nnx_optimizer_step_and_round_trip(film_data, film_grads, film_model):
    x, gate, clip, _ = film_data
    before = film_model.params()
    m = modules.LPNFiLMModule.from_params(FILM_CONFIG, before)  # a copy: the shared fixture stays as it is
    optimizer = nnx.Optimizer(m, optax.adam(1e-2), wrt=nnx.Param)
    (_, grads), (_, pure_grads) = film_grads[0.3]
    optimizer.update(m, grads)
    after = m.params()
    assert not np.allclose(after["synthesis"]["l0"]["W"], before["synthesis"]["l0"]["W"])
    assert not np.allclose(after["style"]["generator"]["dense2"]["W"], before["style"]["generator"]["dense2"]["W"])
    _close_trees(after, _adam_step(before, pure_grads))
    m2 = modules.LPNFiLMModule.from_params(FILM_CONFIG, after)
    _equal_trees(m2.params(), after)
    np.testing.assert_array_equal(m2(x, gate, clip=clip), m(x, gate, clip=clip))


def test_lpn_film_module_errors(film_data, film_model):
    x, gate, clip, _ = film_data
    m = film_model
    with pytest.raises(ValueError, match="exactly one"):
        m(x, gate)
    with pytest.raises(ValueError, match="key= or rngs="):
        m(x, gate, clip=clip, dropout_rate=0.1)
    onehot = style_models.StyleModelConfig("lpn", "onehot", num_styles=2)
    with pytest.raises(ValueError, match="modulation must be 'film'"):
        modules.LPNFiLMModule(onehot, rngs=nnx.Rngs(0))
    wrong = dict(m.params(), gating=m.params()["gating"][:2])
    with pytest.raises(ValueError, match="do not match the config"):
        modules.LPNFiLMModule.from_params(FILM_CONFIG, wrong)


def test_public_names_are_the_modules():
    assert jaxstyle.PFNNModule is modules.PFNNModule
    assert jaxstyle.LPNFiLMModule is modules.LPNFiLMModule
