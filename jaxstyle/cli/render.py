"""``jaxstyle render``: BVH files side by side in a GIF or MP4 (:mod:`jaxstyle.output.preview`)."""

from __future__ import annotations

from pathlib import Path

from jaxstyle.cli.args import add_common, check_positive, finite
from jaxstyle.cli.common import CLIError, check_input_file, ensure_folder, progress

NAME = "render"
HELP = "render BVH files side by side to a GIF (or MP4)"
DOC = "Render BVH files (any skeleton, Y-up) side by side into an animated GIF, or MP4 with ffmpeg."


def add_arguments(p) -> None:
    p.add_argument("files", type=Path, nargs="+", help="BVH files")
    p.add_argument("--out", type=Path, default=Path("preview.gif"), help="output .gif or .mp4")
    p.add_argument("--start", type=finite, default=0.0, help="first second to show")
    p.add_argument("--seconds", type=finite, default=10.0, help="seconds to show")
    p.add_argument("--every", type=int, default=2, help="draw every n-th frame")
    add_common(p, None)


def run(args, run: None) -> None:
    from jaxstyle.labels.contacts import estimate_units_per_meter
    from jaxstyle.motion.bvh import read_bvh
    from jaxstyle.motion.kinematics import global_positions
    from jaxstyle.output import preview

    check_positive(args, "seconds", "every")
    if args.start < 0:
        raise CLIError(f"--start must be >= 0, got {args.start:g}")
    if args.out.suffix.lower() not in (".gif", ".mp4"):
        raise CLIError(f"--out {args.out}: the name must end in .gif or .mp4")
    if args.out.is_dir():
        raise CLIError(f"--out {args.out}: is a folder; give a file name ending in .gif or .mp4")
    ensure_folder(args.out.parent, "--out", args.out)  # before the (slow) reading and drawing
    if args.out.suffix.lower() == ".mp4":
        from matplotlib import animation

        if not animation.writers.is_available("ffmpeg"):
            raise CLIError(f"--out {args.out}: writing MP4 needs ffmpeg, which was not found; name a .gif instead")
    chars, parents, fps, upm = [], None, None, None
    for f in args.files:
        check_input_file(f, what="BVH file")
        m = read_bvh(f)
        a = int(round(args.start * m.fps))
        if a >= m.num_frames:
            raise CLIError(f"{f}: --start {args.start:g} s is past its end ({m.duration:.1f} s)")
        m = m.frames(a, a + int(round(args.seconds * m.fps)))
        if parents is None:
            parents, fps, upm = m.parents, m.fps, estimate_units_per_meter(m)
        elif len(m.parents) != len(parents) or m.fps != fps:
            raise CLIError(f"{f}: a different skeleton or frame rate from {args.files[0]}; render them separately")
        chars.append(global_positions(m))
    write = preview.render_gif if args.out.suffix.lower() == ".gif" else preview.render_mp4
    drawing = preview.Drawing(titles=[f.stem for f in args.files], units_per_meter=upm)
    out = write(args.out, chars, parents, fps, drawing, every=args.every, progress=progress(args))
    print(f"wrote {out}")
