"""Per-frame runtime of the style models: LPN-FiLM (2022) and the 2018 PFNN with a CP adapter,
at batch 1 (one character, the papers' runtime) and batch 1024 (many characters or a batched
rollout), plus the other Table 2 models at both sizes. No motion capture needed.

    python benchmarks/style_models.py [--calls 200] [--runs 5]

The network call only (FiLM parameters precomputed, dropout off, jitted), on the default JAX
device; times are the mean and standard deviation over ``--runs`` runs of the average over
``--calls`` calls, all measured in this run. The papers report 1.1 ms per frame (2018, CP
adapter, 50 phase bins) and 4.53 ms (2022, LPN-FiLM), each on its authors' CPU and runtime.
"""

from __future__ import annotations

import argparse
import os
import platform
from functools import partial

import jax
import jax.numpy as jnp

from jaxstyle.nn import pfnn, style_models
from jaxstyle.nn.style_models import TABLE2, StyleModelConfig
from jaxstyle.timing import time_call


def _row(name, batch, mean, std):
    print(f"| {name} | {batch} | {mean * 1e3:.3f} ± {std * 1e3:.3f} | {mean * 1e6 / batch:.2f} | "
          f"{batch / mean:,.0f} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calls", type=int, default=200)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    dev = jax.devices()[0]
    print(f"device: {dev.device_kind} ({dev.platform}), {platform.machine()} host with {os.cpu_count()} cores, "
          f"jax {jax.__version__}\n")
    print("| model | batch | ms per call | us per frame | frames/s |\n|---|---|---|---|---|")
    key = jax.random.PRNGKey(0)

    # 2018: PFNN with a CP adapter, continuous phase and the runtime's 50-bin table
    cfg = pfnn.PFNNConfig()
    base, adapter = pfnn.init_pfnn(key, cfg), pfnn.init_adapter(key, cfg)
    table, adapter_table = pfnn.discretise(base), pfnn.discretise(adapter)
    fwd = jax.jit(lambda x, p: pfnn.pfnn_apply(base, x, p, adapter=adapter))
    fwd_table = jax.jit(lambda x, p: pfnn.pfnn_apply_table(table, x, p, adapter_table=adapter_table))
    for batch in (1, 1024):
        x, ph = jnp.zeros((batch, cfg.input_size)), jnp.linspace(0, 0.99, batch)
        calls = args.calls if batch == 1 else max(args.calls // 10, 5)
        if batch == 1:
            _row("PFNN-CP 2018, 50-bin table", 1, *time_call(partial(fwd_table, x, 0.3), calls=calls, runs=args.runs))
        _row("PFNN-CP 2018, continuous phase", batch, *time_call(partial(fwd, x, ph), calls=calls, runs=args.runs))

    # 2022: the seven Table 2 models at the paper's sizes
    order = ["LPN FiLM"] + [n for n in TABLE2 if n != "LPN FiLM"]
    for name in order:
        mc = StyleModelConfig.paper(name)
        params = style_models.init_model(key, mc)
        run = style_models.runtime_forward(params, mc)
        style = style_models.example_style(params, mc)
        for batch in (1, 1024):
            x = jnp.zeros((batch, mc.input_size))
            gate = jnp.linspace(0, 0.99, batch) if mc.backbone == "pfnn" else jnp.zeros((batch, mc.gating_input))
            calls = args.calls if batch == 1 else max(args.calls // 10, 5)
            _row(name, batch, *time_call(partial(run, x, gate, style), calls=calls, runs=args.runs))
    print("\npapers: 1.1 ms per frame (2018, CP adapter), 4.53 ms per frame (2022, LPN-FiLM), batch 1")


if __name__ == "__main__":
    main()
