"""The motion-quality benchmark: does generated locomotion follow the path, stop, and keep its
feet planted as well as the capture it learnt from?

    python experiments/quality.py [--small] [--run runs/quality] [--no-contacts] [--lpn runs/mason2022]
        [--foot-smooth S] [--body-smooth S]

Protocol (fixed; ``--small`` shrinks only the sizes and says so in every output):

1. Data: the shared 100STYLE sample ($JAXSTYLE_MOCAP/100style). Base styles: the paper's base
   styles the sample has (Angry, Chicken, Drunk, InTheDark, Neutral), gaits BR, BW, FR, FW, SR,
   SW and ID (idle, so that the network has seen standing); few-shot styles: Elated and Rushed
   (FW), one 10 s clip each (2018 section 7).
2. Base: the 2018 PFNN at the paper's size (hidden 512, CP rank 30) with the paper's recipe
   (Adam 1e-4, batch 32, dropout 0.3, 20 epochs here over the whole sample), with the 2018
   layout's optional foot contact outputs (``--no-contacts``: the paper's layout, contacts then
   labelled on the output by height). ``--small``: hidden 256, rank 8, 10 epochs, clips cut
   to 20 s, gaits FW, FR, ID.
3. Few-shot: one compiled sweep over dropout rates 0.1, 0.3, 0.5, 0.7 (``--small``: 0.3, 0.5),
   100 epochs (``--small``: 40), rate chosen on validation loss and the closed-loop check
   (:func:`jaxstyle.mason2018.pipeline.run_sweep`).
4. Synthesis: every base style and few-shot set along straight, circle (radius 2 m), zigzag
   (45 degrees, 2 s period), stop_and_go (2 s walk, 1 s stand), speed_ramp (0.5x to 1.5x) and
   waypoints, 8 s each at the style's own median speed, with the path-following law
   (:func:`jaxstyle.control.loop.follow_gains`, 0.25 s), in one batched rollout.
5. Measures (:mod:`jaxstyle.output.quality`): skating of the network's joints, of the exported
   BVH and after foot locking (:mod:`jaxstyle.output.footlock`; the plain contact IK of the 2022
   paper beside it for comparison); steps per second, stance fraction, slide per contact, how far
   the lock moved a foot, how deep a foot goes below the floor; feet on floor; bone error (network, BVH); the largest
   network-to-BVH joint distance; path error mean / final / final %; heading error; time to
   stop; jitter; ankle jerk; each beside the style's capture; the targets checked (jaxstyle.output.report.targets).
6. Diagnosis (:func:`jaxstyle.output.diagnose.diagnose`) of the first base style and the first
   few-shot set.
7. The 2022 models: every model trained into ``--lpn`` (a model's folder, or a
   run folder of them such as ``runs/mason2022`` of ``experiments/mason2022_table2.py``; default
   ``runs/mason2022``, skipped with a line when it holds none) is reloaded
   (:func:`jaxstyle.mason2022.synthesis.load_model`) and its training styles (and the new styles
   its FiLM generator was fine-tuned on, when the folder has them) are driven by the 2022
   controller along the same paths, at the same speeds rule, with the same path-following law,
   and measured by the same function beside the same captures
   (:func:`jaxstyle.output.quality.run` with the model's
   :class:`jaxstyle.control.lpn_controller.StyleNetModel`, its phase floor the default and its feet's
   blend ``--foot-smooth``, default :data:`jaxstyle.train.defaults.FOOT_SMOOTH`, the other bones'
   ``--body-smooth``, default :data:`jaxstyle.train.defaults.BODY_SMOOTH`); a model the
   controller cannot drive is skipped with one line saying why. Rows carry a ``model`` column.

Writes to ``--run``: ``quality.csv``, ``quality.md`` (the table, the targets, the diagnosis),
``quality.png`` (bars: generated vs capture), ``contact_sheet.png``. Trained models are kept in
``--run/base`` and ``--run/sweep`` and reused on a re-run; the 2022 models are only read.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax

import jaxstyle as js
from jaxstyle.cli.args import add_joint_blend_args, resolve_defaults
from jaxstyle.data.folders import LOCOMOTION_GAITS, PAPER_BASE, PAPER_FEWSHOT, PipelineError, available_styles
from jaxstyle.mason2018 import base_model, pipeline, sweep_files
from jaxstyle.mason2022 import synthesis as synthesis2022
from jaxstyle.output import diagnose, preview, quality, report
from jaxstyle.train.defaults import BODY_SMOOTH, FOOT_SMOOTH


def model_dirs(folder: Path) -> list[Path]:
    """The 2022 model folders in ``folder``: itself when it holds a model (``config.json``), else
    its sub-folders that do."""
    if (folder / "config.json").is_file():
        return [folder]
    return sorted(d for d in folder.iterdir() if (d / "config.json").is_file()) if folder.is_dir() else []


def lpn_rows(folder: Path, cache: Path, seconds: float, foot_smooth: float | None = FOOT_SMOOTH,
             amplitude_floor: float = 0.0, body_smooth: float | None = BODY_SMOOTH) -> list[dict]:
    """Step 7 of the protocol: the quality rows of every 2022 model in ``folder``, its feet's runtime
    blend ``foot_smooth`` (0.5: the paper's, :class:`jaxstyle.mason2022.synthesis.Loaded`) and
    ``amplitude_floor`` (0: the paper's) and the other bones' ``body_smooth`` (0.5: the paper's)."""
    dirs = model_dirs(folder)
    if not dirs:
        print(f"2022 models: none in {folder} (train them with experiments/mason2022_table2.py or "
              "`jaxstyle lpn`); skipped")
        return []
    rows = []
    for d in dirs:
        t0 = time.perf_counter()
        try:
            loaded = synthesis2022.load_model(d, cache=cache)._replace(foot_smooth=foot_smooth,
                                                                       amplitude_floor=amplitude_floor,
                                                                       body_smooth=body_smooth)
            model = loaded.model
            chosen = d / "chosen_rates.json"
            new = list(json.loads(chosen.read_text())) if chosen.is_file() and loaded.data.new is not None else []
            got, _ = synthesis2022.measure_quality(loaded, model.data.styles, new, seconds=seconds)
        except PipelineError as e:
            print(f"2022 model {d.name}: skipped ({e})")
            continue
        rows += got
        measured = sum(r["path"] == "capture" for r in got)  # one capture row per character
        print(f"2022 model {model.name} ({loaded.epoch_text()}, {d}): {measured} characters measured "
              f"({time.perf_counter() - t0:.0f} s)")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--small", action="store_true", help="small sizes for a quick validation (see the protocol)")
    parser.add_argument("--run", type=Path, default=None, help="run folder (default runs/quality[_small])")
    parser.add_argument("--no-contacts", action="store_true", help="the paper's output layout, without contacts")
    parser.add_argument("--seconds", type=float, default=quality.SECONDS, help="seconds per path")
    parser.add_argument("--lpn", type=Path, default=Path("runs/mason2022"),
                        help="a trained 2022 model's folder, or a run folder of them (default runs/mason2022)")
    parser.add_argument("--lpn-cache", type=Path, default=Path("runs/cache"),
                        help="the 2022 models' LPN row cache (default runs/cache, experiments/mason2022_styles.py's)")
    parser.add_argument("--no-lpn", action="store_true", help="measure the 2018 models only")
    add_joint_blend_args(parser)
    parser.add_argument("--amplitude-floor", type=float, default=0.0, metavar="A",
                        help="2022 models: each limb's local-phase amplitude kept at least A times its style's "
                             "captured median (default 0, the paper's runtime)")
    a = parser.parse_args()
    resolve_defaults(a)
    run = a.run or Path("runs/quality_small" if a.small else "runs/quality")
    run.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    root = js.mocap_dir() / "100style"
    have = set(available_styles(root))
    base_styles = tuple(s for s in PAPER_BASE if s in have)
    shot_styles = [s for s in PAPER_FEWSHOT if s in have and (root / s / f"{s}_FW.bvh").is_file()]
    if a.small:
        settings = base_model.BaseSettings(str(root), base_styles, ("FW", "FR", "ID"), hidden=256, rank=8, epochs=10,
                                         max_seconds=20.0, contacts=not a.no_contacts)
        rates, shot_epochs = (0.3, 0.5), 40
    else:
        settings = base_model.BaseSettings(str(root), base_styles, LOCOMOTION_GAITS + ("ID",), hidden=512, rank=30,
                                         epochs=20, contacts=not a.no_contacts)
        rates, shot_epochs = (0.1, 0.3, 0.5, 0.7), 100
    cache = run / "cache"
    base = base_model.train_base(settings, run / "base", cache=cache)
    t_base = time.perf_counter() - t0
    sweep_dir = run / "sweep"
    if (sweep_dir / "sweep.json").is_file():
        chosen, shots = pipeline.load_sweep(sweep_dir, base, cache=cache)
    else:
        specs = pipeline.fewshot_specs(root, shot_styles, seconds=10.0, gaits=("FW",))
        sweep = pipeline.run_sweep(base, specs, js.SweepConfig(rates=tuple(rates), epochs=shot_epochs), cache=cache)
        pipeline.write_sweep(sweep, sweep_dir)
        shots = sweep.shots
        chosen = json.loads((sweep_dir / "chosen_rates.json").read_text())
    t_sweep = time.perf_counter() - t0 - t_base
    subjects = [quality.Subject(f"{s} (base)", "base", jax.tree.map(lambda v, i=i: v[i], base.adapters),
                                base.dataset, s) for i, s in enumerate(base.dataset.styles)]
    for name in chosen:
        adapter = sweep_files.load_adapter(sweep_dir / "adapters" / name, base.model)
        subjects.append(quality.Subject(f"{name} (few-shot, rate {chosen[name]['rate']:g})", "few-shot", adapter,
                                        shots, name))
    t1 = time.perf_counter()
    rows, drawn = quality.run(base.character_model(), subjects, base.skeleton, seconds=a.seconds)
    t_measure = time.perf_counter() - t1
    t1 = time.perf_counter()
    rows += [] if a.no_lpn else lpn_rows(a.lpn, a.lpn_cache, a.seconds, a.foot_smooth, a.amplitude_floor,
                                                 a.body_smooth)
    t_lpn = time.perf_counter() - t1
    checks = report.targets(rows)
    diag = [diagnose.diagnose(base.params, base.normalisers, s, base.skeleton)
            for s in (subjects[0], *(s for s in subjects if s.kind == "few-shot"))][:2]
    upm = js.estimate_units_per_meter(base.skeleton)
    drawing = preview.Drawing(titles=[s.title for s in subjects[:4]],
                              paths=[drawn[(s.title, "circle")][1] for s in subjects[:4]], units_per_meter=upm)
    sheet = preview.contact_sheet(run / "contact_sheet.png", [drawn[(s.title, "circle")][0] for s in subjects[:4]],
                                  base.skeleton.parents, drawing, frames=6, fps=base.skeleton.fps)
    size = (f"{'SMALL preset: ' if a.small else ''}hidden {settings.hidden}, rank {settings.rank}, "
            f"{settings.epochs} epochs, contacts {'on' if settings.contacts else 'off'}")
    timing = (f"base {t_base:.0f} s, sweep {t_sweep:.0f} s, rollouts and measures {t_measure:.0f} s, "
              f"2022 models {t_lpn:.0f} s, all {time.perf_counter() - t0:.0f} s")
    lines = [f"# Motion quality ({size})", "", timing, "", *report.table(rows), "", "## Targets", "",
             *report.target_summary(checks), "", "## Foot locking against the plain contact IK (same rollouts)", "",
             *report.lock_comparison(rows), "", "## Diagnosis", ""]
    for d in diag:
        lines += [*diagnose.diagnosis_lines(d), ""]
    (run / "quality.md").write_text("\n".join(lines) + "\n")
    files = [report.write_csv(rows, run / "quality.csv"), run / "quality.md", report.plot(rows, run / "quality.png"),
             sheet]
    print("\n".join(lines))
    print("written: " + ", ".join(map(str, files)))


if __name__ == "__main__":
    main()
