"""Learning a new style live: the few-shot sweep of Mason et al. 2018 section 7 on ONE user clip
(:func:`jaxstyle.mason2018.pipeline.run_sweep`, as ``jaxstyle sweep --clip FILE``), run in a
background thread while the characters keep walking.

The sweep is the library's: a fresh CP adapter per dropout rate fine-tuned on the frozen base in
one compiled program, validated and checked closed-loop, a rate chosen. Its report goes to
``RUN/play/styles/<name>/`` (the layout of ``RUN/sweep``), so the style is there again in the next
session. JAX releases the GIL while it computes, so the render loop keeps its frame rate (on 2
CPU cores the two share the cores: frames take longer while a style is learned).

Progress: the sweep reports through tqdm bars (``progress=True``); :class:`Learner` reads the
live bars' counters (``tqdm``'s registry of open bars) to show a progress bar in the page, so no
progress plumbing is added to the pipeline.
"""

from __future__ import annotations

import dataclasses
import re
import threading
import time
from pathlib import Path
from typing import Callable, Sequence

from jaxstyle.data import folders
from jaxstyle.errors import JaxstyleError
from jaxstyle.mason2018 import fewshot, pipeline
from jaxstyle.motion.bvh import read_bvh_names
from jaxstyle.output.check import FAILED_MARK
from jaxstyle.play.models import PlayError, PlayModel, Style, learned_root
from jaxstyle.train.defaults import DEFAULT_RATES, LEARN_EPOCHS

STAGES = ("reading the clip", "fine-tuning", "closed-loop checks", "done")


def style_name(path: str | Path, taken: Sequence[str] = ()) -> str:
    """A style name from a file name: its stem with anything but letters, digits, ``_`` and ``-``
    replaced by ``_``, made unique against ``taken`` (``Name_2``, ...)."""
    stem = re.sub(r"[^A-Za-z0-9_-]+", "_", Path(path).stem).strip("_") or "style"
    name, k = stem, 2
    while name in taken:
        name, k = f"{stem}_{k}", k + 1
    return name


def check_clip(path: str | Path, model: PlayModel, read_names: Callable[[Path], tuple[str, ...]] = read_bvh_names
               ) -> None:
    """Refuse, with one line naming the file, a clip that is not BVH or not of the base's skeleton
    (joint names and count), before any training starts. ``read_names``: how the file is read
    (default here; the live server passes :meth:`ClipReader.names`, another process)."""
    path = Path(path)
    if not path.is_file():
        raise PlayError(f"{path}: no such file")
    try:
        names = read_names(path)
    except UnicodeDecodeError:
        raise PlayError(f"{path}: not a BVH file (not text)") from None
    skeleton = model.base.skeleton
    if tuple(names) != tuple(skeleton.names):
        raise PlayError(f"{path}: a BVH of another skeleton ({len(names)} joints, root {names[0]!r}); "
                        f"the base was trained on {skeleton.num_joints} joints, root {skeleton.names[0]!r}")


