"""What every command shares: one-line errors about paths, the run folder, the compilation cache, the
distributed start, small helpers. The argument parsing is :mod:`jaxstyle.cli.args`."""

from __future__ import annotations

import contextlib
import datetime
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Sequence

DEFAULT_RUN = Path("runs/jaxstyle")
DEMO_RUN = Path("runs/demo")
DATA_HELP = ("a style folder: <Style>/<Style>_<GAIT>.bvh files, with 100STYLE's Frame_Cuts.csv or without it (whole "
             "files), or a folder holding 100style/")


class CLIError(Exception):
    """A problem with the user's arguments or files, reported on one line."""


# --- paths: one-line descriptions of what is wrong with them -----------------------------------

def one_line(message) -> str:
    """``message`` on one line (its non-empty lines joined by spaces)."""
    return " ".join(line.strip() for line in str(message).splitlines() if line.strip())


def file_in_the_way(path: str | os.PathLike) -> Path | None:
    """The nearest ancestor of ``path`` that exists as something other than a folder (a regular
    file), if any: the reason a folder cannot be created there."""
    for parent in Path(path).parents:
        if parent.exists():
            return None if parent.is_dir() else parent
    return None


def describe_os_error(e: OSError) -> str:
    """One line for an :class:`OSError`: the path(s) it names and the problem, e.g.
    ``runs/x/sub: not a directory (runs/x is a file)``."""
    problem = e.strerror or one_line(e) or type(e).__name__
    problem = problem[:1].lower() + problem[1:]
    if e.filename is None:
        return f"{type(e).__name__}: {problem}"
    where = os.fsdecode(e.filename) if isinstance(e.filename, (str, bytes, os.PathLike)) else str(e.filename)
    if e.filename2 is not None:
        where += f" -> {os.fsdecode(e.filename2)}"
    if isinstance(e, (NotADirectoryError, FileNotFoundError)):
        blocker = file_in_the_way(where.split(" -> ")[0])
        if blocker is not None:
            problem += f" ({blocker} is a file, not a folder)"
    return f"{where}: {problem}"


