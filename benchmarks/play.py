"""Server-side cost of one ``jaxstyle play`` frame: the step of every character (one jitted call:
network, foot locking and the scene's arrays, :meth:`jaxstyle.play.session.Session.step`) and the
viser scene update (one node for all bones, one for all joints, one for all future trajectories,
targets, camera), for 1, 8, 32 and 64 characters, with and without foot locking.

    python benchmarks/play.py [--run RUN] [--model pfnn|lpn-film] [--frames 600] [--characters 1 8 32 64]
    python benchmarks/play.py --run runs/demo --screenshot docs/figures/play.png
    python benchmarks/play.py --run runs/demo --learn

``--learn``: learning a style live, from upload to playing. A copy of the run's base and data
(the run folder is not written) is served with the render loop running and one character walking,
no page connected; a 10 s clip (the first 10 s of the base data's ``Proud/Proud_FR.bvh``, else
of its first clip) is given to the page's upload handler, and the time until the new style is in
the style list is measured, then again for an 8 s clip (another length) in the same session.
This runs twice, each in a fresh process: with an empty compilation cache
(``jaxstyle.cli.common.use_xla_cache``, as after installing) and with the cache the first filled
(every later ``jaxstyle play``). Then, without the render loop, the validation loss of the
chosen rate at the live epochs (``--learn-epochs``, default ``jaxstyle play``'s) and at 40 (the demo's
sweep).

``--screenshot``: the page in headless Chromium (/usr/bin/chromium through playwright, as the
browser tests), two characters walking to waypoints in two styles (the README's figure).

With ``--run`` the run folder's model is timed (e.g. ``runs/demo``); without it, a PFNN of the
demo's size (hidden 256, CP adapters of rank 16; random weights: timing does not depend on their
values) on a procedural skeleton (25 joints). ``--model lpn-film``: the 2022 model instead, the run's
(``RUN/lpn``) or a random LPN-FiLM of ``--hidden`` units (default 512, the paper's; 8 experts, the
FiLM vector a per-character argument) on procedural styles. The characters walk (a waypoint ahead, the first
one a blend of two styles). The viser server runs in this process with no page connected: the
scene messages are built and queued as for a page, not sent over a network. The step is timed with
the feet locked (the default) and unlocked, frame by frame in turn. Targets, step + scene update
with the feet locked, on the 2-core CPU: p95 <= 4 ms per frame for up to 8 characters, <= 16 ms
for 64 (and 32); locking <= 1.2x the unlocked step.
"""

from __future__ import annotations

import argparse
import os
import platform
import socket
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from jaxstyle.control.controller import PFNNModel
from jaxstyle.data import datasets, folders, procedural
from jaxstyle.data.datasets import style_rows
from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2018 import base_model, fewshot, pipeline
from jaxstyle.mason2022 import pipeline as pipeline2022
from jaxstyle.mason2022 import styledata
from jaxstyle.mason2022 import synthesis as synthesis2022
from jaxstyle.nn import pfnn, style_models
from jaxstyle.play import models
from jaxstyle.train.defaults import LEARN_EPOCHS


