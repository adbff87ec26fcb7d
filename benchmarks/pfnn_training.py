"""PFNN training and inference speed on synthetic data (no motion capture needed).

    python benchmarks/pfnn_training.py [--steps 200] [--adapter cp]

On the default JAX device, the full-size network (234 -> 512 -> 512 -> 400):

* base-training steps (batch 32, one style per batch, dropout, Adam over the base and 8
  adapters) run in one jitted lax.scan, after a compile run;
* adapter fine-tuning steps (base frozen; the few-shot inner loop);
* forward passes at batch 1 (the runtime) and batch 4096, continuous phase and 50-bin table.

Prints steps/s and rows/s, each timed side by side in this run.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxstyle.mason2018.train import TrainConfig, TrainData, _make_chunk_fn, finetune_adapter, init_state
from jaxstyle.nn import pfnn


def timed(fn, repeats: int = 5) -> float:
    jax.block_until_ready(fn())  # compile
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--adapter", default="cp", choices=pfnn.ADAPTER_KINDS)
    args = parser.parse_args()
    dev = jax.devices()[0]
    print(f"device: {dev.device_kind} ({dev.platform}), host {platform.machine()} with {os.cpu_count()} cores, "
          f"jax {jax.__version__}\n")
    rng = np.random.default_rng(0)
    styles, rows = 8, 4096
    n = styles * rows
    train_rows = tuple(np.arange(s * rows, (s + 1) * rows) for s in range(styles))
    data = TrainData(rng.normal(size=(n, 234)).astype(np.float32), rng.normal(size=(n, 400)).astype(np.float32),
                     rng.uniform(size=n).astype(np.float32), train_rows, tuple(() for _ in range(styles)),
                     tuple(f"s{s}" for s in range(styles)))
    config = TrainConfig(model=pfnn.PFNNConfig(adapter=args.adapter))
    state = init_state(jax.random.PRNGKey(0), config, styles)
    run = _make_chunk_fn(config, optax.adam(config.learning_rate))
    x, y, ph = jnp.asarray(data.x), jnp.asarray(data.y), jnp.asarray(data.phase)
    batches = jnp.asarray(rng.integers(0, n, size=(args.steps, config.batch_size)))
    batch_styles = jnp.asarray(rng.integers(0, styles, size=args.steps))
    trainable = (state.params, state.adapters)
    t_train = timed(lambda: run(trainable, state.opt_state, x, y, ph, batches, batch_styles, jax.random.PRNGKey(1)))
    ft_config = TrainConfig(model=config.model, epochs=max(args.steps * 32 // rows, 1))
    adapter = pfnn.init_adapter(jax.random.PRNGKey(2), config.model)
    ft_steps = ft_config.epochs * (rows // 32)
    t_ft = timed(lambda: finetune_adapter(state.params, adapter, data, 0, ft_config), repeats=3)

    table = pfnn.discretise(state.params)
    one = jax.tree.map(lambda v: v[0], state.adapters)
    one_table = pfnn.discretise(one)
    fwd = jax.jit(lambda xx, p: pfnn.pfnn_apply(state.params, xx, p, adapter=one))
    fwd_table = jax.jit(lambda xx, p: pfnn.pfnn_apply_table(table, xx, p, adapter_table=one_table))
    x1, xb = x[:1], x[:4096]
    t_b1 = timed(lambda: fwd(x1, ph[:1]), 50)
    t_b1_table = timed(lambda: fwd_table(x1, 0.3), 50)
    t_big = timed(lambda: fwd(xb, ph[:4096]), 10)

    print("| what | time | rate |\n|---|---|---|")
    print(f"| base training, {args.steps} steps of batch 32 ({args.adapter} adapters) | {t_train * 1e3:.1f} ms "
          f"| {args.steps / t_train:,.0f} steps/s |")
    print(f"| adapter fine-tuning, {ft_steps} steps of batch 32 | {t_ft * 1e3:.1f} ms "
          f"| {ft_steps / t_ft:,.0f} steps/s |")
    print(f"| forward, batch 1, continuous phase | {t_b1 * 1e6:.0f} us | {1 / t_b1:,.0f} frames/s |")
    print(f"| forward, batch 1, 50-bin table | {t_b1_table * 1e6:.0f} us | {1 / t_b1_table:,.0f} frames/s |")
    print(f"| forward, batch 4096 | {t_big * 1e3:.2f} ms | {4096 / t_big:,.0f} frames/s |")


if __name__ == "__main__":
    main()
