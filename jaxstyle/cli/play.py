"""``jaxstyle play``: steer a styled character live in the browser (:mod:`jaxstyle.play`)."""

from __future__ import annotations

import time
from pathlib import Path

from jaxstyle.cli.common import DEMO_RUN, SWEEP_RATES, CLIError, Run, add_common, check_positive

NAME = "play"
HELP = "steer a styled character live in the browser: switch, blend and learn styles, record"
DOC = """\
Serve a web page (http://HOST:PORT) showing a character driven live by the run's PFNN (Mason et al.
2018), one controller step per frame at 60 frames/s:

- steer: click the ground (Shift+click adds waypoints), the Walk buttons, or the keys W A S D /
  arrows relative to the camera (Shift runs, Space stops); the camera follows;
- styles: every base and few-shot style of the run in a dropdown, switched on the next frame;
  a blend of up to three styles with weight sliders;
- learn a style: upload (or give the path of) a BVH clip of the base skeleton; the few-shot
  sweep runs in the background (progress in the page) and the new style joins the dropdown
  with its chosen dropout rate (kept in RUN/play/styles for later sessions);
- record: save the last seconds as BVH (feet pinned) and GIF in RUN/play/recordings.

Without --run it plays runs/demo, running `jaxstyle demo` first when that holds no model.
Stop with Ctrl-C.
"""


def add_arguments(p) -> None:
    add_common(p, DEMO_RUN)
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (0.0.0.0: every network interface)")
    p.add_argument("--port", type=int, default=8080, help="port of the page")
    p.add_argument("--learn-epochs", type=int, default=40, help="fine-tuning epochs of a style learned live "
                                                                 "(the demo's sweep uses 40)")
    p.add_argument("--rates", type=float, nargs="+", default=SWEEP_RATES, help="dropout rates to sweep when learning")
    p.add_argument("--record-seconds", type=float, default=10.0, help="seconds the Record button saves by default")


def _run_demo(run: Run, args) -> None:
    """``jaxstyle demo`` into the run folder, with its default settings."""
    from jaxstyle.cli import demo
    from jaxstyle.cli.common import resolve_defaults
    from jaxstyle.cli.main import build_parser

    parser, _ = build_parser()
    demo_args = parser.parse_args(["demo", "--run", str(run.dir)] + (["--quiet"] if args.quiet else []))
    resolve_defaults(demo_args)
    demo.run(demo_args, run)


def run(args, run: Run) -> None:
    from jaxstyle.play.server import PlayServer

    check_positive(args, "learn_epochs", "record_seconds")
    if not 0 < args.port < 65536:
        raise CLIError(f"--port must be in 1 .. 65535, got {args.port}")
    if any(not 0 <= r < 1 for r in args.rates):
        raise CLIError(f"--rates must be in [0, 1), got {' '.join(map(str, args.rates))}")
    has_model = (Path(args.run) / "base" / "base.json").is_file()
    if not has_model and Path(args.run) == DEMO_RUN:
        run.say(f"no model in {args.run} yet: running `jaxstyle demo` first (about 5 minutes on 2 CPU cores)")
        _run_demo(run, args)
    elif not has_model:
        run.say(f"no model in {args.run}/base: the page says so and can load another run folder")
    server = PlayServer(args.run, host=args.host, port=args.port, learn_epochs=args.learn_epochs,
                        learn_rates=tuple(args.rates), record_seconds=args.record_seconds, log=run.say)
    try:
        server.start()  # says where the page is, then loads the run
        while True:
            time.sleep(1.0)
    except OSError as e:
        raise CLIError(f"--port {args.port}: cannot serve there ({e.strerror or e})") from None
    except KeyboardInterrupt:
        run.say("stopped")
    finally:
        server.stop()
