"""The ``jaxstyle play`` page's learning controls (:class:`LearnPanel`, a part of
:class:`jaxstyle.play.server.PlayServer`): a BVH clip the page uploads or names is confined to the
allowed folders (:mod:`jaxstyle.play.guard`), read and checked in a worker thread, then learned in
the background by the run's 2018 model's :class:`jaxstyle.play.learn.Learner`; a learned style joins
the model's styles, a refused upload is removed again. While a 2022 model plays, the controls are
disabled and say why.
"""

from __future__ import annotations

import dataclasses
import threading
import uuid
from pathlib import Path

from jaxstyle.play import guard, learn
from jaxstyle.play.models import PFNN, PLAY_DIR, PlayError, PlayModel, Style
from jaxstyle.train.defaults import LEARN_EPOCHS

LEARN_2018_ONLY = ("learning a style live is the 2018 few-shot sweep (Mason et al. 2018): choose the 2018 PFNN "
                   "under Model to learn one; a 2022 model learns new styles with `jaxstyle lpn --clip FILE`")
NO_2018_MODEL = ("learning a style live is the 2018 few-shot sweep (Mason et al. 2018), and this run folder has no "
                 "2018 model (RUN/base); a 2022 model learns new styles with `jaxstyle lpn --clip FILE`")


MAX_UPLOAD_BYTES = 8_000_000  # an upload's default cap (a 10 s 100STYLE clip is about 0.1 MB)


@dataclasses.dataclass(frozen=True)
class Learning:
    """How the page learns a style live: the few-shot sweep's ``epochs`` and dropout ``rates``
    (``None``: the learner's default, :data:`jaxstyle.train.defaults.DEFAULT_RATES`), the folders a
    clip the page names may lie in besides the run folder (``data_dirs``) and the cap on an
    upload's size (``max_upload_bytes``)."""

    epochs: int = LEARN_EPOCHS
    rates: tuple[float, ...] | None = None
    data_dirs: tuple[str | Path, ...] = ()
    max_upload_bytes: int = MAX_UPLOAD_BYTES


