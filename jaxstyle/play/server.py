"""The ``jaxstyle play`` web page: a viser scene (https://viser.studio) driven at 60 frames/s by a
:class:`jaxstyle.play.session.Session`; the scene it draws is :mod:`jaxstyle.play.scene`.

viser is a pip-installable 3-D web viewer that ships its own web client: the characters (bones as
cylinders, joints as spheres), a ground grid with shadows, the predicted future trajectory and
the waypoints are scene nodes updated from Python; the controls are viser GUI elements; clicks on
the ground arrive as scene click events (a ray, intersected here with the floor); keys arrive as
command-palette hotkeys (viser sends key presses, not key releases, so a key sets a walking
direction that holds until the next key, a click or Space).

Threads: viser serves the page and runs the GUI callbacks in its own threads; one render thread
steps the session and updates the scene every 1/60 s; reading and checking a clip the page names
or uploads runs in a worker thread (one at a time), learning a style in another
(:class:`jaxstyle.play.learn.Learner`), loading a run folder and saving a recording in short-lived
ones, so no request blocks the render loop: the lock that serialises access to the session is
never held while a file is read.

Trust (:mod:`jaxstyle.play.guard`, docs/play.md): only the page's own origin may connect (and,
with :class:`Serving`'s ``token``, only with it); files and run folders the page names must lie
under the allowed roots (the run folder, :class:`jaxstyle.play.learn_panel.Learning`'s
``data_dirs``; run folders under ``runs_root``); uploads are capped at its ``max_upload_bytes``,
written under a fresh name and removed when refused; messages about a file
never quote its contents.

Models: a run folder may hold the 2018 PFNN (``RUN/base``) and a trained 2022 model (``RUN/lpn``);
the page's "Model" choice switches between them (each loaded and compiled once per server, then
kept), the style dropdown and the blend sliders acting on the model that plays. Learning a style
live is the 2018 few-shot sweep: while a 2022 model plays, the learn controls are disabled and say
so (a style learned meanwhile joins the 2018 model's styles).

Bad input (a BVH of another skeleton, a file that is not BVH, a run folder without a model, a
failed recording) shows one line in the page (``message``) and in a notification; the server
keeps running.
"""

from __future__ import annotations

import collections
import contextlib
import datetime
import math
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np

from jaxstyle.errors import JaxstyleError
from jaxstyle.play import guard, learn
from jaxstyle.play.guard import Serving
from jaxstyle.play.learn_panel import Learning, LearnPanel
from jaxstyle.play.models import (
    PFNN,
    PLAY_DIR,
    AnyPlayModel,
    PlayError,
    available_models,
    load_any,
)
from jaxstyle.play.scene import SceneView
from jaxstyle.play.session import (
    Session,
    save_recording,
)
from jaxstyle.play.style_panel import NO_BLEND, STEER_BUTTONS, StylePanel

FPS = 60.0


NO_MODEL = "(none)"


def _one_line(e: BaseException) -> str:
    message = e.args[0] if isinstance(e, KeyError) and e.args else e
    return " ".join(line.strip() for line in str(message).splitlines() if line.strip()) or type(e).__name__