def demo_size_model(folder: Path, hidden: int = 256, rank: int = 16) -> models.PlayModel:
    """A random PFNN of the demo's size with three random styles, on a procedural clip."""
    root = procedural.write_dataset(folder / "data", ["Neutral"], ["FW"], seconds=6.0)
    settings = base_model.BaseSettings(data=str(root), styles=("Neutral",), hidden=hidden, rank=rank, epochs=1)
    dataset = base_model.build(folders.clip_specs(root, settings.styles, None), None)
    layout = PFNNLayout((dataset.inputs.shape[1] - 48) // 6)
    config = pfnn.PFNNConfig(input_size=layout.input_size, output_size=layout.output_size, hidden_size=hidden,
                             rank=rank)
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    params = pfnn.init_pfnn(keys[0], config)
    adapters = [pfnn.init_adapter(k, config) for k in keys[1:]]
    skeleton = datasets.load_clip(dataset.specs[0], fps=60.0)
    base = base_model.Base(params, pfnn.stack_adapters(adapters[:1]), dataset.normalisers(), config, dataset, skeleton,
                         settings)
    styles = {name: models.Style(name, "base", None, a) for name, a in zip(("A", "B", "C"), adapters, strict=True)}
    upm = estimate_units_per_meter(skeleton)
    speed = PFNNModel.own_speed(dataset, style_rows(dataset, "Neutral"), upm)
    return models.PlayModel(base, styles=styles, units_per_meter=upm, speed=speed, run_dir=folder)


def random_lpn_model(folder: Path, hidden: int = 512) -> models.LPNPlayModel:
    """A random LPN-FiLM (``hidden`` units, the demo's FiLM generator preset) on two procedural styles."""
    root = procedural.write_dataset(folder / "data", ["Neutral", "Crouched"], ["FW"], seconds=8.0, progress=False)
    styles, _ = folders.split_styles(root, [])
    data = pipeline2022.build_data(root, styles)
    config = pipeline2022.model_config(data.base, hidden=hidden, generator_hidden=512, filters=32)
    params = style_models.init_model(jax.random.PRNGKey(0), config)
    model = pipeline2022.Model(pipeline2022.MODEL, config, params,
                               styledata.style_data(data.base, data.skeleton))
    return models.lpn_play_model(synthesis2022.Loaded(model, data, folder / "lpn", 0), folder)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def time_frames(server, characters: int, frames: int) -> dict[str, np.ndarray]:
    """Per-frame milliseconds over ``frames`` frames after 30 warm-up ones: the session's step with
    foot locking (``step``, :mod:`jaxstyle.output.footlock`, the default) and without it
    (``step_unlocked``), interleaved frame by frame so both see the same machine load, and the step
    plus the scene update (``total``, locking on)."""
    s = server.session
    while len(s.characters) < characters:
        s.add_character()
    names = list(s.styles)
    if len(names) >= 2:
        s.set_blend(names[:2], [0.5, 0.5])
    s.walk_to(0.0, 50.0)
    out = {"step": [], "step_unlocked": [], "total": []}
    for k in range(2 * frames + 60):
        locked = k % 2 == 0
        s.foot_lock = locked
        t0 = time.perf_counter()
        frame = s.step()
        t1 = time.perf_counter()
        if locked:
            server._update_scene(frame, s.targets())
        t2 = time.perf_counter()
        if k >= 60:  # after compiling for this number of characters and creating its scene nodes
            out["step" if locked else "step_unlocked"].append(1e3 * (t1 - t0))
            if locked:
                out["total"].append(1e3 * (t2 - t0))
    s.foot_lock = True
    return {k: np.asarray(v) for k, v in out.items()}


def screenshot(run: Path, path: Path) -> None:
    """The page on ``run`` with a Crouched and a Proud_FW character walking to two waypoints."""
    from playwright.sync_api import sync_playwright

    from jaxstyle.play.guard import Serving
    from jaxstyle.play.server import PlayServer

    args = ["--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic"]
    server = PlayServer(run, Serving(port=free_port())).start()
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=args)
            page = browser.new_page(viewport={"width": 1280, "height": 720})
            page.goto(server.url)
            page.wait_for_selector("canvas")
            time.sleep(3)
            with server.lock:
                names = list(server.session.styles)
                second = "Proud_FW" if "Proud_FW" in names else names[-1]
                first = "Crouched" if "Crouched" in names else names[0]
                server.session.add_character(second)
                server.set_style(first)
                server.session.walk_to(2.5, 5.0)
                server.session.walk_to(-1.5, 10.0, append=True)
            time.sleep(2.5)
            page.add_style_tag(content=".mantine-Notifications-root{display:none !important}")  # software-WebGL note
            time.sleep(0.5)
            path.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(path))
            browser.close()
    finally:
        server.stop()
    print(f"wrote {path}")