class LearnPanel:
    """The learning half of :class:`jaxstyle.play.server.PlayServer` (which inherits it and calls
    :meth:`_init_learning` first). Besides its own state it uses the server's ``session``, ``lock``,
    ``run_dir``, ``allow_failed``, ``_models``, ``_model_keys``, the page's controls ``_gui`` and the
    server's ``show_error``, ``log``, ``_guarded`` and ``_refresh_style_options``."""

    def _init_learning(self, learning: Learning) -> None:
        """The learning state: ``learner`` (the run's 2018 model's; ``None`` without one) and the
        :class:`Learning` settings as ``learn_epochs``, ``learn_rates``, ``data_dirs`` and
        ``max_upload_bytes``."""
        self.learner: learn.Learner | None = None
        self.learn_epochs = int(learning.epochs)
        self.learn_rates = None if learning.rates is None else tuple(learning.rates)
        self.data_dirs = tuple(Path(d) for d in learning.data_dirs)
        self.max_upload_bytes = int(learning.max_upload_bytes)
        self._learners: dict[int, tuple[PlayModel, learn.Learner]] = {}  # per 2018 model (kept alive with it)
        self._reading = threading.Lock()  # held while a clip the page named is read and checked
        self._pending_upload: Path | None = None
        self._reader = learn.ClipReader()

    def _learner_for(self, run_dir: Path) -> learn.Learner | None:
        """The learner of the run's 2018 model (loaded when a 2022 model plays but the run has a
        2018 one too, so a style learned meanwhile has a model to join); ``None`` without one."""
        model = self._models.get((str(run_dir), PFNN))
        if model is None and self.session is not None and isinstance(self.session.model, PlayModel) \
                and self.session.model.run_dir == run_dir:
            model = self.session.model
        if model is None:
            return None
        if id(model) not in self._learners:
            self._learners[id(model)] = (model, learn.Learner(
                model, lambda style, m=model: self._learned(style, m), on_fail=self._learn_failed,
                epochs=self.learn_epochs, allow_failed=self.allow_failed,
                **({"rates": self.learn_rates} if self.learn_rates else {})))
        return self._learners[id(model)][1]

    def _refresh_learn_controls(self) -> None:
        """Learning a style live needs the 2018 model: disabled, and saying so, while a 2022 one plays."""
        off = not self.session.model.learnable
        for k in ("upload", "path", "learn"):
            self._gui[k].disabled = off
        if off:
            self._gui["learn_note"].content = f"**{self.session.model.title}:** {self._learn_refusal()}."
        elif self.learner is None or self.learner.state == "idle":
            self._gui["learn_note"].content = ""

    def _learn_refusal(self) -> str:
        return LEARN_2018_ONLY if PFNN in self._model_keys.values() else NO_2018_MODEL

    def _check_learnable(self) -> None:
        """Refuse to learn (before an upload is even written) while a model that cannot plays."""
        if not self.session.model.learnable or self.learner is None:
            raise PlayError(f"{self.session.model.title} plays: {self._learn_refusal()}")

    def read_roots(self) -> tuple[Path, ...]:
        """The folders under which the page may name a BVH file: the run folder (its uploads
        included) and the server's ``data_dirs``."""
        return (self.run_dir, *self.data_dirs)

    def _on_upload(self, uploaded) -> None:
        """An upload: refused above the size cap (nothing written); otherwise written under a
        fresh folder (``RUN/play/uploads/<random>/<name>``, so it never replaces another upload,
        such as a learned style's source) and read and learned like a named file; removed again
        when refused or when learning it fails."""
        if not uploaded.name:
            return
        self._check_learnable()
        name = Path(uploaded.name).name
        size = len(uploaded.content)
        if size > self.max_upload_bytes:
            raise PlayError(f"{name}: the upload is {size / 1e6:.1f} MB, more than the {self.max_upload_bytes / 1e6:g} "
                            "MB allowed (jaxstyle play --max-upload-mb raises it)")
        folder = self.run_dir / PLAY_DIR / "uploads" / uuid.uuid4().hex[:12]
        folder.mkdir(parents=True)
        path = folder / (learn.style_name(name) + ".bvh")
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_bytes(uploaded.content)
        tmp.replace(path)
        self._read_then_learn(path, upload=True)

    def learn(self, path: str) -> threading.Thread:
        """Learn the BVH file at ``path`` (it must lie under :meth:`read_roots`): read and checked
        in a worker thread (a bad file's refusal then shows in the page), then learned in the
        background (progress in the page). Returns the worker thread."""
        self._check_learnable()
        resolved = guard.confine(path, self.read_roots(), "BVH file")
        return self._read_then_learn(resolved)

    def _read_then_learn(self, path: Path, upload: bool = False) -> threading.Thread:
        if self.learner.busy:
            self._discard_upload(path if upload else None)
            raise PlayError("a style is being learned already; wait until it is done")
        if not self._reading.acquire(blocking=False):
            self._discard_upload(path if upload else None)
            raise PlayError("a clip is being read already; wait until it is checked")
        model, learner = self.session.model, self.learner
        self._gui["learn_note"].content = f"{path.name}: reading ..."

        def work() -> None:  # errors are shown by _guarded
            try:
                learn.check_clip(path, model, self._reader.names)  # in another process, off the lock
                with self.lock:
                    name = learner.start(path)
                    self._pending_upload = path if upload else None
                self._gui["progress"].value = 0.0
                self._gui["learn_note"].content = f"{name}: starting ..."
            except BaseException:
                self._discard_upload(path if upload else None)
                self._gui["learn_note"].content = ""
                raise
            finally:
                self._reading.release()

        thread = threading.Thread(target=self._guarded(work, reads_files=True), name="jaxstyle-play-read",
                                  daemon=True)
        thread.start()
        return thread

    def _discard_upload(self, path: Path | None) -> None:
        """Remove a refused upload (its fresh folder too)."""
        if path is None:
            return
        path.unlink(missing_ok=True)
        try:
            path.parent.rmdir()
        except OSError:
            pass

    def _learned(self, style: Style, model: PlayModel) -> None:
        """A style learned on the 2018 ``model`` joins its styles (and the dropdown if it plays)."""
        with self.lock:
            if self.session is not None and self.session.model is model:
                self.session.add_style(style)
                self._refresh_style_options()
                note = ""
            else:
                model.styles[style.name] = style
                note = f" (for the {model.title}: choose it under Model to play it)"
            self._pending_upload = None  # kept: the learned style's source
        message = self._learners[id(model)][1].status()[2] + note
        self._gui["progress"].value = 100.0
        self._gui["learn_note"].content = message
        self.log(message)

    def _learn_failed(self, message: str) -> None:
        with self.lock:
            pending, self._pending_upload = self._pending_upload, None
        self._discard_upload(pending)
        self._gui["progress"].value = 0.0
        self._gui["learn_note"].content = message
        self.show_error(message)