class ClipReader:
    """Reads clips in a separate process (spawned once, kept): parsing a large file there holds
    neither the live server's session lock nor its interpreter lock, so the render loop keeps its
    frame rate; a read that takes longer than ``timeout`` seconds is stopped (the process is
    ended and a fresh one spawned for the next). The process imports only the BVH reader
    (:func:`jaxstyle.motion.bvh.read_bvh_names`); :meth:`warm` starts it ahead of the first clip."""

    def __init__(self, timeout: float = 60.0):
        self.timeout = float(timeout)
        self._pool = None
        self._lock = threading.Lock()

    def _started(self):
        import multiprocessing

        if self._pool is None:
            self._pool = multiprocessing.get_context("spawn").Pool(1)
        return self._pool

    def warm(self) -> None:
        """Start the reader process and import the reader there now (about 0.2 s on 2 CPU cores),
        so that the first clip is read without that wait; errors are left to the first read."""
        with self._lock:
            try:
                self._started().apply_async(read_bvh_names, ("",)).get(self.timeout)
            except (OSError, ValueError):
                pass  # the empty path is refused once the reader is imported: that is all this waits for
            except Exception:  # noqa: BLE001 - a warm-up never fails the server; the first read will say why
                self._end()

    def names(self, path: Path) -> tuple[str, ...]:
        import multiprocessing

        with self._lock:
            pending = self._started().apply_async(read_bvh_names, (path,))
            try:
                return pending.get(self.timeout)
            except multiprocessing.TimeoutError:
                self._end()
                raise PlayError(f"{path}: reading it took over {self.timeout:g} s; stopped") from None

    def _end(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool = None

    def close(self) -> None:
        with self._lock:
            self._end()


class Learner:
    """Learns styles in a background thread, one at a time, and reports on them.

    ``status()`` gives ``(state, fraction, message)``: ``state`` is ``idle``, ``running``, ``done``
    or ``failed``; ``message`` is one line (the stage, or the result, or what was wrong with the
    clip). ``on_done(style)`` is called from the thread with the new :class:`Style` (the state is
    ``done`` by then), ``on_fail(message)`` with the one-line message of a failure."""

    def __init__(self, model: PlayModel, on_done: Callable[[Style], None], *,
                 on_fail: Callable[[str], None] = lambda _: None, epochs: int = LEARN_EPOCHS,
                 rates: Sequence[float] = DEFAULT_RATES, clip_range: tuple[float, float] | None = None,
                 mirror: bool = True, allow_failed: bool = False):
        self.model, self.on_done, self.on_fail = model, on_done, on_fail
        self.allow_failed = bool(allow_failed)
        self.epochs, self.rates, self.clip_range, self.mirror = int(epochs), tuple(rates), clip_range, mirror
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.state, self.message, self.stage = "idle", "", ""
        self.seconds: float | None = None
        self._bars_before: set = set()
        self._fraction, self._desc = 0.0, ""

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self, path: str | Path, name: str | None = None) -> str:
        """Start learning the clip at ``path`` as style ``name`` (default from the file name);
        returns the name. Refuses (:class:`PlayError`) while another style is learned."""
        if self.busy:
            raise PlayError("a style is being learned already; wait until it is done")
        name = name or style_name(path, list(self.model.styles))
        with self._lock:
            self.state, self.stage, self.message, self.seconds = "running", STAGES[0], f"{name}: {STAGES[0]}", None
        self._bars_before = set(_open_bars())
        self._fraction, self._desc = 0.0, ""
        self._thread = threading.Thread(target=self._run, args=(Path(path), name), name=f"learn-{name}", daemon=True)
        self._thread.start()
        return name

    def wait(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    def _run(self, path: Path, name: str) -> None:
        t0 = time.perf_counter()
        try:
            check_clip(path, self.model)
            specs = folders.user_clip_specs([path], self.mirror, self.clip_range)
            specs = [dataclasses.replace(s, style=name) for s in specs]
            self._set_stage(STAGES[1])
            config = fewshot.SweepConfig(rates=tuple(self.rates), epochs=self.epochs)
            sweep = pipeline.run_sweep(self.model.base, specs, config, progress=True)
            pipeline.write_sweep(sweep, learned_root(self.model.run_dir) / name)
            result = sweep.result
            passed = bool(result.chosen_passed[result.styles.index(name)])
            if not passed and not self.allow_failed:
                self._fail(f"{name} failed the closed-loop check at every rate ({'; '.join(result.failed(name))}): "
                           "not added (jaxstyle play --allow-failed adds it anyway)")
                return
            kind = "learned" if passed else "learned" + FAILED_MARK
            style = Style(name, kind, float(result.chosen_rate(name)), result.adapter(name))
            with self._lock:
                self.seconds = time.perf_counter() - t0
                self.state, self.stage = "done", STAGES[3]
                self.message = (f"learned {name} in {self.seconds:.0f} s: rate {style.rate:g} chosen"
                                + ("" if passed else " (it failed the closed-loop check at every rate: used because "
                                                     "of --allow-failed)"))
            self.on_done(style)
        except (JaxstyleError, ValueError, KeyError, OSError) as e:
            self._fail(f"{name}: {_one_line(e)}")
        except Exception as e:  # noqa: BLE001 - the server must survive any failure of a learning run
            self._fail(f"{name}: internal error: {type(e).__name__}: {_one_line(e)}")

    def _fail(self, message: str) -> None:
        with self._lock:
            self.state, self.message = "failed", message
        self.on_fail(message)

    def _set_stage(self, stage: str) -> None:
        with self._lock:
            self.stage = stage

    def status(self) -> tuple[str, float, str]:
        """``(state, fraction done in [0, 1], one-line message)``."""
        with self._lock:
            state, stage, message = self.state, self.stage, self.message
        if state != "running":
            return state, 1.0 if state == "done" else 0.0, message
        fraction, desc = self._fraction, self._desc or stage
        bars = [b for b in _open_bars() if b not in self._bars_before]
        for bar in bars:
            total = getattr(bar, "total", None) or 0
            if total:
                if str(getattr(bar, "desc", "")).startswith("closed-loop"):
                    fraction, desc = 0.9 + 0.1 * bar.n / total, STAGES[2]
                else:
                    fraction, desc = 0.05 + 0.85 * bar.n / total, STAGES[1]
        # between bars (compiling, validating) the last stage and fraction hold
        self._fraction, self._desc = max(fraction, self._fraction), desc
        name = message.split(":")[0]
        return state, min(self._fraction, 0.99), f"{name}: {desc}"


def _open_bars() -> list:
    from tqdm.std import tqdm

    return list(getattr(tqdm, "_instances", ()))


def _one_line(e: BaseException) -> str:
    message = e.args[0] if isinstance(e, KeyError) and e.args else e
    return " ".join(line.strip() for line in str(message).splitlines() if line.strip()) or type(e).__name__