def _clip(run: Path, seconds: float, folder: Path, name: str, prefer: str) -> Path:
    """The first ``seconds`` of the base data's ``prefer`` clip (else its first), written to ``folder``."""
    from jaxstyle.motion import bvh

    data = run / "data"
    source = data / prefer if (data / prefer).is_file() else sorted(data.rglob("*.bvh"))[0]
    motion = bvh.read_bvh(source)
    path = folder / f"{name}.bvh"
    bvh.write_bvh(motion.frames(0, int(round(seconds * motion.fps))), path)
    return path


def learn_once(run: Path, epochs: int) -> None:
    """One process's upload-to-playing times (two clips, one session); prints one line per clip."""
    import shutil
    import types

    from jaxstyle.cli.common import use_xla_cache
    from jaxstyle.play.guard import Serving
    from jaxstyle.play.learn_panel import Learning
    from jaxstyle.play.server import PlayServer

    use_xla_cache()
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "run"
        for part in ("base", "data"):
            shutil.copytree(run / part, copy / part)
        clips = [_clip(copy, 10.0, Path(tmp), "Proud10", "Proud/Proud_FR.bvh"),
                 _clip(copy, 8.0, Path(tmp), "Limping8", "Limping/Limping_FW.bvh")]
        server = PlayServer(copy, Serving(port=free_port()), Learning(epochs=epochs)).start()
        try:
            server.session.walk_to(0.0, 50.0)
            time.sleep(3.0)  # walking, the reader process started
            for clip in clips:
                upload = types.SimpleNamespace(name=clip.name, content=clip.read_bytes())
                t0 = time.monotonic()
                server._on_upload(upload)
                while clip.stem not in server.session.styles:
                    state = server.learner.status()[0] if server.learner else "none"
                    if state == "failed" or time.monotonic() - t0 > 600:
                        raise SystemExit(f"learning {clip.name} failed: {server.message}")
                    time.sleep(0.02)
                seconds = time.monotonic() - t0
                frames = [t for t in server.frame_times if t >= t0]
                gaps = np.diff(frames) if len(frames) > 1 else np.array([np.nan])
                print(f"LEARN {clip.stem} {seconds:.2f} {len(frames) / seconds:.1f} {1e3 * np.max(gaps):.0f} "
                      f"{server.learner.status()[2]}", flush=True)
        finally:
            server.stop()


