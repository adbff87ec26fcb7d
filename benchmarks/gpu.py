"""What matters on an accelerator, in one command of at most a few minutes: the few-shot sweep at
scale, LPN-FiLM training throughput and many live characters. Writes ``gpu.json`` and ``gpu.md``
(a markdown table) to ``--out`` and prints the table.

    python benchmarks/gpu.py [--out runs/bench_gpu]            # the full size (a GPU: about 5 min)
    python benchmarks/gpu.py --small [--out DIR]               # a reduced size, any machine (CPU: ~1 min)

Sections (``--sections``, default all; each is timed after its own compile, which is reported
apart, and a failing section is recorded with its error while the others run):

* ``sweep``: :func:`jaxstyle.mason2018.fewshot.adapter_sweep` on the paper-size 2018 network
  (234 -> 512 -> 512 -> 400, CP adapters of rank 30), 57 styles (100STYLE's few-shot half) x 8
  dropout rates in one program, 600 synthetic rows per style (+-5%), 100 epochs of batch 32, in
  the paper mode (dropout on every layer, float32) and the fast mode (dropout on the adapter path
  only, the frozen products in bfloat16): seconds, ms per step, (style, rate) pairs per second,
  the achieved GFLOP/s against plain matmuls of the same shapes, and one single run's time times
  the pair count (the Python loop of single runs that the sweep replaces, estimated).
* ``lpn``: LPN-FiLM training (Mason et al. 2022 at the paper's size: 95 styles, hidden 512, 8
  experts, the FiLM generator on 240 x 300 clips) with the training code
  (:func:`jaxstyle.mason2022.train._train_chunk`), one epoch of the shared 100STYLE sample (810
  steps of 32 rows; 25,920 samples) at batch 32 and at batch 128 (the same rows in 203 steps):
  samples per second.
* ``live``: ``jaxstyle play``'s frame (:meth:`jaxstyle.play.session.Session.step`: steering rows,
  one jitted call for the network step, foot locking and the scene's arrays, the copy back) for
  1024 characters on a random PFNN of the demo's size (hidden 256, rank 16) and a random
  paper-size LPN-FiLM (hidden 512): p50 / p95 ms per frame, frames per second, character-frames
  per second.

``--small``: a PFNN of hidden 64 and rank 8 for 2 styles x 2 rates of 200 rows and 2 epochs, an
LPN-FiLM of hidden 32 (generator on 48 x 300 clips, 8 filters) for 20 steps, 16 live characters
of the PFNN only: the same code paths at a size a CPU runs in under a minute (the test suite
runs it).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import tempfile
import time
import traceback
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import lpn_training  # noqa: E402  (this folder's scripts)
import play as play_bench  # noqa: E402
import sweep as sweep_bench  # noqa: E402

from jaxstyle.mason2018 import fewshot  # noqa: E402
from jaxstyle.nn import pfnn  # noqa: E402
from jaxstyle.play import session  # noqa: E402
from jaxstyle.train import scan  # noqa: E402

FULL = {"styles": 57, "rates": (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8), "frames": 600, "epochs": 100,
        "lpn_steps": 810, "lpn_batches": (32, 128), "characters": 1024, "frames_timed": 200}
SMALL = {"styles": 2, "rates": (0.1, 0.5), "frames": 200, "epochs": 2,
         "lpn_steps": 20, "lpn_batches": (32,), "characters": 16, "frames_timed": 10}
MODES = {"paper": {"adapter_dropout_only": False, "matmul_dtype": "float32"},
         "fast": {"adapter_dropout_only": True, "matmul_dtype": "bfloat16"}}


def _timed(fn) -> float:
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t0


def sweep_rows(size: dict, small: bool) -> list[dict]:
    model = pfnn.PFNNConfig(hidden_size=64, rank=8) if small else pfnn.PFNNConfig()
    rng = np.random.default_rng(0)
    styles = size["styles"]
    sizes = (size["frames"] * (1 + 0.05 * np.linspace(-1, 1, styles))).astype(int)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    rows = [np.arange(offsets[s], offsets[s + 1]) for s in range(styles)]
    n = int(offsets[-1])
    x = jnp.asarray(rng.normal(size=(n, model.input_size)), jnp.float32)
    y = jnp.asarray(rng.normal(size=(n, model.output_size)), jnp.float32)
    phase = jnp.asarray(rng.uniform(size=n), jnp.float32)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), model)
    out = []
    for mode, options in MODES.items():
        config = fewshot.SweepConfig(model=model, epochs=size["epochs"], rates=tuple(size["rates"]), **options)
        batches, mask = scan.sweep_batches(rows, config.epochs, config.batch_size)
        pairs, steps = styles * len(config.rates), int(batches.shape[1])
        sweep_bench._compile_seconds[0] = 0.0
        first = _timed(lambda config=config, batches=batches, mask=mask: fewshot.adapter_sweep(
            params, x, y, phase, batches, mask, config))
        compile_s = sweep_bench._compile_seconds[0]
        seconds = _timed(lambda config=config, batches=batches, mask=mask: fewshot.adapter_sweep(
            params, x, y, phase, batches, mask, config))
        one = lambda config=config, batches=batches, mask=mask: fewshot.finetune_one(  # noqa: E731
            params, x, y, phase, batches[0], mask[0], config.rates[0], scan.pair_key(config.seed, 0, 0), config)[0]
        _timed(one)
        single = _timed(one)
        flops = sweep_bench.sweep_flops(model, pairs * config.batch_size, config.adapter_dropout_only) * steps
        if config.adapter_dropout_only:
            flops += sweep_bench.frozen_flops_per_row(model) * n
        mm_s, mm_flops = sweep_bench.matmul_reference(model, pairs * config.batch_size, steps,
                                                      config.adapter_dropout_only, jnp.dtype(config.matmul_dtype))
        out.append({"mode": mode, "styles": styles, "rates": len(config.rates), "pairs": pairs, "steps": steps,
                    "epochs": config.epochs, "first_call_s": first, "compile_s": compile_s, "seconds": seconds,
                    "ms_per_step": 1e3 * seconds / steps, "pairs_per_s": pairs / seconds,
                    "gflop_s": flops / seconds / 1e9, "matmul_gflop_s": mm_flops / mm_s / 1e9,
                    "single_run_s": single, "loop_estimate_s": single * pairs})
        print(f"  sweep {mode}: {seconds:.2f} s ({1e3 * seconds / steps:.2f} ms per step, compile {compile_s:.1f} s)",
              flush=True)
    return out


def small_lpn_config():
    from jaxstyle.nn import film_generator as film
    from jaxstyle.nn.style_models import StyleModelConfig

    generator = film.FiLMConfig(clip_frames=48, filters=8, width=5, hidden=64, film_size=128)
    return StyleModelConfig("lpn", "film", num_styles=lpn_training.NUM_STYLES, hidden_size=32, generator=generator)


def lpn_rows(size: dict, small: bool) -> list[dict]:
    out = []
    samples = size["lpn_steps"] * 32  # one epoch of the shared sample at batch 32 (full size)
    for batch in size["lpn_batches"]:
        steps = max(1, samples // batch)
        run, state, (_, mc, *_rest) = lpn_training._step_runner("LPN FiLM", steps, batch, None,
                                                                small_lpn_config() if small else None)
        t0 = time.perf_counter()
        state = run(state)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        run(state)
        seconds = time.perf_counter() - t0
        out.append({"model": "LPN FiLM", "hidden": mc.hidden_size, "batch": batch, "steps": steps,
                    "samples": steps * batch, "first_call_s": first, "seconds": seconds,
                    "ms_per_step": 1e3 * seconds / steps, "samples_per_s": steps * batch / seconds})
        print(f"  lpn batch {batch}: {steps * batch / seconds:,.0f} samples/s", flush=True)
    return out


def live_rows(size: dict, small: bool) -> list[dict]:
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        models = {"PFNN (hidden 256, rank 16)": lambda: play_bench.demo_size_model(Path(tmp) / "pfnn")}
        if not small:  # the 2022 session's frame is the same program (tests/test_play.py runs it on a CPU)
            models["LPN FiLM (hidden 512)"] = lambda: play_bench.random_lpn_model(Path(tmp) / "lpn", 512)
        for name, make in models.items():
            model = make()
            s = session.Session(model)
            t0 = time.perf_counter()
            while len(s.characters) < size["characters"]:
                s.add_character()
            add_s = time.perf_counter() - t0
            s.walk_to(0.0, 50.0)
            t0 = time.perf_counter()
            s.step()
            first = time.perf_counter() - t0
            for _ in range(10):
                s.step()
            ms = []
            for _ in range(size["frames_timed"]):
                t0 = time.perf_counter()
                frame = s.step()
                ms.append(1e3 * (time.perf_counter() - t0))
            assert np.isfinite(frame.positions).all()
            p50, p95 = float(np.median(ms)), float(np.percentile(ms, 95))
            c = len(s.characters)
            out.append({"model": name, "characters": c, "add_characters_s": add_s, "first_frame_s": first,
                        "p50_ms": p50, "p95_ms": p95, "frames_per_s": 1e3 / p50,
                        "character_frames_per_s": c * 1e3 / p50})
            print(f"  live {name}: {c} characters, {p50:.2f} ms per frame (p95 {p95:.2f})", flush=True)
    return out


COLUMNS = {  # per section: (column title, cell of one result row)
    "sweep": [("sweep mode", lambda r: r["mode"]), ("styles x rates", lambda r: f"{r['styles']} x {r['rates']}"),
              ("steps", lambda r: f"{r['steps']}"), ("compile s", lambda r: f"{r['compile_s']:.1f}"),
              ("sweep s", lambda r: f"{r['seconds']:.2f}"), ("ms per step", lambda r: f"{r['ms_per_step']:.2f}"),
              ("pairs per s", lambda r: f"{r['pairs_per_s']:.1f}"), ("GFLOP/s", lambda r: f"{r['gflop_s']:.0f}"),
              ("matmul GFLOP/s", lambda r: f"{r['matmul_gflop_s']:.0f}"),
              ("sweep / matmul", lambda r: f"{r['gflop_s'] / r['matmul_gflop_s']:.2f}"),
              ("loop of single runs s (estimate)", lambda r: f"{r['loop_estimate_s']:.1f}")],
    "lpn": [("LPN training", lambda r: r["model"]), ("hidden", lambda r: f"{r['hidden']}"),
            ("batch", lambda r: f"{r['batch']}"), ("steps", lambda r: f"{r['steps']}"),
            ("first call s", lambda r: f"{r['first_call_s']:.1f}"), ("s", lambda r: f"{r['seconds']:.2f}"),
            ("ms per step", lambda r: f"{r['ms_per_step']:.2f}"),
            ("samples per s", lambda r: f"{r['samples_per_s']:,.0f}")],
    "live": [("live model", lambda r: r["model"]), ("characters", lambda r: f"{r['characters']}"),
             ("first frame s", lambda r: f"{r['first_frame_s']:.1f}"), ("p50 ms", lambda r: f"{r['p50_ms']:.2f}"),
             ("p95 ms", lambda r: f"{r['p95_ms']:.2f}"), ("frames per s", lambda r: f"{r['frames_per_s']:.0f}"),
             ("character-frames per s", lambda r: f"{r['character_frames_per_s']:,.0f}")],
}


def markdown(result: dict) -> str:
    lines = [f"Machine: {result['device']}; host {result['host']}; jax {result['jax']}; {result['date']}; "
             f"{'small' if result['small'] else 'full'} size", ""]
    for section, columns in COLUMNS.items():
        if section not in result:
            continue
        lines += ["| " + " | ".join(title for title, _ in columns) + " |", "|" + "---|" * len(columns)]
        lines += ["| " + " | ".join(cell(r) for _, cell in columns) + " |" for r in result[section]]
        lines.append("")
    for name, error in result.get("errors", {}).items():
        lines.append(f"{name}: FAILED: {error}")
    return "\n".join(lines) + "\n"


def run(small: bool, sections, out: Path) -> dict:
    size = SMALL if small else FULL
    dev = jax.devices()[0]
    result = {"device": f"{dev.device_kind} ({dev.platform}) x {jax.device_count()}",
              "host": f"{platform.machine()}, {os.cpu_count()} cores", "jax": jax.__version__,
              "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
              "small": small, "size": {k: list(v) if isinstance(v, tuple) else v for k, v in size.items()}}
    print(f"{result['device']}; {result['host']}; jax {result['jax']}", flush=True)
    work = {"sweep": lambda: sweep_rows(size, small), "lpn": lambda: lpn_rows(size, small),
            "live": lambda: live_rows(size, small)}
    for name in sections:
        t0 = time.perf_counter()
        try:
            result[name] = work[name]()
        except Exception as e:  # one failing section must not lose the others' figures
            traceback.print_exc()
            result.setdefault("errors", {})[name] = f"{type(e).__name__}: {e}"
        result.setdefault("section_s", {})[name] = time.perf_counter() - t0
        out.mkdir(parents=True, exist_ok=True)
        (out / "gpu.json").write_text(json.dumps(result, indent=1))  # after each section: a timeout keeps the rest
        (out / "gpu.md").write_text(markdown(result))
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--small", action="store_true", help="a reduced size that a CPU runs in about a minute")
    parser.add_argument("--out", type=Path, default=Path("runs/bench_gpu"), help="folder for gpu.json and gpu.md")
    parser.add_argument("--sections", nargs="+", choices=("sweep", "lpn", "live"), default=["sweep", "lpn", "live"])
    args = parser.parse_args(argv)
    result = run(args.small, args.sections, args.out)
    print(markdown(result))
    return 1 if result.get("errors") else 0


if __name__ == "__main__":
    sys.exit(main())
