"""Table 2 of Mason, Starke & Komura 2022: parameter counts and per-frame runtime of the seven
style models, at the paper's sizes (95 styles), beside the paper's numbers.

    python experiments/mason2022_table2.py [--calls 200] [--runs 5] [--no-runtime]

A.S.N. (animation synthesis network), S.M.N. (style modulation network) and P.S.R. (parameters
per style at runtime) come from the formulas of ``jaxstyle.nn.style_models`` (tested to equal the
sizes of the initialised parameter trees). Runtime: one frame at batch 1 on this machine's
default JAX device, FiLM parameters precomputed (the network call only, not the controller),
as the mean and standard deviation over ``--runs`` runs of the average over ``--calls`` calls,
as in the paper (which timed its own C# runtime on its own CPU). No motion capture needed.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform

import jax
import jax.numpy as jnp

from jaxstyle.nn import film_generator as film
from jaxstyle.nn import style_models
from jaxstyle.nn.style_models import TABLE2, StyleModelConfig
from jaxstyle.timing import time_call

# the paper's Table 2: A.S.N., S.M.N., P.S.R., runtime mean and std (ms)
PAPER = {"PFNN One-hot": (2_436_380, 194_560, 2048, 0.78, 0.01),
         "LPN One-hot": (4_935_928, 389_120, 4096, 4.11, 0.02),
         "PFNN Resad": (2_436_380, 2_978_440, 31_352, 0.92, 0.01),
         "LPN Resad": (4_935_928, 24_952_320, 262_656, 4.78, 0.06),
         "PFNN FiLM": (2_436_380, 35_668_530, 2048, 1.37, 0.02),
         "MANN FiLM": (4_870_392, 35_668_530, 2048, 4.48, 0.04),
         "LPN FiLM": (4_935_928, 35_668_530, 2048, 4.53, 0.04)}


@dataclasses.dataclass(frozen=True)
class Config:
    num_styles: int = 95
    calls: int = 200
    runs: int = 5
    runtime: bool = True


def runtime_ms(config: StyleModelConfig, calls: int, runs: int) -> tuple[float, float]:
    """Batch-1 time of one frame, ms (mean, std over runs)."""
    params = style_models.init_model(jax.random.PRNGKey(0), config)
    fwd = style_models.runtime_forward(params, config)
    style = style_models.example_style(params, config)
    x = jnp.zeros((1, config.input_size))
    gate = jnp.full((1,), 0.3) if config.backbone == "pfnn" else jnp.zeros((1, config.gating_input))
    mean, std = time_call(lambda: fwd(x, gate, style), calls=calls, runs=runs)
    return mean * 1e3, std * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calls", type=int, default=Config.calls)
    parser.add_argument("--runs", type=int, default=Config.runs)
    parser.add_argument("--no-runtime", action="store_true", help="print the parameter counts only")
    args = parser.parse_args()
    config = Config(calls=args.calls, runs=args.runs, runtime=not args.no_runtime)
    dev = jax.devices()[0]
    print(f"device: {dev.device_kind} ({dev.platform}), {platform.machine()} host with {os.cpu_count()} cores, "
          f"jax {jax.__version__}; {config.num_styles} styles\n")
    print("| model | A.S.N. | paper | S.M.N. | paper | P.S.R. | paper | runtime ms (batch 1) | paper ms |")
    print("|---|---|---|---|---|---|---|---|---|")
    mismatches = []
    for name, paper in PAPER.items():
        mc = StyleModelConfig.paper(name, config.num_styles)
        c = style_models.parameter_counts(mc)
        ours = (c["synthesis"], c["style_network"], c["per_style"])
        mismatches += [(name, col, o, p) for col, o, p in zip(("A.S.N.", "S.M.N.", "P.S.R."), ours, paper[:3],
                                                              strict=True) if o != p]
        rt = "-"
        if config.runtime:
            mean, std = runtime_ms(mc, config.calls, config.runs)
            rt = f"{mean:.3f} ± {std:.3f}"
        cells = " | ".join(f"{o:,} | {p:,}" for o, p in zip(ours, paper[:3], strict=True))
        print(f"| {name} | {cells} | {rt} | {paper[3]:.2f} ± {paper[4]:.2f} |", flush=True)
    print()
    for name, col, ours, paper in mismatches:
        print(f"{name} {col}: {ours:,} here, {paper:,} in the paper")
    if any(col == "S.M.N." and TABLE2[name][1] == "film" for name, col, _, _ in mismatches):
        g = film.FiLMConfig()
        print(f"  The FiLM generator as described (conv {g.clip_features}->{g.filters} width {g.width}, maxpool 2, "
              f"conv {g.filters}->{g.filters} width {g.width}, maxpool 2, dense {g.pooled_frames}*{g.filters}->"
              f"{g.hidden}, dense {g.hidden}->{g.film_size}, with biases) has {film.generator_size(g):,} parameters; "
              "no variant searched (padding, pooling, widths, biases) gives the paper's 35,668,530 "
              "(see jaxstyle/nn/film_generator.py).")
    unexplained = [m for m in mismatches if not (m[1] == "S.M.N." and TABLE2[m[0]][1] == "film")]
    if unexplained:
        raise SystemExit(f"unexpected parameter-count mismatches: {unexplained}")


if __name__ == "__main__":
    main()
