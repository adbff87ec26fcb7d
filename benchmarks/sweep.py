"""Few-shot sweep speed: one jit(vmap) program against a Python loop of the same single runs.

    python benchmarks/sweep.py [--styles 8] [--rates 0.1 0.3 0.5 0.7] [--frames 600] [--epochs 100]
                               [--modes paper adapter]

On the full-size 2018 network (234 -> 512 -> 512 -> 400, CP adapters of rank 30) and synthetic
rows (speed does not depend on the values), with ``--styles`` styles of about ``--frames`` rows
(ragged: +-5%), ``--epochs`` epochs of batch 32 per pair, measured side by side in one run for
each mode (``paper``: dropout on every layer as in the paper; ``adapter``: dropout on the adapter
path only, frozen activations cached; ``bf16``: the paper's dropout with the frozen layers'
products in bfloat16; ``adapter-bf16``: both options; see :class:`jaxstyle.mason2018.fewshot.SweepConfig`):

(a) wall time of the vmapped sweep over all styles x rates against a Python loop of the same
    single runs (:func:`jaxstyle.mason2018.fewshot.finetune_one`, same keys, data order and steps), and
    their ratio;
(b) amortised seconds per (style, rate) pair for ``--epochs`` epochs, and milliseconds per
    pair-step (one batch-32 training step of one pair: the sweep's time over pairs x steps);
(c) achieved GFLOP/s of the sweep (FLOPs counted from the layer shapes) over that of plain
    matmuls of the same shapes and dtype run in a ``lax.scan`` of the same length.

Compile time is printed separately: the time JAX reports spending on tracing, lowering and
compiling during the sweep's first call (``jax.monitoring`` compile events); every other time
is of a later, already compiled call.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.mason2018 import fewshot
from jaxstyle.nn import pfnn
from jaxstyle.train import scan

COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
                  "/jax/core/compile/backend_compile_duration")
_compile_seconds = [0.0]


def _on_event(event: str, duration: float, **_) -> None:
    if event in COMPILE_EVENTS:
        _compile_seconds[0] += duration


jax.monitoring.register_event_duration_secs_listener(_on_event)


def frozen_flops_per_row(model: pfnn.PFNNConfig) -> float:
    """Multiply-adds x 2 of the frozen layers 0 and 1 forward for one row (4 control points each)."""
    i, h = model.input_size, model.hidden_size
    return 2 * 4 * (i * h + h * h)


def matmul_flops(model: pfnn.PFNNConfig, rows: int, adapter_dropout_only: bool) -> float:
    """Multiply-adds x 2 of one step's big products over ``rows`` rows: the last layer forward and
    its input gradient, and (unless the adapter-only mode caches them) the frozen layers forward."""
    per_row = 2 * 4 * model.hidden_size * model.output_size * 2
    if not adapter_dropout_only:
        per_row += frozen_flops_per_row(model)
    return float(per_row * rows)


def sweep_flops(model: pfnn.PFNNConfig, rows_per_step: int, adapter_dropout_only: bool) -> float:
    """Multiply-adds x 2 of one training step over ``rows_per_step`` rows (all pairs together): the
    big products (:func:`matmul_flops`; in the adapter-only mode the cache is computed once and
    counted separately) and the CP adapter forward and backward (``10 H r``)."""
    return matmul_flops(model, rows_per_step, adapter_dropout_only) + float(
        10 * model.hidden_size * model.rank * rows_per_step)


def timed(fn):
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t0


def matmul_reference(model: pfnn.PFNNConfig, rows: int, steps: int, adapter_dropout_only: bool,
                     dtype=jnp.float32) -> tuple[float, float]:
    """``(seconds, flops)`` of a lax.scan of ``steps`` steps of the sweep's big matmuls alone, at the
    sweep's shapes: ``(rows, I) @ (I, 4H)``, ``(rows, H) @ (H, 4H)``, ``(rows, H) @ (H, 4O)`` and the
    input gradient ``(rows, 4O) @ (4O, H)`` (the adapter-only mode: the last two), operands in
    ``dtype``, accumulated in float32."""
    i, h, o = model.input_size, model.hidden_size, model.output_size
    key = jax.random.PRNGKey(0)
    ks = jax.random.split(key, 6)
    w0, w1 = jax.random.normal(ks[0], (i, 4 * h), dtype), jax.random.normal(ks[1], (h, 4 * h), dtype)
    w2, w2t = jax.random.normal(ks[2], (h, 4 * o), dtype), jax.random.normal(ks[3], (4 * o, h), dtype)

    def mm(a, b):
        return jnp.matmul(a.astype(dtype), b, preferred_element_type=jnp.float32)

    x = jax.random.normal(ks[4], (rows, i)) * 1e-3
    g = jax.random.normal(ks[5], (rows, 4 * o)) * 1e-3

    @jax.jit
    def run_full(x, g):
        def step(c, _):  # every product is used whole, so XLA cannot slice any away
            xx, hh, gg = c
            a = mm(xx, w0).reshape(rows, 4, h).sum(1)
            b = mm(a + hh, w1).reshape(rows, 4, h).sum(1)
            y = mm(b, w2)
            d = mm(gg, w2t)
            return (xx + 1e-6 * jnp.tanh(d.mean(-1, keepdims=True)), 1e-3 * jnp.tanh(b + d), 1e-3 * jnp.tanh(y)), None

        def step_adapter(c, _):
            xx, hh, gg = c
            y = mm(hh, w2)
            d = mm(gg, w2t)
            return (xx, 1e-3 * jnp.tanh(d + hh), 1e-3 * jnp.tanh(y)), None

        hh = jnp.ones((rows, h)) * 1e-3
        (xx, hh, gg), _ = jax.lax.scan(step_adapter if adapter_dropout_only else step, (x, hh, g), None, length=steps)
        return xx.sum() + hh.sum() + gg.sum()

    timed(lambda: run_full(x, g))
    seconds = timed(lambda: run_full(x, g))
    return seconds, matmul_flops(model, rows, adapter_dropout_only) * steps


def measure(mode: str, model, x, y, phase, rows, rates, epochs) -> dict:
    config = fewshot.SweepConfig(model=model, epochs=epochs, rates=tuple(rates),
                                 adapter_dropout_only=mode.startswith("adapter"),
                                 matmul_dtype="bfloat16" if mode.endswith("bf16") else "float32")
    batches, mask = scan.sweep_batches(rows, config.epochs, config.batch_size)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), model)
    pairs = len(rows) * len(rates)
    _compile_seconds[0] = 0.0
    timed(lambda: fewshot.adapter_sweep(params, x, y, phase, batches, mask, config))
    compile_s = _compile_seconds[0]
    sweep = timed(lambda: fewshot.adapter_sweep(params, x, y, phase, batches, mask, config))

    def loop():
        out = []
        for s in range(len(rows)):
            for r, rate in enumerate(rates):
                out.append(fewshot.finetune_one(params, x, y, phase, batches[s], mask[s], rate,
                                                scan.pair_key(config.seed, s, r), config)[0])
        return out

    jax.block_until_ready(fewshot.finetune_one(params, x, y, phase, batches[0], mask[0], rates[0],
                                               scan.pair_key(0, 0, 0), config))  # compile the single run
    loop_s = timed(loop)
    steps = batches.shape[1]
    flops = sweep_flops(model, pairs * config.batch_size, config.adapter_dropout_only) * steps
    if config.adapter_dropout_only:
        flops += frozen_flops_per_row(model) * len(x)  # the cache, once
    mm_s, mm_flops = matmul_reference(model, pairs * config.batch_size, steps, config.adapter_dropout_only,
                                      jnp.dtype(config.matmul_dtype))
    return {"mode": mode, "pairs": pairs, "steps": steps, "compile": compile_s, "sweep": sweep, "loop": loop_s,
            "gflops": flops / sweep / 1e9, "mm_gflops": mm_flops / mm_s / 1e9}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--styles", type=int, default=8)
    parser.add_argument("--rates", type=float, nargs="+", default=[0.1, 0.3, 0.5, 0.7])
    parser.add_argument("--frames", type=int, default=600, help="rows per style (about; ragged by +-5%%)")
    parser.add_argument("--epochs", type=int, default=100)
    modes = ["paper", "adapter", "bf16", "adapter-bf16"]
    parser.add_argument("--modes", nargs="+", default=modes, choices=modes,
                        help="paper: dropout everywhere; adapter: dropout on the adapter path only; bf16: paper "
                             "dropout with bfloat16 products of the frozen layers; adapter-bf16: both")
    args = parser.parse_args()
    dev = jax.devices()[0]
    print(f"device: {dev.device_kind} ({dev.platform}) x {jax.device_count()}, host {platform.machine()} with "
          f"{os.cpu_count()} cores, jax {jax.__version__}")
    model = pfnn.PFNNConfig()
    rng = np.random.default_rng(0)
    sizes = (args.frames * (1 + 0.05 * np.linspace(-1, 1, args.styles))).astype(int)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    rows = [np.arange(offsets[s], offsets[s + 1]) for s in range(args.styles)]
    n = int(offsets[-1])
    x = jnp.asarray(rng.normal(size=(n, model.input_size)), jnp.float32)
    y = jnp.asarray(rng.normal(size=(n, model.output_size)), jnp.float32)
    phase = jnp.asarray(rng.uniform(size=n), jnp.float32)
    print(f"{args.styles} styles of {sizes.min()}-{sizes.max()} rows x {len(args.rates)} rates {tuple(args.rates)}, "
          f"{args.epochs} epochs of batch 32, CP rank {model.rank}, 234 -> 512 -> 512 -> 400\n")
    print("| mode | steps | compile s | sweep s | loop of single runs s | loop / sweep "
          "| s per pair (sweep) | ms per pair-step (sweep) | sweep GFLOP/s | matmul GFLOP/s | sweep / matmul |")
    print("|---|---|---|---|---|---|---|---|---|---|---|", flush=True)
    for mode in args.modes:
        r = measure(mode, model, x, y, phase, rows, args.rates, args.epochs)
        print(f"| {r['mode']} | {r['steps']} | {r['compile']:.1f} | {r['sweep']:.1f} | {r['loop']:.1f} "
              f"| {r['loop'] / r['sweep']:.2f}x | {r['sweep'] / r['pairs']:.2f} "
              f"| {1e3 * r['sweep'] / (r['pairs'] * r['steps']):.2f} | {r['gflops']:.0f} "
              f"| {r['mm_gflops']:.0f} | {r['gflops'] / r['mm_gflops']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
