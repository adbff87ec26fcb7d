"""Shared normalisation, contiguous splits and style-balanced batches."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxstyle.data.batching import balanced_batches, contiguous_split
from jaxstyle.data.normalise import Normaliser, fit_normaliser


def test_normaliser_pools_styles_and_shares_group_std(tmp_path):
    rng = np.random.default_rng(0)
    a = rng.normal(0.0, [1.0, 2.0, 3.0, 4.0], size=(500, 4))
    b = rng.normal(5.0, [1.0, 2.0, 3.0, 4.0], size=(300, 4))
    norm = fit_normaliser([a, b], groups={"g": slice(0, 2)})
    pooled = np.concatenate([a, b])
    np.testing.assert_allclose(norm.mean, pooled.mean(0))  # one mean over all styles, not per style
    np.testing.assert_allclose(norm.std[:2], pooled.std(0)[:2].mean())
    np.testing.assert_allclose(norm.std[2:], pooled.std(0)[2:])
    np.testing.assert_allclose(norm.invert(norm.apply(pooled)), pooled)
    norm.save(tmp_path / "stats.npz")
    again = Normaliser.load(tmp_path / "stats.npz")
    np.testing.assert_array_equal(again.mean, norm.mean)
    assert not list(tmp_path.glob("*.tmp"))


def test_normaliser_errors_and_constant_columns():
    with pytest.raises(ValueError, match="NaN"):
        fit_normaliser([np.array([[1.0, np.nan]])])
    with pytest.raises(ValueError, match="different feature sizes"):
        fit_normaliser([np.zeros((2, 3)), np.zeros((2, 4))])
    norm = fit_normaliser([np.ones((10, 2))])
    assert np.isfinite(norm.apply(np.ones((1, 2)))).all()


@pytest.mark.parametrize("seed", range(6))
def test_contiguous_split_blocks_and_gaps(seed):
    split = contiguous_split(1000, (0.8, 0.1, 0.1), gap=60, seed=seed)
    allrows = np.concatenate(list(split.values()))
    assert len(np.unique(allrows)) == len(allrows) == 1000 - 120
    for rows in split.values():
        np.testing.assert_array_equal(np.diff(rows), 1)  # one contiguous block
    blocks = sorted((rows[0], rows[-1]) for rows in split.values())
    assert all(b[0] - a[1] - 1 == 60 for a, b in zip(blocks, blocks[1:], strict=False))  # gaps between blocks
    assert len(split["validation"]) == len(split["test"]) == 88


def test_balanced_batches_one_style_each_in_cyclic_order():
    sizes = [70, 45, 100]
    offsets = np.cumsum([0] + sizes)
    rows = [np.arange(offsets[s], offsets[s + 1]) for s in range(3)]
    style_of = np.repeat(np.arange(3), sizes)
    batches = balanced_batches(rows, 8, seed=1)
    assert batches.shape == (3 * (45 // 8), 8)
    styles = style_of[batches]
    assert (styles == styles[:, :1]).all()  # one style per batch
    np.testing.assert_array_equal(styles[:, 0], np.tile(np.arange(3), 45 // 8))  # fixed cyclic order
    for s in range(3):
        used = batches[styles[:, 0] == s].ravel()
        assert len(np.unique(used)) == len(used)  # no row twice within an epoch
    assert not np.array_equal(batches, balanced_batches(rows, 8, seed=2))


def test_half_mirrored_batches():
    rows = [np.arange(0, 40), np.arange(40, 80)]  # originals; mirrors are row + 80
    mirror_of = np.concatenate([np.arange(80, 160), np.arange(0, 80)])
    batches = balanced_batches(rows, 16, mirror_of=mirror_of)
    np.testing.assert_array_equal(batches[:, 8:], batches[:, :8] + 80)
    with pytest.raises(ValueError, match="halves"):
        balanced_batches(rows, 15, mirror_of=mirror_of)
    with pytest.raises(ValueError, match="fewer than one batch"):
        balanced_batches([np.arange(3), np.arange(50)], 8)


def test_batches_drive_a_scan():
    data = jnp.arange(30.0)[:, None]
    batches = jnp.asarray(balanced_batches([np.arange(0, 15), np.arange(15, 30)], 5))

    def step(total, idx):
        return total + data[idx].sum(), data[idx].mean()

    total, means = jax.lax.scan(step, 0.0, batches)
    assert float(total) == float(data.sum()) and means.shape == (6,)
