"""Mason et al. 2018, Table 1: memory, training time and runtime of full, diagonal and CP adapters.

    python experiments/mason2018_table1.py [--epochs 100] [--repeats 200]

For each adapter kind, on the 234 -> 512 -> 512 -> 400 PFNN:

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
import dataclasses
import os
import platform
import statistics
import time
import warnings

import jax
import jax.numpy as jnp

import jaxstyle as js
from jaxstyle.data import datasets
from jaxstyle.mason2018.train import TrainConfig, data_from_dataset, finetune_adapter
from jaxstyle.nn import pfnn

PAPER = {"full": ("4.01 / 50.1", "99", "0.0013"), "diagonal": ("0.016 / 0.20", "44", "0.0010"),
         "cp": ("0.126 / 0.131", "50", "0.0011")}
NAMES = {"full": "Full Adapter", "diagonal": "Diagonal Adapter", "cp": "CP Decomposition"}


@dataclasses.dataclass(frozen=True)
class Config:
    epochs: int = 100
    repeats: int = 200


def nbytes(tree) -> int:
    return sum(int(v.size) * v.dtype.itemsize for v in jax.tree.leaves(tree))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=Config.epochs)
    parser.add_argument("--repeats", type=int, default=Config.repeats)
    args = parser.parse_args()
    mocap = js.mocap_dir()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dataset = datasets.build_pfnn_dataset(datasets.specs_xia(mocap / "xia"), skip_short=True)
    data = data_from_dataset(dataset)
    styles = [s for s, rows in enumerate(data.train_rows) if len(rows) >= 32]
    sizes = ", ".join(f"{data.styles[s]} {len(data.train_rows[s])}" for s in styles)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} "
          f"on {jax.devices()[0].platform}; styles with at least one batch of training rows: {sizes}\n")
    mib = 2.0 ** 20
    rows = []
    for kind in pfnn.ADAPTER_KINDS:
        config = pfnn.PFNNConfig(adapter=kind)
        params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
        adapter = pfnn.init_adapter(jax.random.PRNGKey(1), config)
        table, adapter_table = pfnn.discretise(params), pfnn.discretise(adapter)
        measured = (nbytes(adapter), nbytes(adapter_table))
        formula = (pfnn.adapter_bytes(config), pfnn.adapter_bytes(config, num_bins=50))
        assert measured == formula, (kind, measured, formula)

        train_config = TrainConfig(model=config, epochs=args.epochs, batch_size=32)
        per_style = []
        for s in styles:
            jax.block_until_ready(finetune_adapter(params, adapter, data, s, train_config))  # compile this shape
            t0 = time.perf_counter()
            jax.block_until_ready(finetune_adapter(params, adapter, data, s, train_config))
            per_style.append(time.perf_counter() - t0)
        train_s = statistics.mean(per_style)

        forward = jax.jit(lambda x, p, t=table, a=adapter_table: pfnn.pfnn_apply_table(t, x, p, adapter_table=a))
        x = jnp.asarray(data.x[:1])
        jax.block_until_ready(forward(x, 0.3))
        times = []
        for i in range(args.repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(forward(x, (i % 50) / 50))
            times.append(time.perf_counter() - t0)
        rows.append((kind, measured[0] / mib, measured[1] / mib, train_s, statistics.median(times)))

    print("| method | memory MB (ours) | memory MB (paper) | training s (ours) | training s (paper) "
          "| runtime s (ours) | runtime s (paper) |")
    print("|---|---|---|---|---|---|---|")
    for kind, m_cp, m_bins, train_s, run_s in rows:
        paper = PAPER[kind]
        print(f"| {NAMES[kind]} | {m_cp:.3f} / {m_bins:.3f} | {paper[0]} | {train_s:.1f} | {paper[1]} "
              f"| {run_s:.5f} | {paper[2]} |")
    print(f"\nmemory = formula for every kind; training = mean over {len(styles)} styles of {args.epochs} epochs "
          "of batch 32.")


if __name__ == "__main__":
    main()
