"""Train a 2018 PFNN base model with one CP adapter per style on the shared sample.

    python experiments/mason2018_base.py [--epochs 300] [--batch-size 8] [--out runs/mason2018_base] [--adapter cp]

Data: the 8 Xia styles (mirrored) plus the PFNN captures (their hand-cleaned phases) from
$JAXSTYLE_MOCAP, at 60 fps, clips shorter than the 2 s trajectory window left out. Prints the
per-style validation loss against the loss of predicting the mean, and the training time. The
sample is small (about 1,000 training rows, 8 in the smallest style), hence batches of 8 and more
epochs than the paper's 25 over its 11,552 frames per style.
Re-running the same command resumes from the last checkpoint in --out.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np

import jaxstyle as js
from jaxstyle.data import clips, datasets
from jaxstyle.mason2018.train import TrainConfig, data_from_dataset, mean_predictor_losses, train, validation_losses
from jaxstyle.nn import pfnn


@dataclasses.dataclass(frozen=True)
class Config:
    epochs: int = 300
    batch_size: int = 8  # the shared Xia "childlike" style has only 8 training rows (4 frames + mirrors)
    adapter: str = "cp"
    out: Path = Path("runs/mason2018_base")
    cache: Path = Path("runs/cache")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=Config.epochs)
    parser.add_argument("--batch-size", type=int, default=Config.batch_size)
    parser.add_argument("--adapter", default=Config.adapter, choices=pfnn.ADAPTER_KINDS)
    parser.add_argument("--out", type=Path, default=Config.out)
    args = parser.parse_args()
    mocap = js.mocap_dir()
    specs = clips.specs_xia(mocap / "xia") + clips.specs_pfnn(mocap / "pfnn_excerpt")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dataset = datasets.build_pfnn_dataset(specs, cache_dir=Config.cache, skip_short=True)
    data = data_from_dataset(dataset)
    config = TrainConfig(model=pfnn.PFNNConfig(adapter=args.adapter), epochs=args.epochs, batch_size=args.batch_size)
    print(f"{len(dataset.styles)} styles, {sum(map(len, data.train_rows))} training rows, "
          f"{sum(map(len, data.val_rows))} validation rows; {args.adapter} adapters; {args.epochs} epochs")
    t0 = time.perf_counter()
    state = train(data, config, args.out)
    seconds = time.perf_counter() - t0
    val = validation_losses(state.params, state.adapters, data)
    mean = mean_predictor_losses(data)
    print(f"\ntrained in {seconds:.0f} s (this call)\n")
    print("| style | validation MSE | mean predictor | ratio |\n|---|---|---|---|")
    for s, v, m, rows in zip(data.styles, val, mean, data.val_rows, strict=True):
        if len(rows) == 0:
            print(f"| {s} | (no validation rows) | | |")
            continue
        print(f"| {s} | {v:.3f} | {m:.3f} | {v / m:.2f} |")
    ok = np.isfinite(val)
    v, m = np.mean(val[ok]), np.mean(mean[ok])
    print(f"| **all** | **{v:.3f}** | {m:.3f} | {v / m:.2f} |")


if __name__ == "__main__":
    main()
