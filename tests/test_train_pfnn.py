"""Base training: learning, checkpoint/resume equivalence, logs, data parallelism."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from jaxstyle.mason2018.train import TrainConfig, TrainData, mean_predictor_losses, train, validation_losses
from jaxstyle.nn import pfnn

SMALL = pfnn.PFNNConfig(input_size=6, hidden_size=16, output_size=5, rank=4)


def synthetic(seed: int = 0, rows: int = 400) -> TrainData:
    """Two styles; y depends on x, the phase and the style, so adapters have something to learn."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(2 * rows, 6)).astype(np.float32)
    phase = rng.uniform(size=2 * rows).astype(np.float32)
    style = np.repeat([0, 1], rows)
    w = rng.normal(size=(6, 5)) / 3
    y = (x @ w + np.sin(2 * np.pi * phase)[:, None] + np.where(style[:, None] == 1, 0.8, -0.8)).astype(np.float32)
    y = (y - y.mean(0)) / y.std(0)
    train_rows = tuple(np.arange(s * rows, s * rows + int(0.8 * rows)) for s in (0, 1))
    val_rows = tuple(np.arange(s * rows + int(0.8 * rows), (s + 1) * rows) for s in (0, 1))
    return TrainData(x, y, phase, train_rows, val_rows, ("a", "b"))


CONFIG = TrainConfig(model=SMALL, epochs=2, batch_size=16, learning_rate=3e-3, dropout_rate=0.1, log_every=7)


def test_training_beats_the_mean_predictor():
    data = synthetic()
    config = TrainConfig(model=SMALL, epochs=6, batch_size=16, learning_rate=3e-3, dropout_rate=0.0)
    state = train(data, config, progress=False)
    val = validation_losses(state.params, state.adapters, data)
    assert (val < 0.3 * mean_predictor_losses(data)).all(), val


def test_resume_gives_the_uninterrupted_result(tmp_path):
    data = synthetic()
    straight = train(data, CONFIG, tmp_path / "a", progress=False)
    train(data, CONFIG, tmp_path / "b", progress=False, stop_after_epochs=1)  # "interrupted" after epoch 1
    with open(tmp_path / "b" / "log.csv") as f:
        assert len(list(csv.reader(f))) == 2
    resumed = train(data, CONFIG, tmp_path / "b", progress=False)
    for a, b in zip(jax.tree.leaves(straight.params), jax.tree.leaves(resumed.params), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    with open(tmp_path / "b" / "log.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["epoch"] for r in rows] == ["1", "2"] and "val_b" in rows[0]
    assert (tmp_path / "b" / "config.json").is_file()
    with pytest.raises(ValueError, match="different config"):
        train(data, TrainConfig(model=SMALL, epochs=3), tmp_path / "b", progress=False)


@pytest.mark.slow  # python -m pytest -m slow; the default run covers the same code more cheaply
def test_data_parallel_matches_one_device(tmp_path):
    """Runs in a subprocess with 2 forced host devices (the flag must precede importing jax)."""
    script = textwrap.dedent(f"""
        import sys, numpy as np, jax
        sys.path.insert(0, {str(os.getcwd())!r})
        assert jax.device_count() == 2, jax.devices()
        from tests.test_train_pfnn import synthetic, CONFIG
        from jaxstyle.mason2018.train import train
        data = synthetic()
        one = train(data, CONFIG, progress=False)
        two = train(data, CONFIG, progress=False, data_parallel=True)
        for a, b in zip(jax.tree.leaves(one.params), jax.tree.leaves(two.params)):
            np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
        print("ok")
    """)
    env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-3000:]


@pytest.mark.slow  # 30 s; the default run trains on the shared clips too: tests/test_synthesis.py's trained_pfnn
# (the Neutral captures, then driven along paths) and `jaxstyle demo` on them (tests/test_cli.py)
def test_base_model_on_the_shared_sample_learns(mocap):
    """The 8 Xia styles + the PFNN captures, full-size network, a short run: validation loss
    well below predicting the mean (experiments/mason2018_base.py runs the long version)."""
    import warnings

    from jaxstyle.data import clips, datasets
    from jaxstyle.mason2018.train import data_from_dataset

    specs = clips.specs_xia(mocap / "xia") + clips.specs_pfnn(mocap / "pfnn_excerpt")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dataset = datasets.build_pfnn_dataset(specs, skip_short=True)
    data = data_from_dataset(dataset)
    assert len(data.styles) == 9
    state = train(data, TrainConfig(epochs=40, batch_size=8), progress=False)
    val, mean = validation_losses(state.params, state.adapters, data), mean_predictor_losses(data)
    ok = np.isfinite(val)
    assert np.mean(val[ok]) < 0.5 * np.mean(mean[ok]), (val, mean)


def test_finetune_improves_a_new_adapter_with_the_base_frozen():
    from jaxstyle.mason2018.train import finetune_adapter

    data = synthetic(1)
    state = train(data, CONFIG, progress=False)
    fresh = pfnn.init_adapter(jax.random.PRNGKey(9), SMALL)
    config = TrainConfig(model=SMALL, epochs=30, batch_size=16, learning_rate=3e-3, dropout_rate=0.0)
    tuned = finetune_adapter(state.params, fresh, data, 1, config)
    stacked = jax.tree.map(lambda v: v[None], tuned)
    before = validation_losses(state.params, jax.tree.map(lambda v: v[None], fresh), data._replace(
        val_rows=(data.val_rows[1],)))
    after = validation_losses(state.params, stacked, data._replace(val_rows=(data.val_rows[1],)))
    assert after[0] < 0.5 * before[0]
