"""Feature normalisation shared by all styles (both papers' reference code).

One mean and standard deviation are computed over the rows of **all** training styles, never per
style: style information lives in the statistics. Within each feature group (trajectory
positions, joint velocities, ...) the standard deviation is replaced by the group's average, so
the relative scale of the coordinates inside a group is kept (Holden et al. 2017, and Mason et
al.'s code). New few-shot styles are normalised with these base statistics.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

STD_FLOOR = 1e-6  # a group that never varies is divided by this, not by 0


@dataclass(frozen=True)
class Normaliser:
    """``mean`` and ``std`` of shape ``(D,)``; ``apply`` and ``invert`` work on ``(..., D)``."""

    mean: np.ndarray
    std: np.ndarray

    def apply(self, x):
        return (x - self.mean) / self.std

    def invert(self, z):
        return z * self.std + self.mean

    def save(self, path: str | os.PathLike) -> None:
        """Write ``mean`` and ``std`` to an ``.npz`` file atomically (write, then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as f:
            np.savez(f, mean=self.mean, std=self.std)
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Normaliser":
        with np.load(path) as data:
            return cls(data["mean"], data["std"])


def fit_normaliser(arrays: Sequence[np.ndarray], groups: Mapping[str, slice] | None = None) -> Normaliser:
    """Statistics over the rows of all ``arrays`` (each ``(N_i, D)``, e.g. one per style).

    ``groups`` maps a name to a slice of the feature axis; each slice's std becomes the mean of
    its per-dimension stds. Dimensions outside every group keep their own std.
    """
    if not arrays:
        raise ValueError("no arrays to compute statistics from")
    dims = {a.shape[-1] for a in arrays}
    if len(dims) != 1:
        raise ValueError(f"arrays have different feature sizes {sorted(dims)}")
    dim = dims.pop()
    rows = np.concatenate([np.asarray(a, dtype=np.float64).reshape(-1, dim) for a in arrays])
    if not np.isfinite(rows).all():
        bad = np.flatnonzero(~np.isfinite(rows).all(axis=0))
        raise ValueError(f"features contain NaN or infinity (columns {bad[:10].tolist()})")
    mean, std = rows.mean(axis=0), rows.std(axis=0)
    for sl in (groups or {}).values():
        std[sl] = std[sl].mean()
    return Normaliser(mean, np.maximum(std, STD_FLOOR))
