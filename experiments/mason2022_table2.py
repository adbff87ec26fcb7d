"""Table 2 of Mason, Starke & Komura 2022: parameter counts and per-frame runtime of the seven
style models, at the paper's sizes (95 styles), beside the paper's numbers; with ``--train``, the
seven models trained at a size that fits a 2-core CPU, tested and driven in the closed loop.

    python experiments/mason2022_table2.py [--calls 200] [--runs 5] [--no-runtime]
    python experiments/mason2022_table2.py --train [--epochs 20] [--out runs/table2]

A.S.N. (animation synthesis network), S.M.N. (style modulation network) and P.S.R. (parameters
per style at runtime) come from the formulas of ``jaxstyle.nn.style_models`` (tested to equal the
sizes of the initialised parameter trees). Runtime: one frame at batch 1 on this machine's
default JAX device, FiLM parameters precomputed (the network call only, not the controller),
as the mean and standard deviation over ``--runs`` runs of the average over ``--calls`` calls,
as in the paper (which timed its own C# runtime on its own CPU). No motion capture needed.

``--train`` (the CPU scale; the paper trains 512 hidden units and a generator of 256 filters and
2048 dense units for 90 epochs at 1e-4 on 95 styles, on a GPU):

1. Data: the paper's base styles of the shared 100STYLE sample
   (:data:`jaxstyle.data.folders.PAPER_BASE`: Angry, Chicken, Drunk, InTheDark, Neutral; every
   gait, idling and transitions included as in ``experiments/mason2022_styles.py``, mirrored;
   :func:`jaxstyle.mason2022.pipeline.build_data`), or ``--styles`` of ``--data``.
2. Models: all seven at the demo's size (``--hidden`` 256 units, a FiLM generator of ``--filters``
   32 filters and ``--generator-hidden`` 512 dense units), Adam at ``--learning-rate`` 1e-3 (the
   demo's: at 1e-4 a few epochs leave every model standing still), ``--epochs`` epochs each, as the
   paper gives every model the same epochs (a wall-clock budget, as in
   ``experiments/mason2022_styles.py``, would favour the cheaper models and change with the
   machine's load). Trained models are kept in ``--out/<model>`` and resumed or reloaded.
3. Test: normalised MSE and bone-length loss per style on the test rows, and the paper's claims
   about its Figure 10 (:func:`jaxstyle.mason2022.report.ordering_lines`).
4. Closed loop: every training style along ``straight`` and ``circle`` for 10 s at its own speed
   (:func:`jaxstyle.mason2022.synthesis.measure_quality`, the quality benchmark's protocol) with
   each runtime of ``--phase-floors`` (0: the paper's; the default floor,
   :data:`jaxstyle.train.defaults.PHASE_FLOOR`), the feet blended as every joint (the paper's runtime;
   ``--foot-smooth S``: the feet's own weight, the commands' default being
   :data:`jaxstyle.train.defaults.FOOT_SMOOTH`; ``--body-smooth S`` the other bones',
   :data:`jaxstyle.train.defaults.BODY_SMOOTH`), summarised per model
   (:func:`jaxstyle.mason2022.report.closed_loop_figures`) with the verdicts of
   :func:`jaxstyle.mason2022.report.closed_loop_ordering_lines`.

Writes ``--out/table2.md`` and ``--out/closed_loop.csv`` (every row of the quality benchmark).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from jaxstyle.cli.args import add_joint_blend_args
from jaxstyle.nn import film_generator as film
from jaxstyle.nn import style_models
from jaxstyle.nn.style_models import TABLE2, StyleModelConfig
from jaxstyle.timing import time_call
from jaxstyle.train.defaults import PHASE_FLOOR

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


ORDER = ("PFNN One-hot", "LPN One-hot", "PFNN Resad", "LPN Resad", "PFNN FiLM", "MANN FiLM", "LPN FiLM")
PATHS = ("straight", "circle")
SECONDS = 10.0


def names(text: str) -> tuple[str, ...]:
    """A comma-separated list of names (argparse ``type``)."""
    return tuple(s.strip() for s in text.split(",") if s.strip())


def train(args) -> None:
    """``--train``: the seven models at the CPU scale, their test losses and closed-loop figures."""
    from jaxstyle.data import clips, folders
    from jaxstyle.data.locate import mocap_dir
    from jaxstyle.mason2022 import pipeline, report
    from jaxstyle.mason2022 import synthesis as synthesis2022
    from jaxstyle.output import report as quality_report

    t0 = time.perf_counter()
    root = folders.style_root(args.data or mocap_dir() / "100style")
    styles = [s for s in args.styles or folders.PAPER_BASE if s in folders.available_styles(root)]
    if len(styles) < 1:
        raise SystemExit(f"error: none of the styles {', '.join(args.styles or folders.PAPER_BASE)} is in {root}")
    gaits = clips.GAITS_100STYLE if (root / "Frame_Cuts.csv").is_file() else None
    data = pipeline.build_data(root, styles, gaits=gaits, cache=args.out / "cache", progress=not args.no_progress)
    lines = [f"Table 2 at CPU scale: {', '.join(data.base.styles)}, {int((data.base.split == 0).sum()):,} training "
             f"rows; {args.hidden} hidden units, FiLM generator {args.filters} filters / {args.generator_hidden} dense "
             f"units; {args.epochs} epochs each at Adam {args.learning_rate:g} (data ready after "
             f"{time.perf_counter() - t0:.0f} s)", ""]
    print(lines[0], flush=True)
    configs = {name: pipeline.model_config(data.base, name, hidden=args.hidden, generator_hidden=args.generator_hidden,
                                           filters=args.filters) for name in args.models}
    done = pipeline.train_models(data, configs, args.out, pipeline.SharedBudget.epochs(args.epochs),
                                 train_config={"learning_rate": args.learning_rate}, progress=not args.no_progress,
                                 after_each=lambda name, runs: print(report.model_line(name, runs), flush=True))
    lines += report.budget_table(done.runs, done.logs)
    lines += ["", "Test rows, dropout off: mean over styles, then per style MSE / BLL:", ""]
    lines += report.models_table(data.base.styles, done.results) + ["", *report.ordering_lines(done.results)]
    rows = []
    for floor in args.phase_floors:
        t1 = time.perf_counter()
        mine = []
        for name, run in done.runs.items():
            loaded = synthesis2022.Loaded(run.model, data, pipeline.model_folder(args.out, name), run.epochs,
                                          phase_floor=floor, foot_smooth=args.foot_smooth,
                                          body_smooth=args.body_smooth)
            mine += [{**r, "phase_floor": floor} for r in
                     synthesis2022.measure_quality(loaded, styles, path_names=PATHS, seconds=SECONDS).rows]
        figures = report.closed_loop_figures(mine)
        runtime = "the paper's runtime (no phase floor)" if floor == 0 else f"local phases floored at {floor:g}"
        lines += ["", f"Closed loop, {runtime}: {len(styles)} styles x {len(PATHS)} paths, {SECONDS:g} s each at the "
                      f"style's own speed ({time.perf_counter() - t1:.0f} s):", "",
                  *report.closed_loop_table(figures, done.results), "", *report.closed_loop_ordering_lines(figures)]
        rows += mine
    lines += ["", f"whole run: {(time.perf_counter() - t0) / 60:.1f} min"]
    print("\n".join(lines[2:]))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "table2.md").write_text("\n".join(lines) + "\n")
    quality_report.write_csv(rows, args.out / "closed_loop.csv")
    print(f"written: {args.out / 'table2.md'}, {args.out / 'closed_loop.csv'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calls", type=int, default=Config.calls)
    parser.add_argument("--runs", type=int, default=Config.runs)
    parser.add_argument("--no-runtime", action="store_true", help="print the parameter counts only")
    t = parser.add_argument_group("--train: the seven models trained at the CPU scale")
    t.add_argument("--train", action="store_true", help="train, test and drive the seven models")
    t.add_argument("--models", type=names, default=ORDER,
                   help="comma-separated, in training order (default: all seven)")
    t.add_argument("--epochs", type=int, default=20, help="epochs per model")
    t.add_argument("--hidden", type=int, default=256)
    t.add_argument("--generator-hidden", type=int, default=512)
    t.add_argument("--filters", type=int, default=32)
    t.add_argument("--learning-rate", type=float, default=1e-3)
    t.add_argument("--phase-floors", type=float, nargs="+", default=[0.0, PHASE_FLOOR])
    add_joint_blend_args(t, paper=True)
    t.add_argument("--data", type=Path, help="a style folder (default: $JAXSTYLE_MOCAP/100style)")
    t.add_argument("--styles", type=names,
                   help="comma-separated training styles (default: the paper's base styles of the sample)")
    t.add_argument("--out", type=Path, default=Path("runs/table2"))
    t.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    if args.train:
        unknown = [m for m in args.models if m not in PAPER]
        if unknown:
            raise SystemExit(f"error: unknown model(s) {', '.join(unknown)}; Table 2 has {', '.join(PAPER)}")
        return train(args)
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
