"""``jaxstyle play``: steer a styled character live in the browser (:mod:`jaxstyle.play`)."""

from __future__ import annotations

import re
import time
from pathlib import Path

from jaxstyle.cli.args import (
    LEARN_EPOCHS,
    SWEEP_RATES,
    add_common,
    add_lpn_runtime_args,
    check_positive,
    check_rates,
    finite,
)
from jaxstyle.cli.common import DEMO_RUN, CLIError, Run

PLAY_MODELS = ("pfnn", "lpn-film", "lpn-onehot", "lpn-resad", "mann-film", "pfnn-film", "pfnn-onehot", "pfnn-resad")
"""``--model``: the 2018 PFNN and the 2022 models of Table 2 (``jaxstyle.mason2022.synthesis.MODELS``)."""

NAME = "play"
HELP = "steer a styled character live in the browser: switch, blend and learn styles, record"
DOC = """\
Serve a web page (http://HOST:PORT) showing a character driven live by the run's PFNN (Mason et al.
2018) or its trained 2022 model (Mason et al. 2022, LPN-FiLM: RUN/lpn, written by `jaxstyle lpn` or
`jaxstyle demo --model lpn-film`), one controller step per frame at 60 frames/s:

- model: when the run holds both, the page's Model choice switches between them (--model picks
  the one to start with; default the 2018 PFNN when there is one);
- steer: click the ground (Shift+click adds waypoints), the Walk buttons, or the keys W A S D /
  arrows relative to the camera (Shift runs, Space stops); the camera follows;
- styles: every style of the model in a dropdown, switched on the next frame (2018: base styles,
  few-shot adapters, styles learned live; 2022: training styles as their FiLM vectors and the
  styles the FiLM sweep fine-tuned); a blend of up to three styles with weight sliders (the CP
  adapters' exact blend; the 2022 model's weighted FiLM vector);
- learn a style (2018 model; disabled, saying so, while a 2022 model plays): upload (or give the
  path of) a BVH clip of the base skeleton; the few-shot sweep runs in the background (progress
  in the page) and the new style joins the dropdown with its chosen dropout rate (kept in
  RUN/play/styles for later sessions);
- record: save the last seconds as BVH (feet pinned) and GIF in RUN/play/recordings.

Trust: only the page itself (its own origin; with --token, its URL) may connect; files the page
names must lie in the run folder or a --clip-dir folder, run folders beside the --run folder; uploads
above --max-upload-mb are refused (docs/play.md, "Who may connect").

Without --run it plays runs/demo, running `jaxstyle demo` first when that holds no model
(`jaxstyle demo --model lpn-film` with --model lpn-film).
Stop with Ctrl-C.
"""


def add_arguments(p) -> None:
    add_common(p, DEMO_RUN)
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (0.0.0.0: every network interface; give --token with it)")
    p.add_argument("--token", default=None,
                   help="a secret the page must present: only the URL printed at start (which carries it) "
                        "connects; for --host 0.0.0.0")
    p.add_argument("--clip-dir", type=Path, action="append", default=[],
                   help="a folder whose BVH files the page may name in 'BVH path' (repeatable; the run folder "
                        "always may be)")
    p.add_argument("--max-upload-mb", type=finite, default=8.0, help="largest BVH upload the page accepts")
    p.add_argument("--port", type=int, default=8080, help="port of the page")
    p.add_argument("--model", choices=PLAY_MODELS, default=None,
                   help="the model to start with: pfnn (the 2018 base, RUN/base) or the run's trained 2022 model "
                        "(lpn-film ...: RUN/lpn); default pfnn when the run has one; the page switches between them")
    p.add_argument("--learn-epochs", type=int, default=LEARN_EPOCHS,
                   help="fine-tuning epochs of a style learned live (default %(default)s, the sweep's)")
    p.add_argument("--rates", type=finite, nargs="+", default=SWEEP_RATES, help="dropout rates to sweep when learning")
    p.add_argument("--record-seconds", type=finite, default=10.0, help="seconds the Record button saves by default")
    p.add_argument("--allow-failed", action="store_true",
                   help="offer few-shot and learned styles whose closed-loop check failed at every rate (marked "
                        "[FAILED CHECK]); by default they are left out, with one line saying so")
    add_lpn_runtime_args(p)


