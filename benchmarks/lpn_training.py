"""Training-step throughput of the seven Table 2 models (Mason, Starke & Komura 2022) at the
paper's sizes, against this machine's limit measured in the same run, and LPN-FiLM side by side
with the code of commit 1508a4f (before this benchmark's changes). No motion capture needed.

    python benchmarks/lpn_training.py [--steps 8] [--runs 3] [--rounds 2] [--models "LPN FiLM" ...]
                                      [--skip-table] [--skip-compare] [--base 1508a4f]

For each model (95 styles, batch 32, dropout 0.3, Adam 1e-4, random normalised rows; a FiLM
model reads one 240 x 300 clip per step) it prints:

* ``step ms``: one step of :func:`jaxstyle.mason2022.train._train_chunk` (the training code
  itself, ``--steps`` steps per compiled call, the median over ``--runs`` calls, per step);
* ``GFLOP``: the analytic count (every forward product once, its two backward products, the first
  layers' input gradients left out as the inputs are data; conv as its im2col product) and, in
  brackets, XLA's ``cost_analysis()`` of one compiled step;
* ``MB moved``: parameters and Adam state (read p, g, m, v; write p, m, v, g: 32 bytes per
  parameter) plus activations (written forward, read backward, gradient written: 12 bytes per
  value);
* ``limit ms``: the same work as plain operations timed here, now: every product of the step as a
  plain ``jnp.matmul`` of its shape (forward and backward), plus the bytes streamed at the rate of
  a plain donated in-place update of an array as large as the model's parameters;
* ``ratio``: step / limit.

Then the LPN-FiLM step's parts (generator forward+backward, synthesis forward+backward, the Adam
update with and without donated buffers), and the side-by-side comparison: ``git archive BASE
jaxstyle`` into a temporary folder, the same timing in a subprocess with ``PYTHONPATH`` there and
in one with this tree, alternated ``--rounds`` times so both see the same machine load; per epoch
is 810 steps of 32 rows (an epoch of the shared 100STYLE sample) at the option's batch size.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EPOCH_ROWS = 810 * 32  # one epoch of the shared 100STYLE sample at batch 32 (810 steps)
NUM_STYLES = 95
ROWS = 16384  # >= 128 rows per style for the batch-128 option


# --- synthetic data and one model's step ---------------------------------------------------------

def _rows_module():
    """The module of the training rows in the code on ``sys.path``: ``jaxstyle.mason2022.styledata``
    (``BonePositions``, ``StyleData``, ``device_arrays``, ``StaticBones``); the archived code of
    ``--base`` 1508a4f has them in ``jaxstyle.mason2022.train``, under private names for the last two."""
    import types

    try:
        from jaxstyle.mason2022 import styledata
        return styledata
    except ImportError:
        from jaxstyle.mason2022 import train as T
        return types.SimpleNamespace(BonePositions=T.BonePositions, StyleData=T.StyleData,
                                     device_arrays=T._device_arrays, StaticBones=T._Static)


def _data(D, mc, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(ROWS, mc.input_size)).astype(np.float32)
    y = rng.normal(size=(ROWS, mc.output_size)).astype(np.float32)
    gate = (rng.uniform(size=(ROWS, 1)) if mc.backbone == "pfnn" else rng.normal(size=(ROWS, mc.gating_input)))
    g = mc.generator
    n_clips = 2 * mc.num_styles if mc.modulation == "film" else mc.num_styles
    frames, feats = (g.clip_frames, g.clip_features) if mc.modulation == "film" else (1, 1)
    clips = rng.normal(size=(n_clips, frames, feats)).astype(np.float32)
    per = ROWS // mc.num_styles
    rows = tuple(np.arange(s * per, (s + 1) * per) for s in range(mc.num_styles))
    joints = 27  # 100STYLE's LPN bones: 26 bones of a 27-joint chain is the worst case for the loss
    bones = D.BonePositions(0, np.full(3 * joints, 0.1, np.float32), np.zeros(3 * joints, np.float32),
                            tuple([-1] + list(range(joints - 1))))
    train_clips = tuple(np.arange(2 * s, 2 * s + 2) % n_clips for s in range(mc.num_styles))
    return D.StyleData(x, y, gate.astype(np.float32), clips, rows, rows, rows, train_clips,
                       tuple(f"s{s}" for s in range(mc.num_styles)), bones)


def _step_runner(name: str, steps: int, batch: int, compute_dtype: str | None, mc=None):
    """``(run, state)``: ``run(state) -> state`` does ``steps`` training steps of Table 2's ``name``
    (at the paper's sizes, or the model config ``mc``) with the training code on ``sys.path``
    (today's or the archived one)."""
    import jax
    import jax.numpy as jnp

    from jaxstyle.mason2022 import train as T
    from jaxstyle.nn.style_models import StyleModelConfig

    mc = mc or StyleModelConfig.paper(name, NUM_STYLES)
    lr = 1e-4 * (batch / 32) ** 0.5
    config = T.LPNTrainConfig(model=mc, batch_size=batch, learning_rate=lr)
    styledata = _rows_module()
    data = _data(styledata, mc)
    arrays = styledata.device_arrays(data)
    bones = styledata.StaticBones(data.bones)
    batches, styles, clips = T.epoch_batches(data, config, 0)
    reps = -(-steps // len(batches))
    batches, styles, clips = (np.concatenate([a] * reps)[:steps] for a in (batches, styles, clips))
    keys = jax.random.split(jax.random.PRNGKey(1), steps)
    extra = {} if compute_dtype is None else {"compute_dtype": compute_dtype}
    inputs = (jnp.asarray(batches), jnp.asarray(styles), jnp.asarray(clips), keys)

    def run(state):
        params, opt, out = T._train_chunk(state[0], state[1], arrays, *inputs, jnp.float32(0.3), jnp.float32(1.0),
                                          config=mc, bones=bones, learning_rate=lr, **extra)
        jax.block_until_ready(out)
        return params, opt

    state = T.init_state(jax.random.PRNGKey(0), config)
    return run, (state.params, state.opt_state), (T, mc, config, data, arrays, bones, inputs, lr, extra)


def time_steps(name: str, steps: int, runs: int, batch: int = 32, compute_dtype: str | None = None) -> dict:
    run, state, _ = _step_runner(name, steps, batch, compute_dtype)
    t0 = time.perf_counter()
    state = run(state)  # compile + first call
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        state = run(state)
        times.append((time.perf_counter() - t0) / steps)
    return {"step_s": float(np.median(times)), "all": times, "compile_s": compile_s}


# --- analytic work of a step -----------------------------------------------------------------------

def products(mc, batch: int = 32) -> list[tuple[int, int, int, bool]]:
    """``(M, K, N, input_grad)`` of every forward product of one step: ``input_grad`` False where
    the input is data (no input gradient)."""
    h, k, b = mc.hidden_size, mc.experts, batch
    out = [(b, mc.input_size, k * h, False), (b, h, k * h, True), (b, h, k * mc.output_size, True)]
    if mc.backbone != "pfnn":
        g = mc.gating_hidden
        out += [(b, mc.gating_input, g, False), (b, g, g, True), (b, g, mc.num_experts, True)]
    if mc.modulation == "resad":
        out.append((b, h, mc.rank * k if mc.backbone == "pfnn" else h, True))
        if mc.backbone == "pfnn":
            out.append((b, mc.rank * k, h, True))
    if mc.modulation == "film":
        c = mc.generator
        out += [(c.clip_frames, c.width * c.clip_features, c.filters, False),
                (c.clip_frames // 2, c.width * c.filters, c.filters, True),
                (1, c.pooled_frames * c.filters, c.hidden, True), (1, c.hidden, c.film_size, True)]
    return out


def flops(mc, batch: int = 32) -> float:
    return float(sum(2 * m * kk * n * (3 if grad else 2) for m, kk, n, grad in products(mc, batch)))


def activations(mc, batch: int = 32) -> int:
    """Forward values kept for the backward pass (layer inputs and outputs, expert outputs)."""
    h, k, b = mc.hidden_size, mc.experts, batch
    n = b * (mc.input_size + 2 * h * (k + 3) + mc.output_size * (k + 1))
    if mc.modulation == "film":
        c = mc.generator
        n += c.clip_frames * c.filters * 2 + c.clip_frames // 2 * c.filters * 2 + 2 * c.hidden + c.film_size
    return n


def xla_cost(name: str) -> tuple[float, float]:
    """``(flops, bytes)`` of one compiled step from XLA's ``cost_analysis()``."""
    import jax

    from jaxstyle.mason2022 import train as T
    from jaxstyle.nn.style_models import StyleModelConfig

    mc = StyleModelConfig.paper(name, NUM_STYLES)
    config = T.LPNTrainConfig(model=mc)
    styledata = _rows_module()
    data = _data(styledata, mc)
    arrays, bones = styledata.device_arrays(data), styledata.StaticBones(data.bones)
    state = T.init_state(jax.random.PRNGKey(0), config)
    b, s, c = (np.asarray(a[:1]) for a in T.epoch_batches(data, config, 0))
    lowered = T._train_chunk.lower(state.params, state.opt_state, arrays, b, s, c,
                                   jax.random.split(jax.random.PRNGKey(1), 1), np.float32(0.3), np.float32(1.0),
                                   config=mc, bones=bones, learning_rate=1e-4)
    cost = lowered.compile().cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return float(cost.get("flops", np.nan)), float(cost.get("bytes accessed", np.nan))


# --- plain operations timed now ----------------------------------------------------------------

def _time(f, *args, calls: int = 3) -> float:
    import jax

    jax.block_until_ready(f(*args))
    best = []
    for _ in range(calls):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        best.append(time.perf_counter() - t0)
    return float(np.median(best))


_MATMUL_CACHE: dict = {}


def matmul_seconds(mc, batch: int = 32) -> float:
    """Every product of the step as a plain f32 ``jnp.matmul`` of its shape, forward and backward."""
    import jax
    import jax.numpy as jnp

    mm = jax.jit(jnp.matmul)
    total = 0.0
    for m, k, n, grad in products(mc, batch):
        shapes = [((m, k), (k, n)), ((k, m), (m, n))] + ([((m, n), (n, k))] if grad else [])
        for a, b in shapes:
            if (a, b) not in _MATMUL_CACHE:
                _MATMUL_CACHE[(a, b)] = _time(mm, jnp.ones(a), jnp.ones(b))
            total += _MATMUL_CACHE[(a, b)]
    return total


def stream_rate(values: int) -> float:
    """Bytes per second of a plain donated in-place update ``a <- 0.9 a + b`` of ``values`` float32
    (reads 8, writes 4 bytes per value)."""
    import jax
    import jax.numpy as jnp

    f = jax.jit(lambda a, b: 0.9 * a + b, donate_argnums=0)
    a, b = jnp.ones(values), jnp.ones(values)
    a = f(a, b)
    ts = []
    for _ in range(5):
        t0 = time.perf_counter()
        a = f(a, b)
        jax.block_until_ready(a)
        ts.append(time.perf_counter() - t0)
    return 12 * values / float(np.median(ts))


def table(names, steps: int, runs: int) -> None:
    from jaxstyle.nn import style_models
    from jaxstyle.nn.style_models import StyleModelConfig

    print("| model | params | step ms | GFLOP analytic (XLA) | MB moved (XLA) | matmul ms | stream GB/s | "
          "limit ms | ratio |\n|---|---|---|---|---|---|---|---|---|", flush=True)
    for name in names:
        mc = StyleModelConfig.paper(name, NUM_STYLES)
        import jax

        p = style_models.tree_size(jax.eval_shape(lambda mc=mc: style_models.init_model(jax.random.PRNGKey(0), mc)))
        t = time_steps(name, steps, runs)["step_s"]
        xf, xb = xla_cost(name)
        moved = 32 * p + 12 * activations(mc)
        t_mm = matmul_seconds(mc)
        rate = stream_rate(max(p, 1 << 20))
        limit = t_mm + moved / rate
        print(f"| {name} | {p / 1e6:.2f} M | {t * 1e3:.1f} | {flops(mc) / 1e9:.2f} ({xf / 1e9:.2f}) | "
              f"{moved / 1e6:.0f} ({xb / 1e6:.0f}) | {t_mm * 1e3:.1f} | {rate / 1e9:.1f} | {limit * 1e3:.1f} | "
              f"{t / limit:.2f} |", flush=True)


def profile_film(steps: int, runs: int) -> None:
    """Where an LPN-FiLM step goes: the training step with one part switched off at a time (its
    gradient stopped, or the Adam update skipped), each compiled as the real step (a donated
    ``lax.scan`` of ``steps`` steps); the difference to the full step is that part's cost."""
    import jax
    import jax.numpy as jnp
    import optax

    from jaxstyle.nn import film_generator as film

    _, state, (T, mc, config, data, arrays, bones, inputs, lr, extra) = _step_runner("LPN FiLM", steps, 32, None)
    opt = optax.adam(lr)

    def chunk(params, opt_state, variant):
        def step(carry, inp):
            p, o = carry
            *step_inputs, key = inp

            def loss(p):
                gen = dict(p["style"]["generator"])
                frozen = {"no conv kernel gradients": ("conv1", "conv2"), "no dense gradients": ("dense1", "dense2"),
                          "no generator gradient": tuple(gen)}.get(variant, ())
                for name in frozen:
                    gen[name] = jax.lax.stop_gradient(gen[name])
                p = {**p, "style": {"generator": gen}}
                return T._step_loss(p, mc, arrays, step_inputs, key, 0.3, 1.0, bones, "float32")

            (v, _), g = jax.value_and_grad(loss, has_aux=True)(p)
            if variant == "gradients only, no Adam update":
                return (p, o), v + sum(jnp.sum(x.ravel()[:1]) for x in jax.tree.leaves(g))
            u, o = opt.update(g, o, p)
            return (optax.apply_updates(p, u), o), v

        (params, opt_state), out = jax.lax.scan(step, (params, opt_state), inputs)
        return params, opt_state, out

    compiled = jax.jit(chunk, static_argnames=("variant",), donate_argnums=(0, 1))
    variants = ["full step", "full step, XLA's convolution (before)", "no conv kernel gradients",
                "no dense gradients", "no generator gradient", "gradients only, no Adam update"]
    p, o = state
    print(f"\n| LPN-FiLM step with one part off (donated scan of {steps} steps) | ms/step | "
          "that part costs |\n|---|---|---|")
    full = None
    for variant in variants:
        saved = film.IM2COL_VALUES
        if variant.endswith("(before)"):
            film.IM2COL_VALUES = 0
        try:
            p, o, out = compiled(p, o, variant=variant)
            jax.block_until_ready(out)
            ts = []
            for _ in range(runs):
                t0 = time.perf_counter()
                p, o, out = compiled(p, o, variant=variant)
                jax.block_until_ready(out)
                ts.append((time.perf_counter() - t0) / steps)
        finally:
            film.IM2COL_VALUES = saved
        t = float(np.median(ts))
        full = t if full is None else full
        cost = "" if variant == "full step" else f"{(full - t) * 1e3:+.0f} ms"
        print(f"| {variant} | {t * 1e3:.0f} | {cost} |", flush=True)


# --- side by side with the archived code ---------------------------------------------------------

VARIANTS = {"before (1508a4f), batch 32": ("old", 32, None),
            "now, batch 32 (paper's settings)": ("new", 32, None),
            "now, bf16 products, batch 32": ("new", 32, "bfloat16"),
            "now, batch 64, lr 1.41e-4 (sqrt rule)": ("new", 64, None),
            "now, batch 128, lr 2e-4 (sqrt rule)": ("new", 128, None),
            "now, bf16, batch 128, lr 2e-4": ("new", 128, "bfloat16")}


def worker(args) -> None:
    r = time_steps("LPN FiLM", args.steps, args.runs, args.batch, args.dtype)
    print("RESULT " + json.dumps(r), flush=True)


def compare(args) -> None:
    base_dir = Path(tempfile.mkdtemp(prefix="jaxstyle_base_"))
    archive = subprocess.run(["git", "archive", args.base, "jaxstyle"], cwd=ROOT, check=True, capture_output=True)
    with tarfile.open(fileobj=__import__("io").BytesIO(archive.stdout)) as tar:
        tar.extractall(base_dir, filter="data")
    results: dict[str, list[float]] = {k: [] for k in VARIANTS}
    for rnd in range(args.rounds):
        for label, (code, batch, dtype) in VARIANTS.items():
            env = {**os.environ, "PYTHONPATH": str(base_dir if code == "old" else ROOT)}
            cmd = [sys.executable, __file__, "--worker", "--steps", str(args.steps), "--runs", str(args.runs),
                   "--batch", str(batch)] + ([] if dtype is None else ["--dtype", dtype])
            out = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=base_dir)
            line = [x for x in out.stdout.splitlines() if x.startswith("RESULT ")]
            if out.returncode or not line:
                raise SystemExit(f"{label}: worker failed\n{out.stderr[-3000:]}")
            results[label].append(json.loads(line[0][7:])["step_s"])
            print(f"  round {rnd + 1}: {label}: {results[label][-1] * 1e3:.0f} ms/step", flush=True)
    old = float(np.median(results["before (1508a4f), batch 32"]))
    print(f"\n| LPN-FiLM, side by side ({args.rounds} alternating rounds, median) | ms/step | s/epoch "
          f"({EPOCH_ROWS:,} rows) | epoch speed-up vs before |\n|---|---|---|---|")
    for label, (_, batch, _) in VARIANTS.items():
        t = float(np.median(results[label]))
        epoch = t * EPOCH_ROWS / batch
        print(f"| {label} | {t * 1e3:.0f} | {epoch:.0f} | {old * EPOCH_ROWS / 32 / epoch:.2f}x |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=8, help="steps per compiled call")
    parser.add_argument("--runs", type=int, default=3, help="timed calls per measurement (median)")
    parser.add_argument("--rounds", type=int, default=2, help="alternating before/now rounds")
    parser.add_argument("--models", nargs="+", help="Table 2 models (default all seven)")
    parser.add_argument("--base", default="1508a4f", help="the commit timed as 'before'")
    parser.add_argument("--skip-table", action="store_true")
    parser.add_argument("--skip-compare", action="store_true")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--batch", type=int, default=32, help=argparse.SUPPRESS)
    parser.add_argument("--dtype", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        return worker(args)
    sys.path.insert(0, str(ROOT))
    import jax

    from jaxstyle.nn.style_models import TABLE2

    dev = jax.devices()[0]
    print(f"device: {dev.device_kind} ({dev.platform}), {platform.machine()} host with {os.cpu_count()} cores, "
          f"jax {jax.__version__}, load average {os.getloadavg()[0]:.1f}\n")
    if not args.skip_table:
        table(args.models or list(TABLE2), args.steps, args.runs)
        profile_film(args.steps, args.runs)
    if not args.skip_compare:
        print()
        compare(args)


if __name__ == "__main__":
    main()