def ensure_folder(folder: Path, flag: str, target: Path | None = None) -> Path:
    """Create ``folder`` (parents too) and check that files can be written in it, else raise a
    :class:`CLIError` naming ``flag`` and the path: the folder itself (``--run R``) or the file
    ``target`` to be written in it (``--out R/x.gif``)."""
    folder = Path(folder)
    subject = f"{flag} {folder if target is None else target}"
    it = "" if target is None else f" {folder}"
    if folder.exists() and not folder.is_dir():
        raise CLIError(f"{subject}: {'' if target is None else f'{folder} '}is a file, not a folder")
    blocker = file_in_the_way(folder)
    if blocker is not None:
        raise CLIError(f"{subject}: cannot create the folder{it}: {blocker} is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CLIError(f"{subject}: cannot create the folder{it}: {describe_os_error(e)}") from None
    try:
        tempfile.TemporaryFile(dir=folder).close()
    except OSError as e:
        raise CLIError(f"{subject}: cannot write in the folder{it}: {(e.strerror or str(e)).lower()}") from None
    return folder


def check_input_file(path: Path, flag: str = "", what: str = "file") -> None:
    """Raise a :class:`CLIError` unless ``path`` is an existing file (not a folder)."""
    subject = f"{flag} {path}" if flag else str(path)
    if path.is_dir():
        raise CLIError(f"{subject}: is a folder, not a {what}")
    if not path.exists():
        blocker = file_in_the_way(path)
        raise CLIError(f"{subject}: no such file" + (f" ({blocker} is a file, not a folder)" if blocker else ""))
    if not path.is_file():
        raise CLIError(f"{subject}: not a regular file")


def check_input_folder(path: Path, flag: str) -> None:
    """Raise a :class:`CLIError` when ``path`` exists but is not a folder, or cannot exist because a
    file stands where one of its parents should be (a plainly missing folder is left to the
    command, whose message says what such a folder must hold or creates it)."""
    if path.exists() and not path.is_dir():
        raise CLIError(f"{flag} {path}: is a file, not a folder")
    blocker = file_in_the_way(path)
    if blocker is not None:
        raise CLIError(f"{flag} {path}: {blocker} is a file, not a folder")


# --- the run folder -----------------------------------------------------------------------------

def _jsonable(value):
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    return value


_UNSAVED = ("handler", "debug", "quiet")


class Run:
    """A run folder: ``say`` prints and appends to ``log.txt``; the command's settings are saved in
    ``config.json`` under the command's name (earlier commands' entries are kept). ``writer=False``
    (a process other than 0 of a ``--distributed`` run) writes and prints nothing."""

    def __init__(self, directory: Path, command: str, settings: dict, argv: Sequence[str], *, writer: bool = True,
                 lock: bool = True):
        self.dir = Path(directory)
        self.command = command
        self.writer = writer
        self._lock = self._log = None
        if not writer:  # another process of a --distributed run: process 0 writes and reports
            return
        self.dir.mkdir(parents=True, exist_ok=True)
        if lock:
            self._lock = lock_run(self.dir, argv)
        try:
            self.save_settings(settings)
            self._log = open(self.dir / "log.txt", "a", encoding="utf-8")
        except BaseException:
            self.close()  # the lock too
            raise
        stamp = datetime.datetime.now().isoformat(timespec="seconds")
        self._log.write(f"\n=== {stamp} jaxstyle {' '.join(argv)}\n")
        self._log.flush()

    def save_settings(self, settings: dict) -> None:
        """Write ``settings`` into ``config.json`` under this command's name (atomically)."""
        config_path = self.dir / "config.json"
        config = {}
        if config_path.is_file():
            from jaxstyle.train.checkpoint import read_json  # loads JAX, so here

            try:
                config = read_json(config_path)
            except ValueError as e:
                raise CLIError(f"{e}; it holds the settings of the commands run here: fix it by hand") from None
            if not isinstance(config, dict):
                raise CLIError(f"{config_path}: expected a JSON object of the commands' settings, got "
                               f"{type(config).__name__}; fix it by hand")
        config[self.command] = _jsonable({k: v for k, v in settings.items() if k not in _UNSAVED})
        tmp = config_path.with_name("config.json.tmp")
        from jaxstyle.train.checkpoint import json_text  # strict JSON (NaN -> null); loads JAX, so here

        tmp.write_text(json_text(config))
        os.replace(tmp, config_path)

    def say(self, text: str = "") -> None:
        if self._log is None:
            return
        print(text, flush=True)
        self._log.write(text + "\n")
        self._log.flush()

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None
        if self._lock is not None:
            self._lock.close()  # releases the lock
            self._lock = None


LOCK_FILE = ".jaxstyle.lock"


def lock_run(directory: Path, argv: Sequence[str]):
    """Take the run folder's advisory lock (``flock`` on ``RUN/.jaxstyle.lock``, which names the
    holder) or raise a CLIError naming the command that holds it. The operating system releases
    the lock when its process ends, however it ends, so a killed command leaves no stale lock.
    Returns the open lock file (closing it releases the lock)."""
    import fcntl

    path = Path(directory) / LOCK_FILE
    f = open(path, "a+", encoding="utf-8")
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.seek(0)
        holder = f.read().strip() or "another process"
        f.close()
        raise CLIError(f"--run {directory}: in use by {holder}; wait until it finishes (one command writes a run "
                       "folder at a time)") from None
    f.seek(0)
    f.truncate()
    f.write(f"pid {os.getpid()} (jaxstyle {' '.join(argv)})"[:300])
    f.flush()
    return f


XLA_CACHE_VAR = "JAXSTYLE_XLA_CACHE"


def xla_cache_dir() -> Path | None:
    """Where the command line keeps compiled programs between runs: ``$JAXSTYLE_XLA_CACHE``, else
    ``$XDG_CACHE_HOME/jaxstyle/xla`` (``~/.cache/jaxstyle/xla``); ``None`` when the variable is
    ``off`` (or empty)."""
    value = os.environ.get(XLA_CACHE_VAR)
    if value is not None:
        return None if value.strip().lower() in ("", "off", "0", "no") else Path(value).expanduser()
    home = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(home) / "jaxstyle" / "xla"


def use_xla_cache() -> Path | None:
    """Turn on JAX's persistent compilation cache in :func:`xla_cache_dir` (every program, however
    quick to compile), so a second ``jaxstyle play`` or ``jaxstyle sweep`` on the same base loads its
    programs instead of compiling them: a 10 s clip learned live is playable 8.7 s after its upload
    instead of 17.3 s on the demo's base (``python benchmarks/play.py --learn``, 2 CPU cores). A folder that
    cannot be made leaves the cache off. Returns the folder in use."""
    import jax

    folder = xla_cache_dir()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder


def start_distributed(args) -> bool:
    """Join the other processes when ``--distributed`` is given (before anything uses a device);
    returns whether this process writes the run folder (process 0, or the only process)."""
    if not getattr(args, "distributed", False):
        for flag in ("coordinator", "num_processes", "process_id"):
            if getattr(args, flag, None) is not None:
                raise CLIError(f"--{flag.replace('_', '-')} needs --distributed")
        return True
    from jaxstyle.train import shard

    shard.initialize(args.coordinator, args.num_processes, args.process_id)
    return shard.is_writer()



# --- helpers ------------------------------------------------------------------------------------

def progress(args) -> bool:
    """Progress bars: unless ``--quiet``, and only on the process that reports (``--distributed``)."""
    if getattr(args, "distributed", False):
        from jaxstyle.train import shard

        if not shard.is_writer():
            return False
    return not args.quiet


def _cpu_name() -> str:
    """The CPU's model name (Linux), else what :mod:`platform` knows."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def machine() -> str:
    import jax

    return (f"{_cpu_name()}, {os.cpu_count()} cores, jax {jax.__version__} on "
            f"{jax.devices()[0].platform} x {jax.device_count()}")


def elapsed(t0: float) -> str:
    s = time.perf_counter() - t0
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min"


def written(run: Run, title: str, files: Sequence[Path]) -> None:
    run.say(f"{title}:")
    for f in files:
        run.say(f"  {f}")