class PlayServer(SceneView, LearnPanel, StylePanel):
    """The live page on ``host:port`` for the run folder ``run_dir``.

    ``start()`` serves the page, loads the run (a failure shows in the page) and starts the render
    loop; ``stop()`` ends both. What the page shows is also here for tests and scripts:
    ``session`` (``None`` until a run is loaded), ``message`` (the last error or note),
    ``step_ms`` / ``frame_ms`` (the controller step and the whole frame, smoothed), ``frame_times``
    (``time.monotonic()`` of the last minute's frames) and ``learner``
    (the 2018 model's; ``None`` without one).

    Args:
      run_dir: the run folder to play.
      serving: host, port, token (:class:`Serving`; default: 127.0.0.1:8080, no token).
      learning: how a style is learned live (:class:`jaxstyle.play.learn_panel.Learning`).
      model: the model to start with (``pfnn`` or a 2022 key such as ``lpn-film``,
        :func:`jaxstyle.play.models.available_models`); default the run's 2018 model when it has one.
      record_seconds: the length of a recording.
      log: where notes go (the command line's run log).
      runs_root: the folder whose run folders the page may load (default: ``run_dir``'s parent).
      allow_failed: offer and keep styles that failed the closed-loop check.
      lpn_runtime: the 2022 models' runtime settings (``phase_floor``, ``foot_smooth``, ``body_smooth``;
        :func:`jaxstyle.play.models.load_lpn_model`; default the library's).
    """

    def __init__(self, run_dir: str | Path, serving: Serving | None = None, learning: Learning | None = None, *,
                 model: str | None = None, record_seconds: float = 10.0,
                 log: Callable[[str], None] = lambda _: None, runs_root: str | Path | None = None,
                 allow_failed: bool = False, lpn_runtime: dict | None = None):
        serving = serving or Serving()
        self.lpn_runtime = dict(lpn_runtime or {})
        self.run_dir = Path(run_dir)
        self.allow_failed = bool(allow_failed)  # offer and keep styles that failed the closed-loop check
        self.token = serving.token
        self.runs_root = Path(runs_root) if runs_root is not None else self.run_dir.resolve().parent
        self._init_learning(learning or Learning())
        self.model_key = model
        self._models: dict[tuple[str, str], AnyPlayModel] = {}  # loaded once per (run folder, model)
        self._model_keys: dict[str, str] = {}  # the Model choice's labels -> keys
        self._refreshing_models = False
        self.host, self.port, self.verbose, self.log = serving.host, int(serving.port), serving.verbose, log
        self.record_seconds = float(record_seconds)
        self.session: Session | None = None
        self.message = ""
        self.step_ms = self.frame_ms = float("nan")
        self.last_recording: list[Path] = []
        self.frame_times: collections.deque[float] = collections.deque(maxlen=3600)  # when recent frames were drawn
        self.lock = threading.RLock()
        self._running = threading.Event()
        self._thread: threading.Thread | None = None
        self._nodes: list = []  # the handles of all characters' bones, joints and future trajectories
        self._node_count = 0  # the characters they show
        self._target_node = None
        self._server = None
        self._cam_offset = np.array([2.2, 1.4, -3.6])

    # --- life cycle ---------------------------------------------------------------------------
    def start(self, load: bool = True, model: AnyPlayModel | None = None, loop: bool = True) -> "PlayServer":
        """Serve the page, load the run (or play ``model``) and, with ``loop``, start the render
        loop (without it nothing moves until the caller steps the session and updates the scene:
        ``benchmarks/play.py``)."""
        import viser

        guard.check_address(self.host)
        self._server = viser.ViserServer(host=self.host, port=self.port, verbose=self.verbose)
        self.port = self._server.get_port()
        self.admission = guard.Admission(self.host, self.port, self.token)
        try:
            guard.install(self._server, self.admission, self.log)
        except PlayError:
            self._server.stop()
            raise
        self.log(f"jaxstyle play: open {self.url} in a browser (Ctrl-C stops)")
        if self.admission.every_interface and self.token is None:
            self.log("warning: serving on every interface without --token: any machine that reaches this port can "
                     "steer, learn and record here")
        self._scene_setup()
        self._gui_setup()
        if load:
            self.load_run(self.run_dir, model)
        if self.learner is not None:
            threading.Thread(target=self._reader.warm, name="jaxstyle-play-reader", daemon=True).start()
        if loop:
            self._running.set()
            self._thread = threading.Thread(target=self._loop, name="jaxstyle-play-render", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        if self._server is None:
            return
        self._running.clear()
        if self._thread is not None:
            self._thread.join(5)
        if self._server is not None:
            self._server.stop()
        self._reader.close()

    @property
    def url(self) -> str:
        """The page's address (with the token when there is one)."""
        return guard.Admission(self.host, self.port, self.token).page_url()

    def load_run(self, run_dir: str | Path, model: AnyPlayModel | None = None, key: str | None = None) -> bool:
        """Load the run folder's model ``key`` (``pfnn``: the 2018 base, its few-shot and learned
        styles; a 2022 key: the trained model of ``RUN/lpn`` and its styles; default: the server's
        ``model``, else the 2018 one when there is one) or play ``model``, already loaded, and start
        one character; on failure keep the current one, show the message and return False. A
        model loaded once is kept (switching back compiles nothing again)."""
        run_dir = Path(run_dir)
        have = available_models(run_dir)
        if model is None and key is None:
            key = self.model_key if self.model_key in have else next(iter(have), PFNN)
        self._set_status("loading " + str(run_dir) + " ...")
        self.log(f"loading {run_dir}{'' if model is not None else f' ({key})'} ...")
        try:
            if model is None:
                cached = self._models.get((str(run_dir), key))
                model = cached or load_any(run_dir, key, allow_failed=self.allow_failed, runtime=self.lpn_runtime)
            session = Session(model, record_seconds=max(self.record_seconds, 30.0))
            session.step()  # compiles the step
        except (JaxstyleError, ValueError, KeyError, OSError) as e:
            self.show_error(f"{run_dir}: {_one_line(e)}")
            if self.session is None:
                self._set_status("no model loaded: give a run folder with a trained model below")
            return False
        with self.lock:
            if str(run_dir) != str(self.run_dir):
                self._models = {k: v for k, v in self._models.items() if k[0] == str(run_dir)}
            self._models[(str(run_dir), model.key)] = model
            self.run_dir = run_dir
            self.session = session
            self.learner = self._learner_for(run_dir)
            self._clear_characters()
        # the run's models, and any given to this server for it (a model passed to start())
        extra = {k: m.title for (d, k), m in self._models.items() if d == str(run_dir) and k not in have}
        self._refresh_model_options({**have, **extra})
        self._refresh_learn_controls()
        self._refresh_style_options()
        self._gui["speed"].value = round(session.speed / 0.05) * 0.05
        self._gui["run"].value = str(run_dir)
        self.message = ""
        self._gui["message"].content = ""
        self.log(f"loaded {model.title} of {run_dir}: styles {', '.join(model.styles)}")
        for line in model.refused:  # styles left out because their closed-loop check failed
            self._note(line)
            self.log(line)
        return True

    def load_model_key(self, key: str) -> bool:
        """Switch to the run folder's model ``key`` (the page's Model choice)."""
        if self.session is not None and key == self.session.model.key:
            return True
        return self.load_run(self.run_dir, key=key)

    # --- messages -----------------------------------------------------------------------------
    def show_error(self, text: str) -> None:
        """One line in the page (and a notification in every open page); the server goes on."""
        self.message = text
        self.log("error: " + text)
        if self._server is None:
            return
        self._gui["message"].content = f"**Problem:** {text}"
        for client in self._server.get_clients().values():
            client.add_notification("jaxstyle play", text, color="red", auto_close_seconds=8.0)

    def _note(self, text: str) -> None:
        self.message = text
        self._gui["message"].content = text

    def _set_status(self, text: str) -> None:
        if self._server is not None:
            self._gui["status"].content = text

    def _guarded(self, fn: Callable, reads_files: bool = False) -> Callable:
        """A GUI callback that shows bad input in the page instead of failing. ``reads_files``:
        it runs without the session lock (the render loop goes on while a file is read) and its
        errors are shown without quoting any file (:func:`jaxstyle.play.guard.without_content`)."""
        shown = guard.without_content if reads_files else (lambda text: text)

        def run(*args):
            try:
                with self.lock if not reads_files else contextlib.nullcontext():
                    if self.session is None and fn.__name__ not in ("_on_load_run",):
                        raise PlayError("no model loaded: give a run folder with a trained base")
                    fn(*args)
            except (JaxstyleError, ValueError, KeyError, OSError) as e:
                self.show_error(shown(_one_line(e)))
            except Exception as e:  # noqa: BLE001 - a bug in a callback must not end the page
                self.show_error(f"internal error: {type(e).__name__}: {shown(_one_line(e))}")

        return run

    # --- the render loop ----------------------------------------------------------------------
    def _loop(self) -> None:
        period = 1.0 / FPS
        next_t = time.perf_counter()
        while self._running.is_set():
            t0 = time.perf_counter()
            try:
                with self.lock:
                    if self.session is not None:
                        frame = self.session.step()
                        self._update_scene(frame, self.session.targets())
                        self.frame_times.append(time.monotonic())
                        self.step_ms = _smooth(self.step_ms, frame.step_ms)
                        self.frame_ms = _smooth(self.frame_ms, 1e3 * (time.perf_counter() - t0))
                        if self.session.frames % 15 == 0:
                            self._update_status()
            except Exception as e:  # noqa: BLE001 - show it, keep serving
                self.show_error(f"render loop: {type(e).__name__}: {_one_line(e)}")
                time.sleep(0.5)
            next_t += period
            delay = next_t - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.perf_counter()  # behind: do not try to catch up

    def _update_status(self) -> None:
        name, rate = self.session.describe(0)
        n = len(self.session.characters)
        self._gui["status"].content = (
            f"**Model:** {self.session.model.title}  \n**Style:** {name}  \n**Dropout rate:** {rate}  \n"
            f"**Controller step:** {self.step_ms:.2f} ms "
            f"({n} character{'s' if n > 1 else ''}); frame {self.frame_ms:.2f} ms")
        if self.learner is not None and self.learner.state == "running":
            state, fraction, message = self.learner.status()
            self._gui["progress"].value = 100.0 * fraction
            self._gui["learn_note"].content = message

    # --- the controls -------------------------------------------------------------------------
    def _gui_setup(self) -> None:
        gui = self._server.gui
        g = self._gui = {}
        gui.configure_theme(control_width="medium", show_logo=False)
        g["status"] = gui.add_markdown("loading ...")
        g["message"] = gui.add_markdown("")
        g["model"] = gui.add_dropdown("Model", options=[NO_MODEL], initial_value=NO_MODEL)
        with gui.add_folder("Steer"):
            gui.add_markdown("Click the ground to walk there (Shift+click adds a waypoint); keys W A S D or the "
                             "arrows walk relative to the camera (Shift runs), Space stops.")
            g["steer"] = gui.add_button_group("Walk", options=list(STEER_BUTTONS) + ["Stop"])
            g["speed"] = gui.add_slider("Speed (m/s)", min=0.2, max=4.0, step=0.05, initial_value=1.0)
            g["follow"] = gui.add_checkbox("Camera follows", initial_value=True)
            g["add"] = gui.add_button("Add a character")
            g["remove"] = gui.add_button("Remove a character")
        with gui.add_folder("Style"):
            g["style"] = gui.add_dropdown("Style", options=["(loading)"], initial_value="(loading)")
            gui.add_markdown("Blend up to three styles (the weights are normalised):")
            g["blend"] = [gui.add_dropdown(f"Blend {k}", options=[NO_BLEND], initial_value=NO_BLEND) for k in "ABC"]
            g["weights"] = [gui.add_slider(f"Weight {k}", min=0.0, max=1.0, step=0.05, initial_value=0.5)
                            for k in "ABC"]
            g["blend_on"] = gui.add_button("Play the blend")
        with gui.add_folder("Learn a style"):
            gui.add_markdown("A BVH clip of the base skeleton (a few seconds of one style): upload it or give its "
                             "path, then learn it. The characters keep walking meanwhile.")
            g["upload"] = gui.add_upload_button("Upload a BVH clip and learn it", mime_type="*/*")
            g["path"] = gui.add_text("BVH path", initial_value="")
            g["learn"] = gui.add_button("Learn the style of this file")
            g["progress"] = gui.add_progress_bar(0.0, animated=False)
            g["learn_note"] = gui.add_markdown("")
        with gui.add_folder("Record"):
            g["seconds"] = gui.add_slider("Seconds", min=1.0, max=30.0, step=1.0, initial_value=self.record_seconds)
            g["record"] = gui.add_button("Save the last seconds (BVH + GIF)")
            g["record_note"] = gui.add_markdown("")
        with gui.add_folder("Run folder"):
            g["run"] = gui.add_text("Run folder", initial_value=str(self.run_dir))
            g["load"] = gui.add_button("Load this run folder")

        g["steer"].on_click(lambda e: self._guarded(self._on_steer)(e.target.value))
        g["follow"].on_update(lambda _: self._on_follow())
        g["speed"].on_update(lambda _: self._guarded(lambda: self.session.set_speed(g["speed"].value))())
        g["add"].on_click(lambda _: self._guarded(lambda: self.session.add_character(g["style"].value))())
        g["remove"].on_click(lambda _: self._guarded(self.session_remove)())
        g["style"].on_update(lambda _: self._guarded(self._on_style)())
        g["model"].on_update(lambda _: self._on_model())
        g["blend_on"].on_click(lambda _: self._guarded(self._on_blend)())
        for handle in g["weights"] + g["blend"]:
            handle.on_update(lambda _: self._guarded(self._on_blend_change)())
        g["upload"].on_upload(lambda e: self._guarded(self._on_upload, reads_files=True)(e.target.value))
        g["learn"].on_click(lambda _: self._guarded(lambda: self.learn(g["path"].value), reads_files=True)())
        g["record"].on_click(lambda _: self._guarded(lambda: self.record(g["seconds"].value))())
        g["load"].on_click(lambda _: self._guarded_load())
        for key in ("W", "A", "S", "D", "arrowup", "arrowleft", "arrowdown", "arrowright"):
            for shift in (False, True):
                cmd = gui.add_command(f"{'Run' if shift else 'Walk'} {key}", hotkey=key,
                                      modifier="shift" if shift else None)
                cmd.on_trigger(lambda _, key=key, shift=shift: self._guarded(self.press)(key, shift))
        gui.add_command("Stop", hotkey="space").on_trigger(lambda _: self._guarded(lambda: self.session.stop())())

    def _on_model(self) -> None:
        """The Model choice: load (or take from the loaded ones) the chosen model in a thread, the
        current one playing on meanwhile."""
        key = self._model_keys.get(self._gui["model"].value)
        if self._refreshing_models or key is None or self.session is None or key == self.session.model.key:
            return
        threading.Thread(target=self.load_model_key, args=(key,), name="jaxstyle-play-model", daemon=True).start()

    def _refresh_model_options(self, have: dict[str, str]) -> None:
        # viser calls on_update for values set here too (and when new options drop the old value)
        self._refreshing_models = True
        try:
            self._model_keys = {label: key for key, label in have.items()}
            g = self._gui["model"]
            g.options = list(self._model_keys)
            g.value = have.get(self.session.model.key, next(iter(self._model_keys)))
        finally:
            self._refreshing_models = False

    def _guarded_load(self) -> None:
        """The page's "Run folder": a folder under ``runs_root`` only, loaded in a thread."""
        try:
            path = guard.confine(self._gui["run"].value, [self.runs_root], "run folder")
        except PlayError as e:
            self.show_error(_one_line(e))
            return
        threading.Thread(target=self.load_run, args=(path,), daemon=True).start()

    # --- recording ----------------------------------------------------------------------------
    def record(self, seconds: float) -> None:
        """Save the first character's last ``seconds`` as BVH (feet pinned) and GIF, in a thread."""
        rollout = self.session.recording(float(seconds), 0)
        name, _ = self.session.describe(0)
        model = self.session.model
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        path = self.run_dir / PLAY_DIR / "recordings" / f"{learn.style_name(name.replace('%', 'pc'))}_{stamp}"
        self._gui["record_note"].content = "saving ..."

        def save():
            try:
                files = save_recording(rollout, model, path, title=name)
                self.last_recording = files
                self._gui["record_note"].content = "saved: " + ", ".join(str(f) for f in files)
            except (JaxstyleError, ValueError, OSError) as e:
                self.show_error(f"recording: {_one_line(e)}")

        threading.Thread(target=save, name="jaxstyle-play-record", daemon=True).start()


def _smooth(old: float, new: float, keep: float = 0.9) -> float:
    return new if not math.isfinite(old) else keep * old + (1 - keep) * new


__all__ = ["PlayServer"]
