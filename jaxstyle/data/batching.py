"""Train/validation/test splits and style-balanced minibatches, as index arrays for ``lax.scan``.

Both papers train with minibatches drawn from **one style** each, cycling through the styles in a
fixed order, an epoch being one pass over the smallest style (2018: 8 styles truncated to the
smallest; 2022: round robin over 95 styles). :func:`balanced_batches` returns the whole epoch as
an integer array ``(steps, batch)`` of row indices, so a training loop gathers rows inside
``lax.scan`` instead of iterating a Python generator.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

SPLITS = ("train", "validation", "test")


def contiguous_split(num_rows: int, fractions: tuple[float, float, float] = (0.8, 0.1, 0.1), *,
                     gap: int = 0, seed: int = 0) -> dict[str, np.ndarray]:
    """Row indices of one clip split into three contiguous blocks.

    The blocks keep the clip's order, so neighbouring frames (which share most of a trajectory
    window) never end up on both sides; ``gap`` rows are dropped at each boundary between blocks
    (use the trajectory window length to remove any overlap). ``seed`` picks the order of the
    three blocks along the clip, so validation and test data are not always its end.
    """
    fractions = tuple(float(f) for f in fractions)
    if len(fractions) != 3 or min(fractions) < 0 or not np.isclose(sum(fractions), 1.0):
        raise ValueError(f"fractions must be 3 non-negative numbers summing to 1, got {fractions}")
    order = np.random.default_rng(seed).permutation(3)
    usable = max(num_rows - 2 * gap, 0)
    sizes = np.floor(np.array(fractions) * usable).astype(int)
    sizes[0] += usable - sizes.sum()  # rounding leftovers go to training
    out, start = {}, 0
    for k in order:
        out[SPLITS[k]] = np.arange(start, start + sizes[k])
        start += sizes[k] + gap
    return {name: out[name] for name in SPLITS}


def balanced_batches(rows_per_style: Sequence[np.ndarray], batch_size: int, *, seed: int = 0,
                     mirror_of: np.ndarray | None = None) -> np.ndarray:
    """One epoch of style-balanced minibatches: ``(steps, batch_size)`` global row indices.

    Args:
      rows_per_style: for each style, the indices (into the dataset's rows) of its training rows.
      batch_size: rows per batch, all from one style.
      seed: shuffles each style's rows (a different seed per epoch gives a new epoch).
      mirror_of: optional ``(num_rows,)`` map from a row to its mirrored twin. Then each batch is
        ``batch_size // 2`` rows followed by their mirrors (the 2018 paper's 16 + 16).

    Styles take turns in the given order: batch ``k`` comes from style ``k % num_styles``. Every
    style contributes ``smallest // per_batch`` batches, where ``smallest`` is the row count of the
    smallest style, so an epoch is one pass over the smallest style.
    """
    if not len(rows_per_style):
        raise ValueError("no styles")
    per_batch = batch_size // 2 if mirror_of is not None else batch_size
    if per_batch < 1 or (mirror_of is not None and batch_size % 2):
        raise ValueError(f"batch_size {batch_size} cannot be split into halves" if mirror_of is not None
                         else f"batch_size must be positive, got {batch_size}")
    counts = [len(r) for r in rows_per_style]
    smallest = min(counts)
    if smallest < per_batch:
        style = int(np.argmin(counts))
        raise ValueError(f"style {style} has {smallest} training rows, fewer than one batch of {per_batch}")
    steps = smallest // per_batch
    rng = np.random.default_rng(seed)
    per_style = []
    for rows in rows_per_style:
        chosen = rng.permutation(np.asarray(rows))[:steps * per_batch].reshape(steps, per_batch)
        if mirror_of is not None:
            chosen = np.concatenate([chosen, np.asarray(mirror_of)[chosen]], axis=1)
        per_style.append(chosen)
    # interleave: style 0 batch 0, style 1 batch 0, ..., style 0 batch 1, ...
    return np.stack(per_style, axis=1).reshape(steps * len(rows_per_style), batch_size)
