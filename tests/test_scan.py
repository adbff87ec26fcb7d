"""The shared drivers of jaxstyle.train.scan on a tiny linear problem: the (set, rate) grid equals
a loop of single runs, frozen values get no update, chunks and masks change nothing, and the
epoch loop resumes exactly."""

from __future__ import annotations

import csv
import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxstyle.train import defaults, scan
from tests.toy_fit import toy_fit

D, N, B, LR = 4, 40, 5, 0.05


@dataclasses.dataclass(frozen=True)
class LinearLoss:
    """``mean((X[idx] @ dropout(w) + b - Y[idx])^2) + lam |w|^2``; ``b`` and the data are frozen."""

    def __call__(self, w, frozen, idx, key, rate, hparams):
        keep = jax.random.bernoulli(key, 1.0 - rate, w.shape)
        wd = jnp.where(keep, w / (1.0 - rate), 0.0)
        pred = frozen["X"][idx] @ wd + frozen["b"]
        return jnp.mean((pred - frozen["Y"][idx]) ** 2) + hparams["lam"] * jnp.sum(w ** 2)


def _problem(seed=0):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(N, D)).astype(np.float32)
    Y = (X @ rng.normal(size=D) + 0.5).astype(np.float32)
    frozen = {"X": jnp.asarray(X), "Y": jnp.asarray(Y), "b": jnp.float32(0.3)}
    rows = [np.arange(0, 25), np.arange(25, 40)]  # two sets, ragged: 5 and 3 batches per epoch
    batches, mask = scan.sweep_batches(rows, epochs=3, batch_size=B, seed=seed)
    rates = (0.1, 0.4)
    keys = jnp.stack([jnp.stack([jax.random.split(scan.pair_key(seed, s, r), batches.shape[1])
                                 for r in range(2)]) for s in range(2)])
    w0 = jnp.asarray(rng.normal(size=(2, 2, D)).astype(np.float32))
    return frozen, batches, mask, rates, keys, w0, {"lam": jnp.float32(0.01)}


def _loop(frozen, idx_T, mask_T, keys_T, rate, w, hparams):
    """A plain Python loop of optax Adam steps on ``w`` alone (the reference)."""
    opt = optax.adam(LR)
    state = opt.init(w)
    grad = jax.jit(jax.value_and_grad(lambda w, idx, k: LinearLoss()(w, frozen, idx, k, rate, hparams)))
    losses = []
    for idx, real, k in zip(idx_T, mask_T, keys_T, strict=True):
        if not real:
            losses.append(np.nan)
            continue
        value, g = grad(w, jnp.asarray(idx), k)
        updates, state = opt.update(g, state)
        w = optax.apply_updates(w, updates)
        losses.append(float(value))
    return w, np.array(losses)


def test_grid_equals_a_loop_of_single_runs_and_leaves_frozen_alone():
    frozen, batches, mask, rates, keys, w0, hp = _problem()
    before = jax.tree.map(np.array, frozen)
    w, losses = scan.grid_sweep(LinearLoss(), w0, frozen, scan.Steps(batches, mask, keys), rates, optimizer=LR,
                                hparams=hp)
    assert w.shape == (2, 2, D) and losses.shape == (2, 2, batches.shape[1])
    for s in range(2):
        for r in range(2):
            want_w, want_losses = _loop(frozen, batches[s], mask[s], keys[s, r], jnp.float32(rates[r]), w0[s, r], hp)
            np.testing.assert_allclose(w[s, r], want_w, rtol=1e-5, atol=1e-5)
            np.testing.assert_allclose(losses[s, r], want_losses, rtol=1e-5, atol=1e-5)
            one, _, one_losses = scan.run_pair(LinearLoss(), w0[s, r], optax.adam(LR).init(w0[s, r]), frozen,
                                               scan.Steps(jnp.asarray(batches[s]), jnp.asarray(mask[s]), keys[s, r]),
                                               jnp.float32(rates[r]), hp, optimizer=LR)
            np.testing.assert_allclose(w[s, r], one, rtol=1e-5, atol=1e-5)
            np.testing.assert_allclose(losses[s, r], one_losses, rtol=1e-5, atol=1e-5)
    # the frozen tree got no update (its values are unchanged and the result is that of training
    # w alone), though its gradient is not zero: training b as well moves w differently
    for k in before:
        np.testing.assert_array_equal(before[k], np.asarray(frozen[k]))
    assert float(jax.grad(lambda b: LinearLoss()(w0[0, 0], {**frozen, "b": b}, jnp.arange(B), keys[0, 0, 0], 0.1,
                                                 hp))(frozen["b"])) != 0.0
    both = scan.run_pair(
        lambda t, fz, idx, k, r, h: LinearLoss()(t[0], {**fz, "b": t[1]}, idx, k, r, h), (w0[0, 0], frozen["b"]),
        optax.adam(LR).init((w0[0, 0], frozen["b"])), frozen,
        scan.Steps(jnp.asarray(batches[0]), jnp.asarray(mask[0]), keys[0, 0]), jnp.float32(rates[0]), hp,
        optimizer=LR)[0]
    assert np.abs(np.asarray(both[0]) - np.asarray(w[0, 0])).max() > 1e-4
    # the starting tree passed in is not consumed (the driver trains a copy)
    assert np.isfinite(np.asarray(w0)).all()


