"""Progress bars and per-epoch CSV logs shared by the training loops.

A run folder's ``log.csv`` has one row per finished epoch. A resumed run first drops the rows of
epochs after its last checkpoint (:func:`truncate_log`), so the log always matches the weights.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Mapping


def progress_bar(total: int, desc: str, enabled: bool):
    """A tqdm bar of ``total`` steps, or ``None`` when not ``enabled``."""
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="step", leave=False)


def truncate_log(path: Path, epoch: int) -> None:
    """Keep the log rows of epochs up to ``epoch`` (those a resumed run has checkpoints for)."""
    if not path.is_file():
        return
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    keep = rows[:1] + [r for r in rows[1:] if int(r[0]) <= epoch]
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        csv.writer(f).writerows(keep)
    tmp.replace(path)


def append_log(path: Path, row: Mapping[str, object]) -> None:
    """Append one row (its first column the epoch); a new file gets the keys as its header."""
    new = not path.is_file()
    with open(path, "a", newline="") as f:
        writer = csv.writer(f)
        if new:
            writer.writerow(list(row))
        writer.writerow(list(row.values()))