def _run_demo(run: Run, args) -> None:
    """``jaxstyle demo`` into the run folder, with its default settings (its own arguments, parsed
    by a parser of ``jaxstyle demo`` alone)."""
    from jaxstyle.cli import demo
    from jaxstyle.cli.args import Parser, resolve_defaults

    parser = Parser(prog="jaxstyle demo")
    demo.add_arguments(parser)
    model = ["--model", args.model] if args.model and args.model != "pfnn" else []
    demo_args = parser.parse_args(["--run", str(run.dir)] + model + (["--quiet"] if args.quiet else []))
    resolve_defaults(demo_args)
    demo.run(demo_args, run)


def run(args, run: Run) -> None:
    from jaxstyle.play.guard import Serving
    from jaxstyle.play.learn_panel import Learning
    from jaxstyle.play.models import PlayError, available_models
    from jaxstyle.play.server import PlayServer

    check_positive(args, "learn_epochs", "record_seconds", "max_upload_mb")
    if args.token is not None and not re.fullmatch(r"[A-Za-z0-9_-]{8,128}", args.token):
        raise CLIError("--token must be 8-128 letters, digits, '_' or '-' (it goes into the page's URL)")
    for folder in args.clip_dir:
        if not folder.is_dir():
            raise CLIError(f"--clip-dir {folder}: no such folder")
    if not 0 < args.port < 65536:
        raise CLIError(f"--port must be in 1 .. 65535, got {args.port}")
    check_rates(args.rates)
    have = available_models(args.run)
    wanted = args.model or "pfnn"
    if not have and Path(args.run) == DEMO_RUN:
        from jaxstyle.cli.demo import DEMO_MODELS

        if wanted not in DEMO_MODELS:
            raise CLIError(f"no model in {args.run} yet, and `jaxstyle demo` trains {', '.join(DEMO_MODELS)}, not "
                           f"{wanted}: train one with `jaxstyle lpn --run RUN` and give --run RUN")
        demo = "jaxstyle demo" + ("" if wanted == "pfnn" else f" --model {wanted}")
        run.say(f"no model in {args.run} yet: running `{demo}` first (about 5 minutes on 2 CPU cores)")
        _run_demo(run, args)
        have = available_models(args.run)
    if not have:
        run.say(f"no model in {args.run} (no base/ nor lpn/): the page says so and can load another run folder")
    elif args.model and args.model not in have:
        how = ("`jaxstyle demo`" if args.model == "pfnn" else
               f"`jaxstyle lpn` or `jaxstyle demo --model {args.model}` (into RUN/lpn)")
        raise CLIError(f"--model {args.model}: {args.run} has no trained {args.model} model (it has "
                       f"{', '.join(have)}); train one with {how}")
    server = PlayServer(args.run, Serving(args.host, args.port, args.token),
                        Learning(args.learn_epochs, tuple(args.rates), tuple(args.clip_dir),
                                 int(args.max_upload_mb * 1e6)),
                        record_seconds=args.record_seconds, model=args.model, log=run.say,
                        allow_failed=args.allow_failed,
                        lpn_runtime={"phase_floor": args.phase_floor, "foot_smooth": args.foot_smooth,
                                     "body_smooth": args.body_smooth})
    try:
        server.start()  # says where the page is, then loads the run
        while True:
            time.sleep(1.0)
    except OSError as e:
        raise CLIError(f"--port {args.port}: cannot serve there ({e.strerror or e})") from None
    except PlayError as e:
        raise CLIError(str(e)) from None
    except KeyboardInterrupt:
        run.say("stopped")
    finally:
        server.stop()