def test_masked_steps_change_nothing_and_chunks_give_the_same_result():
    frozen, batches, mask, rates, keys, w0, hp = _problem(1)
    w, losses = scan.grid_sweep(LinearLoss(), w0, frozen, scan.Steps(batches, mask, keys), rates, optimizer=LR,
                                hparams=hp)
    real = int(mask[1].sum())
    assert real < batches.shape[1] and np.isnan(np.asarray(losses[1, :, real:])).all()
    assert np.isfinite(np.asarray(losses[1, :, :real])).all()
    short, _ = scan.grid_sweep(LinearLoss(), w0[1:], frozen,
                               scan.Steps(batches[1:, :real], mask[1:, :real], keys[1:, :, :real]), rates,
                               optimizer=LR, hparams=hp)
    np.testing.assert_allclose(w[1], short[0], rtol=1e-5, atol=1e-6)
    chunked, chunked_losses = scan.grid_sweep(LinearLoss(), w0, frozen, scan.Steps(batches, mask, keys), rates,
                                              optimizer=LR, hparams=hp, run=scan.GridRun(chunk_steps=4))
    np.testing.assert_allclose(chunked, w, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(chunked_losses, losses, rtol=1e-5, atol=1e-6)
    # the rate is traced: another rate, the same compiled program, another result
    other, _ = scan.grid_sweep(LinearLoss(), w0, frozen, scan.Steps(batches, mask, keys), (0.0, 0.4),
                               optimizer=LR, hparams=hp)
    assert np.abs(np.asarray(other[:, 0] - w[:, 0])).max() > 1e-4
    np.testing.assert_allclose(other[:, 1], w[:, 1], rtol=1e-6)


def _fit(tmp_path, name, **kw):
    """The toy run of tests/toy_fit.py in ``tmp_path/name``, logging a made-up column."""
    return toy_fit(tmp_path / name, {"run": name},
                   end_epoch=lambda e, s, out: {"train_loss": f"{out.mean():.6f}", "seconds": None, "w0": "x"}, **kw)


def test_fit_resumes_exactly_and_logs_every_epoch(tmp_path):
    straight = _fit(tmp_path, "a")
    assert int(straight.epoch) == 3
    _fit(tmp_path, "b", stop_after_epochs=1)
    resumed = _fit(tmp_path, "b")
    np.testing.assert_allclose(straight.w, resumed.w, rtol=1e-6)
    with open(tmp_path / "b" / "log.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["epoch", "train_loss", "seconds", "w0"] and [r[0] for r in rows[1:]] == ["1", "2", "3"]
    with pytest.raises(ValueError, match="different config"):
        scan.fit(straight, 3, None, directory=tmp_path / "a", run_config={"run": "other"})


def test_fit_stops_on_a_non_finite_loss():
    def plan_epoch(epoch):
        return 2, lambda state, a, b: (state, np.full(b - a, np.nan))

    class Epochs(NamedTuple):
        epoch: jax.Array

    with pytest.raises(FloatingPointError, match="epoch 1"):
        scan.fit(Epochs(jnp.zeros((), jnp.int32)), 2, plan_epoch, options=scan.FitOptions(progress=False))


def test_default_rates_are_the_2018_ones():
    from jaxstyle.mason2018 import fewshot

    assert defaults.DEFAULT_RATES == (0.3, 0.5, 0.7) == fewshot.SweepConfig().rates


def test_row_buckets_are_powers_of_two_then_eighths():
    assert [scan.row_bucket(n) for n in (0, 1, 2, 3, 600, 1024, 1025, scan.SMALL_ROWS)] == \
        [1, 1, 2, 4, 1024, 1024, 2048, scan.SMALL_ROWS]
    for n in (scan.SMALL_ROWS + 1, 20_000, 100_003, 1_000_000):
        bucket = scan.row_bucket(n)
        step = 1 << (n.bit_length() - 3)
        assert n <= bucket < n + step and bucket % step == 0 and bucket <= 1.25 * n
    x, phase = np.arange(30.0).reshape(10, 3), np.arange(10.0)
    px, pphase = scan.pad_rows(x, phase)
    assert px.shape == (16, 3) and pphase.shape == (16,)
    np.testing.assert_array_equal(px[:10], x)
    np.testing.assert_array_equal(pphase[:10], phase)
    assert not np.asarray(px[10:]).any() and not np.asarray(pphase[10:]).any()
