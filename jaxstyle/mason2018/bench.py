"""Timing of the 2018 workflow (``jaxstyle bench``, ``experiments/mason2018_table1.py``): the
compiled few-shot sweep against a loop of single fine-tunings on the same sets (:func:`bench`), and
the fine-tuning cost and memory of each adapter kind of Table 1 (:func:`adapter_cost`).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import jax
import numpy as np

from jaxstyle.mason2018 import fewshot
from jaxstyle.mason2018.train import TrainConfig, finetune_adapter
from jaxstyle.nn import pfnn
from jaxstyle.train.defaults import DEFAULT_RATES


class Bench(NamedTuple):
    """Timings of :func:`bench`: ``seconds`` (``sweep``, ``loop``) and ``forward_ms`` per batch size;
    the sweep's ``pairs``, ``steps`` per pair and ``batch_size``."""

    seconds: dict[str, float]
    forward_ms: dict[int, tuple[float, float]]
    pairs: int
    steps: int
    batch_size: int


def bench(params: dict, model: pfnn.PFNNConfig, *, sets: int = 4, frames: int = 600, epochs: int = 5,
          rates: Sequence[float] = DEFAULT_RATES, batches: Sequence[int] = (1, 1024)) -> Bench:
    """The few-shot sweep of ``sets`` x ``rates`` pairs on random rows (``frames`` per set) as ONE
    jit(vmap) program against a Python loop of the same single runs, each timed after a compile
    run; and the PFNN forward pass (mean and std, ms) at each batch size of ``batches``."""
    import time

    import jax.numpy as jnp

    from jaxstyle.timing import time_call
    from jaxstyle.train import scan

    rng = np.random.default_rng(0)
    n = sets * frames
    x = jnp.asarray(rng.standard_normal((n, model.input_size)), jnp.float32)
    y = jnp.asarray(rng.standard_normal((n, model.output_size)), jnp.float32)
    phase = jnp.asarray(rng.random(n), jnp.float32)
    rows = [np.arange(s * frames, (s + 1) * frames) for s in range(sets)]
    config = fewshot.SweepConfig(model=model, epochs=epochs, rates=tuple(rates))
    plan, mask = scan.sweep_batches(rows, config.epochs, config.batch_size)

    def sweep():
        return fewshot.adapter_sweep(params, x, y, phase, plan, mask, config)

    def loop():
        return [fewshot.finetune_one(params, x, y, phase, plan[s], mask[s], rate, scan.pair_key(config.seed, s, r),
                                     config)[0]
                for s in range(sets) for r, rate in enumerate(config.rates)]

    seconds = {}
    for name, fn in (("sweep", sweep), ("loop", loop)):
        jax.block_until_ready(fn())  # compile
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        seconds[name] = time.perf_counter() - t0
    forward = jax.jit(lambda xb, pb: pfnn.pfnn_apply(params, xb, pb))
    forward_ms = {}
    for b in batches:
        xb, pb = x[:b] if b <= n else jnp.tile(x, (b // n + 1, 1))[:b], jnp.resize(phase, (b,))
        mean, std = time_call(lambda xb=xb, pb=pb: forward(xb, pb), calls=50 if b == 1 else 10, runs=3)
        forward_ms[b] = (1e3 * mean, 1e3 * std)
    return Bench(seconds, forward_ms, sets * len(config.rates), int(plan.shape[1]), config.batch_size)


class AdapterCost(NamedTuple):
    """Table 1 of the 2018 paper for one adapter ``kind``: memory (MB, 2^20 bytes) of one new adapter's
    control points and of its 50-bin runtime table, mean seconds to fine-tune one on a style, and the
    median seconds of one jitted single-frame forward pass with the tables."""

    kind: str
    memory_mb: float
    table_mb: float
    train_seconds: float
    runtime_seconds: float


def adapter_cost(kind: str, data, styles: Sequence[int], *, epochs: int = 100, repeats: int = 200) -> AdapterCost:
    """:class:`AdapterCost` of ``kind`` on the paper's 234 -> 512 -> 512 -> 400 PFNN: memory measured
    from the arrays (and checked against :func:`jaxstyle.nn.pfnn.adapter_bytes`); fine-tuning a new
    adapter (base frozen) for ``epochs`` epochs of batch 32 on each style of ``styles`` of ``data``
    (:class:`jaxstyle.mason2018.train.TrainData`), each timed after a compile run; the forward pass
    over ``repeats`` calls."""
    import statistics
    import time

    import jax.numpy as jnp

    def nbytes(tree) -> int:
        return sum(int(v.size) * v.dtype.itemsize for v in jax.tree.leaves(tree))

    config = pfnn.PFNNConfig(adapter=kind)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), config)
    adapter = pfnn.init_adapter(jax.random.PRNGKey(1), config)
    table, adapter_table = pfnn.discretise(params), pfnn.discretise(adapter)
    measured = (nbytes(adapter), nbytes(adapter_table))
    formula = (pfnn.adapter_bytes(config), pfnn.adapter_bytes(config, num_bins=50))
    if measured != formula:
        raise AssertionError(f"{kind}: adapter bytes {measured} differ from the formula's {formula}")
    train_config = TrainConfig(model=config, epochs=epochs, batch_size=32)
    per_style = []
    for s in styles:
        jax.block_until_ready(finetune_adapter(params, adapter, data, s, train_config))  # compile this shape
        t0 = time.perf_counter()
        jax.block_until_ready(finetune_adapter(params, adapter, data, s, train_config))
        per_style.append(time.perf_counter() - t0)
    forward = jax.jit(lambda x, p: pfnn.pfnn_apply_table(table, x, p, adapter_table=adapter_table))
    x = jnp.asarray(data.x[:1])
    jax.block_until_ready(forward(x, 0.3))
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(forward(x, (i % 50) / 50))
        times.append(time.perf_counter() - t0)
    mib = 2.0 ** 20
    return AdapterCost(kind, measured[0] / mib, measured[1] / mib, statistics.mean(per_style),
                       statistics.median(times))
