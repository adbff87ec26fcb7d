"""Drive characters along user paths in a base style and two few-shot styles, then write a GIF
per path, a BVH (and .npz) per style and path, a contact sheet, and quality figures beside those
of real motion of each style (Mason et al. 2018 section 7.1's runtime; the 2022 paper's section
4.4 foot-contact IK with ``--foot-ik``).

    python experiments/synthesize.py [--styles Elated_FW,Rushed_FW] [--base-style Neutral]
        [--paths straight,circle,zigzag,stop_and_go,speed_ramp] [--seconds 8] [--speed M_PER_S]
        [--foot-ik] [--mp4] [--out runs/synthesis]

It builds on ``experiments/fewshot_sweep.py``: the base PFNN (trained into ``runs/fewshot/base``
if it is not there yet, about 6 min on 2 CPU cores) and the few-shot adapters it chose
(``runs/fewshot/sweep/adapters/<set>``; run that script first). Every (style, path) character is
generated in ONE batched, jitted ``lax.scan`` (``jaxstyle.controller.rollout_batch``); each
starts from a real pose of its own style chosen to match the requested speed. The base style is
the base network with that training style's adapter; a fourth character walks a 50/50 blend of
the two few-shot styles (``jaxstyle.pfnn.blend_adapters``, exact for CP adapters).

Written to ``--out``: ``<path>.gif`` (styles side by side), ``bvh/<style>_<path>.bvh`` and
``.npz``, ``contact_sheet.png`` (the first path), ``quality.csv`` and ``results.md``.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import sys
import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxstyle as js
from jaxstyle import controller, datasets, export, metrics, paths, preview, selection

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fewshot_sweep  # noqa: E402  (the base model and few-shot sets of the sweep experiment)


@dataclasses.dataclass(frozen=True)
class Config:
    styles: tuple[str, ...] = ("Elated_FW", "Rushed_FW")
    base_style: str = "Neutral"
    paths: tuple[str, ...] = ("straight", "circle", "zigzag", "stop_and_go", "speed_ramp")
    seconds: float = 8.0
    speed: float | None = None  # None: each style walks at its own median speed
    foot_ik: bool = False
    mp4: bool = False
    base: Path = Path("runs/fewshot/base")
    sweep: Path = Path("runs/fewshot/sweep")
    out: Path = Path("runs/synthesis")


def parse_args() -> Config:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    d = Config()
    parser.add_argument("--styles", default=",".join(d.styles), help="few-shot sets (adapters of the sweep)")
    parser.add_argument("--base-style", default=d.base_style, help="a base training style (its adapter)")
    parser.add_argument("--paths", default=",".join(d.paths), help=f"any of {', '.join(paths.PATHS)}")
    parser.add_argument("--seconds", type=float, default=d.seconds)
    parser.add_argument("--speed", type=float, default=d.speed,
                        help="walking speed of the paths, m/s (default: each style's own median speed)")
    parser.add_argument("--foot-ik", action="store_true", help="pin the feet in contact in the BVH files")
    parser.add_argument("--mp4", action="store_true", help="also write MP4s (needs ffmpeg)")
    parser.add_argument("--base", type=Path, default=d.base)
    parser.add_argument("--sweep", type=Path, default=d.sweep)
    parser.add_argument("--out", type=Path, default=d.out)
    a = parser.parse_args()
    config = Config(tuple(s.strip() for s in a.styles.split(",") if s.strip()), a.base_style,
                    tuple(p.strip() for p in a.paths.split(",") if p.strip()), a.seconds, a.speed, a.foot_ik, a.mp4,
                    a.base, a.sweep, a.out)
    unknown = [p for p in config.paths if p not in paths.PATHS]
    if unknown:
        parser.error(f"unknown paths {unknown}; known: {', '.join(paths.PATHS)}")
    if config.base_style not in fewshot_sweep.BASE_STYLES:
        parser.error(f"--base-style must be a base training style: {', '.join(fewshot_sweep.BASE_STYLES)}")
    missing = [s for s in config.styles if not (config.sweep / "adapters" / s).is_dir()]
    if missing:
        parser.error(f"no few-shot adapter for {missing} in {config.sweep / 'adapters'}; "
                     "run python experiments/fewshot_sweep.py first")
    return config


def walk_rows(dataset: datasets.Dataset, style: str, gait: str = "FW") -> np.ndarray:
    """Training rows of ``style``, only those of its forward walks when it has some."""
    rows = dataset.rows_of_style(style, "train")
    walks = np.array([dataset.specs[c].gait == gait for c in dataset.clip[rows]])
    return rows[walks] if walks.any() else rows


def own_speed(dataset: datasets.Dataset, rows: np.ndarray, units_per_meter: float, fps: float = 60.0) -> float:
    """The median ground speed (m/s) of the character over ``rows`` (its per-frame root motion)."""
    step = dataset.outputs[rows, :2]  # root velocity, units per frame, in the character frame
    return float(np.median(np.linalg.norm(step, axis=1)) * fps / units_per_meter)


def main() -> None:
    config = parse_args()
    mocap = js.mocap_dir()
    fs_config = fewshot_sweep.Config(base=config.base)
    base = fewshot_sweep.base_model(mocap, fs_config)
    x_norm, y_norm = base.normalisers
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        shots = datasets.build_pfnn_dataset(fewshot_sweep.fewshot_specs(mocap / "100style", fs_config.seconds),
                                            cache_dir=fs_config.cache)
    skeleton = datasets.load_clip(base.dataset.specs[0], fps=60.0)
    upm = js.estimate_units_per_meter(skeleton)
    chosen = json.loads((config.sweep / "chosen_rates.json").read_text())

    # one character per (style, path): its adapter, a real start pose of its style, its path
    names = [f"{config.base_style} (base)"] + [f"{s} (few-shot, rate {chosen[s]['rate']:g})" for s in config.styles]
    style_adapters = [jax.tree.map(lambda v: v[base.dataset.styles.index(config.base_style)], base.adapters)]
    style_adapters += [selection.load_adapter(config.sweep / "adapters" / s, base.model) for s in config.styles]
    sources = [(base.dataset, config.base_style)] + [(shots, s) for s in config.styles]
    if len(config.styles) >= 2:  # style interpolation: an exact blend of the first two few-shot adapters
        stacked = jax.tree.map(lambda *v: jnp.stack(v), *style_adapters[1:3])
        style_adapters.append(js.pfnn.blend_adapters(stacked, [0.5, 0.5]))
        names.append(f"50/50 {config.styles[0]} + {config.styles[1]}")
        sources.append(sources[1])
    starts, speeds, real_specs = [], [], []
    for dataset, style in sources:
        rows = walk_rows(dataset, style)
        speed = own_speed(dataset, rows, upm) if config.speed is None else config.speed
        row = controller.start_row(dataset.inputs, speed, units_per_meter=upm, rows=rows)
        starts.append(controller.initial_state(dataset.inputs[row], float(dataset.phases[row, 0]),
                                               skeleton.num_joints))
        speeds.append(speed)
        real_specs.append(dataset.specs[int(dataset.clip[rows[0]])])
    if js.pfnn.adapter_kind(style_adapters[0]) == "cp":  # a CP blend's rank is the sum of its styles'
        rank = max(a["A"].shape[0] for a in style_adapters)
        style_adapters = [js.pfnn.pad_rank(a, rank) for a in style_adapters]
    pairs = [(s, p) for s in range(len(names)) for p in config.paths]
    signals = [paths.named(p, config.seconds, speeds[s], units_per_meter=upm) for s, p in pairs]
    print("speeds (m/s): " + ", ".join(f"{n} {v:.2f}" for n, v in zip(names, speeds, strict=True)))
    stack = lambda items: jax.tree.map(lambda *v: jnp.stack(v), *items)  # noqa: E731
    args = (base.params, stack([style_adapters[s] for s, _ in pairs]), x_norm, y_norm,
            stack([starts[s] for s, _ in pairs]), stack([controller.signal_controls(sig) for sig in signals]))
    t0 = time.perf_counter()
    out = jax.block_until_ready(controller.rollout_batch(*args))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = jax.block_until_ready(controller.rollout_batch(*args))
    seconds = time.perf_counter() - t0
    frames = len(pairs) * out.positions.shape[1]
    print(f"\n{len(pairs)} characters x {out.positions.shape[1]} frames in one batched rollout: {seconds:.2f} s "
          f"({frames / seconds:,.0f} frames/s; first call with compilation {first:.1f} s)")

    config.out.mkdir(parents=True, exist_ok=True)
    fps = skeleton.fps
    rows, written, ik_rows = [], [], []
    for p in config.paths:
        idx = [k for k, (_, q) in enumerate(pairs) if q == p]
        chars = [np.asarray(out.positions[k]) for k in idx]
        path_xz = [signals[k].positions for k in idx]
        gif = preview.render_gif(config.out / f"{p}.gif", chars, skeleton.parents, fps, titles=names, paths=path_xz,
                                 units_per_meter=upm, every=2)
        written.append(gif)
        if config.mp4:
            written.append(preview.render_mp4(config.out / f"{p}.mp4", chars, skeleton.parents, fps, titles=names,
                                              paths=path_xz, units_per_meter=upm, every=2))
        if p == config.paths[0]:
            written.append(preview.contact_sheet(config.out / "contact_sheet.png", chars, skeleton.parents, frames=6,
                                                 titles=names, paths=path_xz, units_per_meter=upm, fps=fps))
    for k, (s, p) in enumerate(pairs):
        one = jax.tree.map(lambda v, k=k: v[k], out)
        label = ([config.base_style, *config.styles, "blend"][s]) + f"_{p}"
        motion = export.rollout_motion(one, skeleton)
        if config.foot_ik:
            fixed = export.fix_feet(motion, one)
            ik_rows.append((names[s], p, *(metrics.foot_skating(js.global_positions(m), skeleton, fps,
                                                                 units_per_meter=upm) for m in (motion, fixed))))
            motion = fixed
        written += export.save_rollout(config.out / "bvh" / label, one, skeleton, motion=motion).values()
        q = metrics.motion_quality(np.asarray(one.positions), skeleton, fps, units_per_meter=upm,
                                   path_Tx2=signals[k].positions)
        rows.append({"style": names[s], "path": p, **q.as_row()})
    for spec, name in list(zip(real_specs, names, strict=True))[:1 + len(config.styles)]:
        q = metrics.reference_quality(datasets.load_clip(spec, fps=60.0))
        rows.append({"style": name, "path": f"real ({Path(spec.path).name})", **q.as_row()})
    with open(config.out / "quality.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = ["| style | path | skating m/s | feet on floor | bone error mean / max | path error mean / final m "
             "| jitter m/s^3 |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['style']} | {r['path']} | {r['foot_skating_m_s']:.2f} | {r['contact_fraction']:.2f} "
                     f"| {100 * r['bone_error_mean']:.1f}% / {100 * r['bone_error_max']:.0f}% "
                     f"| {r['path_error_mean_m']:.2f} / {r['path_error_final_m']:.2f} | {r['jitter_m_s3']:.0f} |")
    if ik_rows:
        lines += ["", "foot-contact IK on the exported BVH (skating of the decoded motion, m/s):", "",
                  "| style | path | before IK | after IK |", "|---|---|---|---|"]
        lines += [f"| {n} | {p} | {a:.2f} | {b:.2f} |" for n, p, a, b in ik_rows]
    (config.out / "results.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"\nwritten to {config.out}: {len(written)} files, e.g. " + ", ".join(str(w) for w in written[:4]))


if __name__ == "__main__":
    main()
