"""The 2022 style models: LPN pieces, FiLM generator, the seven Table 2 variants, their training,
testing and FiLM fine-tuning sweep, checked against numpy references and single runs."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from jax.test_util import check_grads

import jaxstyle as js
from jaxstyle.mason2022 import finetune, styledata
from jaxstyle.mason2022 import loss as lpn_loss
from jaxstyle.mason2022 import train as train_lpn
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import lpn, style_models
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.train import scan

KEY = jax.random.PRNGKey(0)
SMALL_FILM = film.FiLMConfig(clip_frames=16, clip_features=6, filters=4, width=5, hidden=8, film_size=32)


def small_config(backbone="lpn", modulation="film", **kw) -> StyleModelConfig:
    return StyleModelConfig(backbone, modulation, num_styles=3, input_size=10, hidden_size=8, output_size=9,
                            gating_input=12 if backbone == "mann" else 4, gating_hidden=6, num_experts=3,
                            rank=2, generator=SMALL_FILM, **kw)


# --- numpy references ---------------------------------------------------------------------------

def np_layer_norm(f, eps=lpn.LAYER_NORM_EPS):
    f = np.asarray(f, np.float64)
    return (f - f.mean(-1, keepdims=True)) / np.sqrt(f.var(-1, keepdims=True) + eps)


def np_conv_same(x_TxC, w_KxCxO, b_O):
    k = w_KxCxO.shape[0]
    pad_lo = (k - 1) // 2
    xp = np.pad(x_TxC, ((pad_lo, k - 1 - pad_lo), (0, 0)))
    return np.stack([np.einsum("kc,kco->o", xp[t:t + k], w_KxCxO) for t in range(len(x_TxC))]) + b_O


def np_generator(params, clip_TxC):
    p = jax.tree.map(lambda v: np.asarray(v, np.float64), params)
    h = np.maximum(np_conv_same(clip_TxC, p["conv1"]["W"], p["conv1"]["b"]), 0)
    h = h.reshape(len(h) // 2, 2, -1).max(1)
    h = np.maximum(np_conv_same(h, p["conv2"]["W"], p["conv2"]["b"]), 0)
    h = h.reshape(len(h) // 2, 2, -1).max(1).reshape(-1)
    h = np.maximum(h @ p["dense1"]["W"] + p["dense1"]["b"], 0)
    return h @ p["dense2"]["W"] + p["dense2"]["b"]


def np_bone_length_loss(pred, true, parents):
    parents = np.asarray(parents)
    out = []
    for p, t in zip(np.asarray(pred, np.float64), np.asarray(true, np.float64), strict=True):
        bones = [abs(np.linalg.norm(t[j] - t[parents[j]]) - np.linalg.norm(p[j] - p[parents[j]]))
                 for j in range(len(parents)) if parents[j] >= 0]
        out.append(np.mean(bones))
    return np.mean(out)


# --- LPN pieces ---------------------------------------------------------------------------------

def test_equal_gating_equals_the_average_expert():
    layer = lpn.init_experts(KEY, 8, 7, 5)
    layer["b"] = jax.random.normal(jax.random.PRNGKey(1), layer["b"].shape)
    x = jax.random.normal(jax.random.PRNGKey(2), (4, 7))
    out = lpn.expert_dense(layer, x, jnp.full((4, 8), 1 / 8))
    mean_w, mean_b = np.asarray(layer["W"], np.float64).mean(0), np.asarray(layer["b"], np.float64).mean(0)
    np.testing.assert_allclose(out, np.asarray(x, np.float64) @ mean_w + mean_b, rtol=1e-5, atol=1e-5)


def test_output_blend_equals_weight_blend():
    layer = lpn.init_experts(KEY, 8, 7, 5)
    layer["b"] = jax.random.normal(jax.random.PRNGKey(1), layer["b"].shape)
    x = jax.random.normal(jax.random.PRNGKey(2), (6, 7))
    alpha = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(3), (6, 8)) * 3)
    out = lpn.expert_dense(layer, x, alpha)
    for i in range(6):
        w = lpn.blended_weights(layer, alpha[i])
        np.testing.assert_allclose(out[i], x[i] @ w["W"] + w["b"], rtol=1e-5, atol=1e-5)


def test_gating_is_a_softmax_over_experts_and_depends_on_the_phases():
    params = lpn.init_gating(KEY)
    g = jax.random.normal(jax.random.PRNGKey(1), (5, 8))
    alpha = lpn.gating_apply(params, g)
    assert alpha.shape == (5, 8)
    np.testing.assert_allclose(alpha.sum(1), 1.0, rtol=1e-6)
    assert (alpha > 0).all() and float(jnp.abs(alpha[0] - alpha[1]).max()) > 1e-4


def test_layer_norm_with_identity_film_is_plain_layer_norm():
    f = jax.random.normal(KEY, (4, 16)) * 3 + 1
    plain = lpn.layer_norm(f)
    np.testing.assert_allclose(plain, np_layer_norm(f), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(lpn.film(plain, jnp.ones(16), jnp.zeros(16)), plain)
    gamma, beta = jnp.arange(16.0), -jnp.arange(16.0)
    np.testing.assert_allclose(lpn.film(plain, gamma, beta), np.asarray(plain) * np.arange(16) - np.arange(16),
                               rtol=1e-6, atol=1e-5)


def test_identity_film_equals_the_network_without_film():
    config = small_config()
    params = style_models.init_model(KEY, config)
    x, g = jax.random.normal(jax.random.PRNGKey(1), (5, 10)), jax.random.normal(jax.random.PRNGKey(2), (5, 4))
    alpha = lpn.gating_apply(params["gating"], g)
    identity = jnp.concatenate([jnp.ones(8), jnp.zeros(8), jnp.ones(8), jnp.zeros(8)])
    with_film = lpn.synthesis_apply(params["synthesis"], x, alpha, film_params=identity)
    without = lpn.synthesis_apply(params["synthesis"], x, alpha)
    np.testing.assert_allclose(with_film, without, rtol=1e-6, atol=1e-6)


def test_bone_length_loss_matches_numpy():
    parents = [-1, 0, 1, 1, 3]
    pred = jax.random.normal(KEY, (3, 5, 3))
    true = jax.random.normal(jax.random.PRNGKey(1), (3, 5, 3))
    np.testing.assert_allclose(lpn.bone_length_loss(pred, true, parents), np_bone_length_loss(pred, true, parents),
                               rtol=1e-5)
    assert float(lpn.bone_length_loss(true, true, parents)) == 0.0


# --- FiLM generator -----------------------------------------------------------------------------

def test_generator_shapes_at_the_paper_size():
    config = film.FiLMConfig()
    shapes = jax.eval_shape(lambda k: film.init_generator(k, config), KEY)
    out = jax.eval_shape(lambda p, c: film.generator_apply(p, c), shapes, jax.ShapeDtypeStruct((2, 240, 300),
                                                                                               jnp.float32))
    assert out.shape == (2, 2048)
    assert style_models.tree_size(shapes) == film.generator_size(config) == 39_214_592
    gamma1, beta1, gamma2, beta2 = lpn.split_film(jnp.zeros((2, 2048)), 512)
    assert gamma1.shape == beta2.shape == (2, 512)


def test_generator_matches_numpy():
    params = film.init_generator(KEY, SMALL_FILM)
    params = jax.tree.map(lambda v: v + 0.1 * jax.random.normal(jax.random.PRNGKey(3), v.shape), params)
    clips = jax.random.normal(jax.random.PRNGKey(1), (2, 16, 6))
    out = film.generator_apply(params, clips)
    for i in range(2):
        np.testing.assert_allclose(out[i], np_generator(params, np.asarray(clips[i], np.float64)), rtol=1e-4,
                                   atol=1e-5)


def test_generator_rejects_wrong_clip_shapes():
    params = film.init_generator(KEY, SMALL_FILM)
    with pytest.raises(ValueError, match="frames"):
        film.generator_apply(params, jnp.zeros((1, 15, 6)))
    with pytest.raises(ValueError, match=r"\(B, frames, 6\)"):
        film.generator_apply(params, jnp.zeros((1, 16, 5)))


def test_style_vectors_and_interpolation():
    params = film.init_generator(KEY, SMALL_FILM)
    clips = np.asarray(jax.random.normal(jax.random.PRNGKey(1), (5, 16, 6)))
    vectors = film.style_vectors(params, clips, np.array([0, 0, 1, 1, 1]), 2)
    per_clip = np.asarray(film.generator_apply(params, clips))
    np.testing.assert_allclose(vectors[1], per_clip[2:].mean(0), rtol=1e-5, atol=1e-6)
    mid = film.interpolate(vectors, [0.25, 0.75])
    np.testing.assert_allclose(mid, 0.25 * vectors[0] + 0.75 * vectors[1], rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="barycentric"):
        film.interpolate(vectors, [0.5, 0.6])
    with pytest.raises(ValueError, match="no clip"):
        film.style_vectors(params, clips, np.zeros(5, int), 2)


# --- the seven models ---------------------------------------------------------------------------

PAPER_COUNTS = {  # Table 2: A.S.N., S.M.N., P.S.R. (the FiLM S.M.N. is the one jaxstyle does not reproduce)
    "PFNN One-hot": (2_436_380, 194_560, 2048), "LPN One-hot": (4_935_928, 389_120, 4096),
    "PFNN Resad": (2_436_380, 2_978_440, 31_352), "LPN Resad": (4_935_928, 24_952_320, 262_656),
    "PFNN FiLM": (2_436_380, 35_668_530, 2048), "MANN FiLM": (4_870_392, 35_668_530, 2048),
    "LPN FiLM": (4_935_928, 35_668_530, 2048)}


@pytest.mark.parametrize("name", list(style_models.TABLE2))
def test_parameter_counts_match_the_formulas_and_table_2(name):
    config = StyleModelConfig.paper(name)
    shapes = jax.eval_shape(lambda k: style_models.init_model(k, config), KEY)
    counts = style_models.parameter_counts(config)
    assert counts["synthesis"] == style_models.tree_size([shapes["synthesis"], shapes.get("gating", [])])
    assert counts["style_network"] == style_models.tree_size(shapes["style"])
    asn, smn, psr = PAPER_COUNTS[name]
    assert counts["synthesis"] == asn and counts["per_style"] == psr
    if config.modulation == "film":
        assert counts["style_network"] == film.generator_size() != smn
    else:
        assert counts["style_network"] == smn
        per = [v.shape[1:] for v in jax.tree.leaves(shapes["style"])]  # one style's row of the tables
        assert sum(int(np.prod(s)) for s in per) == psr


def _style_input(params, config, n):
    if config.modulation == "film":
        return film.generator_apply(params["style"]["generator"], jnp.ones((n, 16, 6)))
    return style_models.style_runtime(params, config, 1)


def _gate(config, n):
    if config.backbone == "pfnn":
        return jnp.linspace(0, 0.9, n)
    return jax.random.normal(jax.random.PRNGKey(5), (n, config.gating_input))


# the slowest three (about 80 s together) run with -m slow; the default run keeps one of each backbone and modulation
_SLOW_MODELS = {("lpn", "onehot"), ("pfnn", "onehot"), ("pfnn", "resad")}


@pytest.mark.parametrize("backbone,modulation", [pytest.param(*m, marks=pytest.mark.slow) if m in _SLOW_MODELS else m
                                                 for m in style_models.TABLE2.values()])
def test_every_model_runs_and_its_gradients_pass_finite_differences(backbone, modulation):
    config = small_config(backbone, modulation)
    params = style_models.init_model(KEY, config)
    params = jax.tree.map(lambda v: v + 0.05 * jax.random.normal(jax.random.PRNGKey(9), v.shape), params)
    x, g = jax.random.normal(jax.random.PRNGKey(1), (4, 10)), _gate(config, 4)
    y = jax.random.normal(jax.random.PRNGKey(2), (4, 9))
    z = style_models.model_apply(params, config, x, g, _style_input(params, config, 4))
    assert z.shape == (4, 9) and np.isfinite(np.asarray(z)).all()

    def f(p):
        return jnp.mean((style_models.model_apply(p, config, x, g, _style_input(p, config, 4)) - y) ** 2)

    with jax.enable_x64(True):
        p64 = jax.tree.map(lambda v: jnp.asarray(v, jnp.float64), params)
        check_grads(jax.jit(f), (p64,), order=1, modes=["rev"], eps=1e-4, atol=1e-4, rtol=1e-3)


def test_one_hot_tables_interpolate_and_styles_differ():
    config = small_config("lpn", "onehot")
    params = style_models.init_model(KEY, config)
    x, g = jax.random.normal(jax.random.PRNGKey(1), (4, 10)), _gate(config, 4)
    t0, t1 = (style_models.style_runtime(params, config, s) for s in (0, 1))
    z0, z1 = (style_models.model_apply(params, config, x, g, t) for t in (t0, t1))
    assert float(jnp.abs(z0 - z1).max()) > 1e-4
    half = style_models.model_apply(params, config, x, g, 0.5 * t0 + 0.5 * t1)
    assert np.isfinite(np.asarray(half)).all()


def test_dropout_rate_is_an_array_and_vmaps():
    config = small_config()
    params = style_models.init_model(KEY, config)
    x, g = jax.random.normal(jax.random.PRNGKey(1), (4, 10)), _gate(config, 4)
    st = _style_input(params, config, 4)
    run = jax.vmap(lambda r: style_models.model_apply(params, config, x, g, st, key=KEY, dropout_rate=r))
    out = run(jnp.array([0.0, 0.5]))
    np.testing.assert_allclose(out[0], style_models.model_apply(params, config, x, g, st), rtol=1e-6, atol=1e-6)
    assert float(jnp.abs(out[1] - out[0]).max()) > 1e-4


def test_bad_configs_are_refused():
    with pytest.raises(ValueError, match="backbone"):
        StyleModelConfig(backbone="rnn")
    with pytest.raises(ValueError, match="modulation"):
        StyleModelConfig(modulation="adain")
    with pytest.raises(ValueError, match="4 x hidden_size"):
        StyleModelConfig(hidden_size=256)
    with pytest.raises(KeyError, match="Table 2"):
        StyleModelConfig.paper("LPN AdaIN")


# --- training, testing and fine-tuning on synthetic data ---------------------------------------

def synthetic_data(num_styles=3, rows=96, clips=4, seed=0) -> styledata.StyleData:
    """Random rows whose outputs depend on the inputs and the style, 3 bones of positions."""
    rng = np.random.default_rng(seed)
    n = num_styles * rows
    x = rng.normal(size=(n, 10)).astype(np.float32)
    style = np.repeat(np.arange(num_styles), rows)
    w = rng.normal(size=(10, 9)) / 3
    y = (np.tanh(x @ w) + 0.5 * style[:, None]).astype(np.float32)
    gate = rng.normal(size=(n, 4)).astype(np.float32)
    clip_arr = np.concatenate([rng.normal(loc=s, size=(clips, 16, 6)) for s in range(num_styles)]).astype(np.float32)
    rows_of = [np.flatnonzero(style == s) for s in range(num_styles)]
    bones = styledata.BonePositions(0, np.full(9, 0.1, np.float32), np.zeros(9, np.float32), (-1, 0, 1))
    return styledata.StyleData(x, y, gate, clip_arr, tuple(r[:64] for r in rows_of), tuple(r[64:80] for r in rows_of),
                               tuple(r[80:] for r in rows_of), tuple(np.arange(s * clips, (s + 1) * clips)
                                                                     for s in range(num_styles)),
                               tuple(f"s{s}" for s in range(num_styles)), bones)


@pytest.mark.parametrize("modulation", ["film", pytest.param("onehot", marks=pytest.mark.slow),
                                        pytest.param("resad", marks=pytest.mark.slow)])
def test_training_lowers_the_loss_and_resumes_exactly(tmp_path, modulation):
    data = synthetic_data()
    config = train_lpn.LPNTrainConfig(model=small_config("lpn", modulation), epochs=4, batch_size=8,
                                      learning_rate=3e-3, dropout_rate=0.1, log_every=5)
    before = train_lpn.evaluate(train_lpn.init_state(jax.random.PRNGKey(0), config).params, config.model, data,
                                "validation")
    full = train_lpn.train(data, config, tmp_path / "a", progress=False)
    after = train_lpn.evaluate(full.params, config.model, data, "validation")
    assert np.mean(after["mse"]) < 0.7 * np.mean(before["mse"])
    train_lpn.train(data, config, tmp_path / "b", progress=False, stop_after_epochs=2)
    resumed = train_lpn.train(data, config, tmp_path / "b", progress=False)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6), full.params,
                 resumed.params)
    log = (tmp_path / "b" / "log.csv").read_text().splitlines()
    assert log[0].startswith("epoch,train_loss,train_mse,train_bll,val_mse,val_bll") and len(log) == 5


def test_averaged_epochs_are_the_mean_of_the_last_epochs_weights(tmp_path):
    """``average_epochs=4`` over 5 epochs: the trained and the loaded parameters are the mean of
    epochs 2-5's, taken from a plain run stopped after every epoch (the same training); the
    paper's setting loads the last epoch's; without a run folder it is refused."""
    data = synthetic_data()
    plain = train_lpn.LPNTrainConfig(model=small_config(), epochs=5, batch_size=8, learning_rate=3e-3, log_every=5)
    per_epoch = [train_lpn.train(data, plain, tmp_path / "plain", progress=False, stop_after_epochs=1).params
                 for _ in range(5)]
    want = jax.tree.map(lambda *a: np.mean(np.stack([np.asarray(x, np.float64) for x in a[1:]]), axis=0), *per_epoch)
    averaged = dataclasses.replace(plain, average_epochs=4)
    trained = train_lpn.train(data, averaged, tmp_path / "avg", progress=False)
    loaded = train_lpn.load(tmp_path / "avg", averaged, data.styles)
    assert len(list((tmp_path / "avg" / "steps").iterdir())) == 4  # the 4 epochs averaged are kept
    for got in (trained.params, loaded.params):
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6), got, want)
    assert int(loaded.epoch) == 5
    last = train_lpn.load(tmp_path / "plain", plain, data.styles)
    jax.tree.map(lambda a, b: np.testing.assert_array_equal(a, b), last.params, per_epoch[-1])
    assert max(float(np.max(np.abs(np.asarray(a) - b))) for a, b in  # the mean differs from the last
               zip(jax.tree.leaves(per_epoch[-1]), jax.tree.leaves(want), strict=True)) > 1e-4
    with pytest.raises(ValueError, match="run directory"):
        train_lpn.train(data, averaged, progress=False)


def test_evaluate_matches_a_direct_computation():
    data = synthetic_data()
    config = small_config("lpn", "resad")
    params = style_models.init_model(KEY, config)
    out = train_lpn.evaluate(params, config, data, "test", chunk=5)
    rows = data.test_rows[2]
    pred = style_models.model_apply(params, config, data.x[rows], data.gate[rows],
                                    style_models.style_runtime(params, config, 2))
    pos = lambda y: (np.asarray(y)[:, :9] * 0.1).reshape(-1, 3, 3)  # noqa: E731
    np.testing.assert_allclose(out["mse"][2], np.mean((np.asarray(pred) - data.y[rows]) ** 2), rtol=1e-5)
    np.testing.assert_allclose(out["bll"][2], np_bone_length_loss(pos(pred), pos(data.y[rows]), [-1, 0, 1]),
                               rtol=1e-4)


def test_film_finetune_sweep_equals_single_runs_and_freezes_the_network():
    data = synthetic_data(num_styles=2, rows=96)
    config = small_config()
    params = style_models.init_model(KEY, config)
    ft = finetune.FiLMFinetuneConfig(epochs=2, batch_size=8, learning_rate=1e-3, rates=(0.0, 0.3))
    gens, per_step = finetune.finetune_film_sweep(params, config, data, ft, chunk_steps=5)  # 5+5+5+1 steps
    assert per_step.shape == (2, 2, 16) and np.isfinite(per_step).all()
    # style 1, rate index 1, run alone through the same scan: the sweep is a vmap of single runs
    batches, clips, mask = finetune.finetune_batches(data, ft)
    keys = jax.random.split(scan.pair_key(ft.seed, 1, 1), batches.shape[1])
    frozen = {k: v for k, v in params.items() if k != "style"}
    arrays = styledata.device_arrays(data)

    def loss_fn(gen, inputs, key):
        idx, clip = inputs
        return lpn_loss.batch_loss({**frozen, "style": {"generator": gen}}, config, arrays,
                                   lpn_loss.Batch(idx, 0, clip), key,
                                   lpn_loss.LossWeights(jnp.float32(0.3), jnp.float32(1.0)), data.bones)[0]

    gen0 = params["style"]["generator"]
    one, _, losses = jax.jit(lambda g: scan.train_scan(
        loss_fn, g, optax.adam(1e-3).init(g),
        scan.Steps((jnp.asarray(batches[1]), jnp.asarray(clips[1])), jnp.asarray(mask[1]), keys),
        optimizer=1e-3))(gen0)
    np.testing.assert_allclose(per_step[1, 1], losses, rtol=2e-5, atol=1e-6)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a[1, 1], b, rtol=1e-4, atol=1e-6), gens, one)
    changed = jax.tree.map(lambda a, b: float(jnp.abs(a[0, 0] - b).max()), gens, gen0)
    assert max(jax.tree.leaves(changed)) > 1e-4


# --- on real 100STYLE clips ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def real_data(mocap, tmp_path_factory):
    from jaxstyle.data import clips, datasets

    specs = [s for s in clips.specs_100style(mocap / "100style", styles=["Neutral", "Rushed"]) if s.gait == "FW"]
    ds = datasets.build_lpn_dataset(specs, cache_dir=tmp_path_factory.mktemp("cache"))
    skeleton = js.read_bvh(specs[0].path)
    return ds, skeleton


def test_style_data_positions_are_the_skeletons_bones_in_metres(real_data):
    from jaxstyle.motion.kinematics import bone_lengths

    ds, skeleton = real_data
    data = styledata.style_data(ds, skeleton)
    pos = np.asarray(lpn_loss.positions_m(jnp.asarray(data.y[:500]), data.bones))
    parents = np.asarray(data.bones.parents)
    joints = np.flatnonzero(parents[:skeleton.num_joints] >= 0)
    lengths = np.linalg.norm(pos[:, joints] - pos[:, parents[joints]], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(bone_lengths(skeleton)[joints] / 100.0, lengths.shape),
                               atol=2e-3)  # float32 features; 100STYLE is in centimetres
    assert float(lpn.bone_length_loss(pos, pos, data.bones.parents)) == 0.0
    # MANN gating input: the 4 end effectors' velocities, taken from the normalised input
    mann = styledata.style_data(ds, skeleton, backbone="mann")
    assert mann.gate.shape == (len(ds.inputs), 12)
    # PFNN backbones: the gate is each row's global phase; a dataset without one is refused
    pfnn = styledata.style_data(ds, skeleton, backbone="pfnn")
    np.testing.assert_array_equal(pfnn.gate[:, 0], np.asarray(ds.global_phase, np.float32))
    with pytest.raises(ValueError, match="global phase"):
        styledata.style_data(dataclasses.replace(ds, global_phase=np.zeros(0)), skeleton, backbone="pfnn")


def test_training_clips_lie_in_training_rows(real_data):
    ds, _ = real_data
    for style in ds.styles:
        train_clips = ds.clips_of_style(style, "train")
        assert 0 < len(train_clips) < len(ds.clips_of_style(style))
        for c in ds.clips_of_style(style):
            rows = (ds.clip == ds.clip_source[c]) & (ds.frame >= ds.clip_start[c]) & (ds.frame < ds.clip_start[c] + 240)
            assert ((ds.split[rows] == 0).all() and rows.any()) == (c in train_clips)
    with pytest.raises(KeyError, match="unknown style"):
        ds.clips_of_style("Zombie")


@pytest.mark.slow  # python -m pytest -m slow; the default run covers the same code more cheaply
def test_a_small_model_trains_on_real_clips(real_data):
    ds, skeleton = real_data
    data = styledata.style_data(ds, skeleton)
    mc = StyleModelConfig(num_styles=2, hidden_size=16, num_experts=2, gating_hidden=8,
                          generator=film.FiLMConfig(filters=4, width=5, hidden=16, film_size=64))
    config = train_lpn.LPNTrainConfig(model=mc, epochs=1, learning_rate=1e-3, log_every=40)
    before = train_lpn.evaluate(train_lpn.init_state(jax.random.PRNGKey(0), config).params, mc, data, "validation")
    state = train_lpn.train(data, config, progress=False)
    after = train_lpn.evaluate(state.params, mc, data, "validation")
    assert np.isfinite(after["mse"]).all() and np.mean(after["mse"]) < np.mean(before["mse"])


def test_table2_script_prints_the_paper_counts():
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "experiments" / "mason2022_table2.py"
    out = subprocess.run([sys.executable, str(script), "--no-runtime"], capture_output=True, text=True, check=True,
                         timeout=300).stdout
    assert "| LPN FiLM | 4,935,928 | 4,935,928 | 39,214,592 | 35,668,530 | 2,048 | 2,048 |" in out
    assert "| PFNN Resad | 2,436,380 | 2,436,380 | 2,978,440 | 2,978,440 | 31,352 | 31,352 |" in out
    assert "LPN Resad S.M.N." not in out  # only the FiLM generator's count differs


@pytest.mark.slow  # trains two tiny models and drives them: about 2 min
def test_table2_script_trains_tests_and_drives_the_models(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from jaxstyle.data import procedural

    root = procedural.write_dataset(tmp_path / "procedural", styles=["Neutral", "Crouched"], gaits=("FW",),
                                    seconds=12, progress=False)
    script = Path(__file__).resolve().parents[1] / "experiments" / "mason2022_table2.py"
    out = subprocess.run([sys.executable, str(script), "--train", "--data", str(root), "--styles", "Neutral,Crouched",
                          "--models", "PFNN One-hot,LPN FiLM", "--epochs", "1", "--hidden", "16",
                          "--generator-hidden", "16", "--filters", "4", "--out", str(tmp_path / "t2"),
                          "--no-progress"], capture_output=True, text=True, check=True, timeout=900).stdout
    assert "| PFNN One-hot | 1 | max epochs |" in out and "| LPN FiLM | 1 | max epochs |" in out
    assert out.count("| LPN FiLM | ") == 4  # the training, test and two closed-loop tables
    assert "LPN FiLM lowest median raw skating / capture: " in out
    assert "paper: every FiLM model below every one-hot / adapter model: " in out
    assert (tmp_path / "t2" / "table2.md").is_file() and (tmp_path / "t2" / "closed_loop.csv").is_file()
