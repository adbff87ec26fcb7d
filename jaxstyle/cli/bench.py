"""``jaxstyle bench``: the few-shot sweep against a loop of single runs, and the network's speed
(:func:`jaxstyle.mason2018.bench.bench`)."""

from __future__ import annotations

from jaxstyle.cli.args import SWEEP_RATES, add_common, check_positive, check_rates, finite
from jaxstyle.cli.common import Run, machine

NAME = "bench"
HELP = "time the few-shot sweep against a loop of single runs, and the network"
DOC = """\
Measured side by side in one run: the few-shot sweep of --sets x rates pairs as ONE jit(vmap)
program against a Python loop of the same single runs, and the PFNN forward pass at batch 1 and
1024. Uses RUN/base when there is one, else a randomly initialised network of --hidden units.
The fuller benchmarks are the scripts in the repository's benchmarks/ folder.
"""


def add_arguments(p) -> None:
    p.add_argument("--sets", type=int, default=4, help="few-shot sets (styles) in the sweep")
    p.add_argument("--rates", type=finite, nargs="+", default=SWEEP_RATES, help="dropout rates")
    p.add_argument("--frames", type=int, default=600, help="rows per set")
    p.add_argument("--sweep-epochs", type=int, default=5, help="epochs per pair")
    p.add_argument("--hidden", type=int, default=512, help="hidden units when the run has no base model")
    add_common(p)


def run(args, run: Run) -> None:
    import jax

    from jaxstyle.mason2018 import base_model
    from jaxstyle.mason2018 import bench as bench2018
    from jaxstyle.nn import pfnn

    check_positive(args, "sets", "frames", "sweep_epochs", "hidden")
    check_rates(args.rates)
    if (run.dir / "base" / "base.json").is_file():
        base = base_model.load_base(run.dir / "base", cache=run.dir / "cache", progress=False)
        model, params, what = base.model, base.params, f"the base of {run.dir / 'base'}"
    else:
        model = pfnn.PFNNConfig(hidden_size=args.hidden)
        params, what = pfnn.init_pfnn(jax.random.PRNGKey(0), model), "a random network"
    run.say(f"bench on {machine()}: {what}, {model.input_size} -> {model.hidden_size} -> {model.output_size}, "
            f"CP rank {model.rank}")
    b = bench2018.bench(params, model, sets=args.sets, frames=args.frames, epochs=args.sweep_epochs, rates=args.rates)
    sweep, loop = b.seconds["sweep"], b.seconds["loop"]
    run.say(f"few-shot fine-tuning, {b.pairs} pairs x {b.steps} steps of batch {b.batch_size}: "
            f"one jit(vmap) sweep {sweep:.2f} s, loop of single runs {loop:.2f} s, "
            f"ratio {loop / sweep:.2f}x ({sweep / b.pairs:.3f} s per pair)")
    for size, (mean, std) in b.forward_ms.items():
        run.say(f"PFNN forward, batch {size}: {mean:.3f} +- {std:.3f} ms ({size / mean * 1e3:,.0f} frames/s)")
    figures = {**b.seconds, **{f"forward_batch_{size}_ms": ms[0] for size, ms in b.forward_ms.items()}}
    from jaxstyle.train.checkpoint import json_text

    (run.dir / "bench.json").write_text(json_text({"machine": machine(), **figures}))
    run.say(f"written: {run.dir / 'bench.json'}")