def learn_benchmark(run: Path, epochs: int) -> None:
    """Upload-to-playing with an empty and a filled compilation cache (each in a fresh process),
    and the validation loss of the live epochs' chosen rate beside 40 epochs' (the demo's sweep)."""
    import dataclasses
    import subprocess
    import sys

    print(f"jaxstyle play, learning a style live; {platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} "
          f"on {jax.devices()[0].platform}; {run}, {epochs} epochs, rates 0.3 0.5 0.7; render loop running, "
          "one character walking")
    print("| compilation cache | clip | upload to playing (s) | frames/s meanwhile | longest frame gap (ms) | "
          "target <= 30 s |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "JAXSTYLE_XLA_CACHE": cache, "PYTHONUNBUFFERED": "1"}
        for label in ("empty", "filled by the run above"):
            out = subprocess.run([sys.executable, __file__, "--run", str(run), "--learn-once", "--learn-epochs",
                                  str(epochs)], env=env, capture_output=True, text=True, check=False)
            lines = [line.split(" ", 5) for line in out.stdout.splitlines() if line.startswith("LEARN ")]
            if out.returncode or len(lines) != 2:
                raise SystemExit(f"the learning run failed:\n{out.stdout[-2000:]}\n{out.stderr[-2000:]}")
            for k, (_, clip, seconds, fps, gap, _) in enumerate(lines):
                where = "first clip of the session" if k == 0 else "second clip, same session"
                print(f"| {label} | {clip} ({where}) | {float(seconds):.1f} | {fps} | {gap} | "
                      f"{'met' if float(seconds) <= 30 else 'NOT met'} |", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        clip = _clip(run, 10.0, Path(tmp), "Proud10", "Proud/Proud_FR.bvh")
        base = base_model.load_base(run / "base", progress=False)
        specs = [dataclasses.replace(s, style="Proud10") for s in folders.user_clip_specs([clip], True, None)]
        cells = []
        for e in (epochs, 40):
            result = pipeline.run_sweep(base, specs, fewshot.SweepConfig(epochs=e), progress=False).result
            cells.append(f"{e} epochs: {result.validation_loss[0, int(result.chosen[0])]:.4f} at rate "
                         f"{result.chosen_rate('Proud10'):g} ({result.seconds['sweep']:.1f} s fine-tuning)")
        print(f"\nvalidation loss of the chosen rate, Proud10 (no render loop): {cells[0]}; {cells[1]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=Path, help="time this run folder's model (default: a random demo-size PFNN)")
    parser.add_argument("--model", choices=("pfnn", "lpn-film"), default="pfnn",
                        help="the 2018 PFNN or the 2022 LPN-FiLM (the run's RUN/lpn, or a random one)")
    parser.add_argument("--hidden", type=int, default=512, help="--model lpn-film without --run: hidden units")
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--characters", type=int, nargs="+", default=[1, 8, 32, 64])
    parser.add_argument("--screenshot", type=Path, help="write a screenshot of the page on --run instead")
    parser.add_argument("--learn", action="store_true", help="time learning a style live on --run instead "
                        "(default runs/demo)")
    parser.add_argument("--learn-epochs", type=int, default=LEARN_EPOCHS,
                        help="with --learn: epochs (default jaxstyle play's)")
    parser.add_argument("--learn-once", action="store_true", help=argparse.SUPPRESS)  # one process of --learn
    args = parser.parse_args()
    if args.learn or args.learn_once:
        (learn_once if args.learn_once else learn_benchmark)(args.run or Path("runs/demo"), args.learn_epochs)
        return
    if args.screenshot:
        screenshot(args.run or Path("runs/demo"), args.screenshot)
        return
    from jaxstyle.play.guard import Serving
    from jaxstyle.play.server import PlayServer

    with tempfile.TemporaryDirectory() as tmp:
        if args.model == "lpn-film":
            model = models.load_any(args.run, "lpn-film") if args.run else random_lpn_model(Path(tmp), args.hidden)
            what = (f"{args.run or 'random'} {model.title} (hidden {model.loaded.model.config.hidden_size}, "
                    f"{model.loaded.model.config.num_experts} experts)")
        elif args.run:
            model = models.load_model(args.run)
            what = f"{args.run} (hidden {model.base.model.hidden_size}, rank {model.base.model.rank})"
        else:
            model = demo_size_model(Path(tmp))
            what = "random PFNN of the demo's size (hidden 256, rank 16)"
        server = PlayServer(tmp, Serving(port=free_port()))
        server.start(model=model, loop=False)
        try:
            print(f"jaxstyle play, server side per frame; {platform.machine()}, {os.cpu_count()} cores, "
                  f"jax {jax.__version__} on {jax.devices()[0].platform}; {what}; {args.frames} frames")
            print("| characters | step ms, feet locked (median / p95) | step ms, unlocked (median / p95) | "
                  "locked / unlocked (median) | step + scene update ms (median / p95) | target |")
            print("|---|---|---|---|---|---|")
            for c in args.characters:
                t = time_frames(server, c, args.frames)
                target = 4.0 if c <= 8 else 16.0
                total = np.percentile(t["total"], 95)
                ratio = np.median(t["step"]) / np.median(t["step_unlocked"])
                print(f"| {c} | {np.median(t['step']):.2f} / {np.percentile(t['step'], 95):.2f} | "
                      f"{np.median(t['step_unlocked']):.2f} / {np.percentile(t['step_unlocked'], 95):.2f} | "
                      f"{ratio:.2f}x (<= 1.2x: {'met' if ratio <= 1.2 else 'NOT met'}) | "
                      f"{np.median(t['total']):.2f} / {total:.2f} | p95 <= {target:g} ms: "
                      f"{'met' if total <= target else 'NOT met'} |", flush=True)
        finally:
            server.stop()


if __name__ == "__main__":
    main()
