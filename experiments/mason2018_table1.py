"""Mason et al. 2018, Table 1: memory, training time and runtime of full, diagonal and CP adapters.

    python experiments/mason2018_table1.py [--epochs 100] [--repeats 200]

For each adapter kind, on the 234 -> 512 -> 512 -> 400 PFNN
(:func:`jaxstyle.mason2018.bench.adapter_cost`):

* memory of one new adapter in MB (2^20 bytes, float32): control points only / discretised into
  the runtime's 50 phase bins, measured from the arrays and checked against the formulas;
* mean training time per style: fine-tuning a new adapter (base frozen) for ``--epochs`` epochs
  in batches of 32 on each Xia style of the shared sample with at least 32 training rows, each
  timed after a compile run;
* runtime: one forward pass of one frame with the discretised tables, jitted, median of
  ``--repeats`` calls.

The paper's figures (Unity on an Intel i7-6700HQ; training on their own data and GPU) are
printed beside ours.
"""

from __future__ import annotations

import argparse
import os
import platform
import warnings

import jax

import jaxstyle as js
from jaxstyle.data import clips, datasets
from jaxstyle.mason2018 import bench as bench2018
from jaxstyle.mason2018.train import data_from_dataset
from jaxstyle.nn import pfnn

PAPER = {"full": ("4.01 / 50.1", "99", "0.0013"), "diagonal": ("0.016 / 0.20", "44", "0.0010"),
         "cp": ("0.126 / 0.131", "50", "0.0011")}
NAMES = {"full": "Full Adapter", "diagonal": "Diagonal Adapter", "cp": "CP Decomposition"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dataset = datasets.build_pfnn_dataset(clips.specs_xia(js.mocap_dir() / "xia"), skip_short=True)
    data = data_from_dataset(dataset)
    styles = [s for s, rows in enumerate(data.train_rows) if len(rows) >= 32]
    sizes = ", ".join(f"{data.styles[s]} {len(data.train_rows[s])}" for s in styles)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} "
          f"on {jax.devices()[0].platform}; styles with at least one batch of training rows: {sizes}\n")
    rows = [bench2018.adapter_cost(kind, data, styles, epochs=args.epochs, repeats=args.repeats)
            for kind in pfnn.ADAPTER_KINDS]
    print("| method | memory MB (ours) | memory MB (paper) | training s (ours) | training s (paper) "
          "| runtime s (ours) | runtime s (paper) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        paper = PAPER[r.kind]
        print(f"| {NAMES[r.kind]} | {r.memory_mb:.3f} / {r.table_mb:.3f} | {paper[0]} | {r.train_seconds:.1f} "
              f"| {paper[1]} | {r.runtime_seconds:.5f} | {paper[2]} |")
    print(f"\nmemory = formula for every kind; training = mean over {len(styles)} styles of {args.epochs} epochs "
          "of batch 32.")


if __name__ == "__main__":
    main()
