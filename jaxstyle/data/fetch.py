"""Download, verify and unpack public motion-capture datasets (standard library only, plus tqdm).

``fetch("100style", "data")`` downloads the 100STYLE archive into ``data/``, resuming an interrupted
download, checks its md5, unpacks it safely and returns the folder holding the style sub-folders::

    from jaxstyle.data.fetch import fetch
    root = fetch("100style", "~/data")          # ~/data/100STYLE, with Frame_Cuts.csv etc.
    specs = jaxstyle.data.clips.specs_100style(root)

How it behaves:

* the download goes to ``<dest>/<filename>.part``; a re-run resumes it with an HTTP
  ``Range: bytes=N-`` request (a server that ignores ``Range`` and answers 200 restarts it from
  zero; a 416 answer means the part is already complete). A connection dropped mid-transfer is
  resumed automatically a few times, as long as each attempt made progress;
* the finished file's md5 is checked; only then is ``.part`` renamed to the final name
  (``os.replace``, atomic). A bad file is moved to ``<filename>.bad`` and :class:`FetchError` says
  which checksum was expected and which one was found;
* a verified archive already at ``<dest>/<filename>`` is never downloaded again: a re-run
  re-verifies it and unpacks it again only if the unpacked folder is missing. An archive put there
  by hand (downloaded in a browser) is verified and unpacked the same way, offline. A finished unpack is
  recorded in ``<dest>/.<filename>.unpacked`` (the md5), so deleting the archive afterwards to save
  space does not make a re-run download it again;
* zip and tar archives are unpacked into ``dest``; members with absolute paths or ``..`` are
  refused before anything is written;
* without a network (DNS failure, connection refused, timeout) it fails fast, after at most
  ``timeout`` seconds, with one :class:`FetchError` naming the URL, the destination and how to put
  the files in place by hand. There is no retry loop on connection failures.
"""

from __future__ import annotations

import hashlib
import http.client
import ipaddress
import logging
import os
import re
import socket
import tarfile
import threading
import urllib.error
import urllib.parse
import urllib.request
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path

from jaxstyle.errors import JaxstyleError

__all__ = ["REMOTES", "FetchError", "FetchWarning", "Remote", "fetch", "file_md5", "missing_files", "unpack_archive",
           "verify_md5"]

log = logging.getLogger(__name__)

CHUNK = 1 << 20  # bytes read and hashed at a time
USER_AGENT = "jaxstyle-fetch/0.1 (Python urllib)"


class FetchError(JaxstyleError, RuntimeError):
    """A dataset could not be downloaded, verified or unpacked; the message says what to do next.

    ``url`` and ``dest`` (the destination folder) are kept as attributes when known.
    """

    def __init__(self, message: str, *, url: str | None = None, dest: str | os.PathLike | None = None):
        super().__init__(message)
        self.url = url
        self.dest = None if dest is None else Path(dest)


class FetchWarning(UserWarning):
    """Something the user should know about fetched data (for example files the archive lacks)."""


@dataclass(frozen=True)
class Remote:
    """One downloadable dataset archive.

    ``folder`` is where the archive unpacks to, relative to the destination (``""``: the
    destination itself); ``required`` names files the unpacked data folder must hold, and ``note``
    says where to get them if the archive lacks them.
    """

    name: str
    url: str
    md5: str
    filename: str
    homepage: str
    folder: str = ""
    size: int | None = None
    required: tuple[str, ...] = ()
    citation: str = ""
    licence: str = ""
    note: str = ""


# 100STYLE (Mason, Starke & Komura 2022), Zenodo record 8127870, CC BY 4.0.
# What was found, and how sure it is (no internet here; from public code that downloads it):
# * file name ``100STYLE.zip`` (the 100 styles' raw 60 fps BVH, about 1.47 GB): certain. Several independent
#   projects download it as https://zenodo.org/records/8127870/files/100STYLE.zip?download=1 (curl/wget scripts) or
#   https://zenodo.org/api/records/8127870/files/100STYLE.zip/content (a nix fetchurl pinned by hash, so that URL
#   served the file); both are Zenodo's standard forms and either should work. The record also holds
#   ``100Style-Labelled-Data.zip`` (about 14.8 GB of processed data), which jaxstyle does not need.
# * md5 3cf627852fd8192024c04a8d0ef49583: as given by the project, and the same value is quoted as Zenodo's
#   checksum by other projects. Two of them also pin the sha256
#   2c3b4017f8e2397ee6904c9b9f43551d8b426d39ddc3558d121fee9e55cb2d58 (noted here, not checked).
# * exact size in bytes: not found, so ``size`` is None (the progress bar uses Content-Length).
# * layout: top folder ``100STYLE/`` with ``<Style>/<Style>_<GAIT>.bvh``, and (fairly sure: a script reads
#   ``100STYLE/Frame_Cuts.csv`` straight from the zip) the two CSVs beside the style folders. If they are missing,
#   fetch() warns; they are also in the authors' repository github.com/ianxmason/local-phases under
#   data-labelling/Unity/Assets/Data/.
_LOCAL_PHASES_CSVS = ("https://github.com/ianxmason/local-phases/tree/main/data-labelling/Unity/Assets/Data")

REMOTES: dict[str, Remote] = {
    "100style": Remote(
        name="100STYLE",
        url="https://zenodo.org/records/8127870/files/100STYLE.zip?download=1",
        md5="3cf627852fd8192024c04a8d0ef49583",
        filename="100STYLE.zip",
        homepage="https://zenodo.org/records/8127870",
        folder="100STYLE",
        size=None,
        required=("Frame_Cuts.csv", "Dataset_List.csv"),
        citation=("I. Mason, S. Starke, T. Komura, \"Real-Time Style Modelling of Human Locomotion via Feature-Wise "
                  "Transformations and Local Motion Phases\", Proc. ACM CGIT 5(1), 2022, doi:10.1145/3522618"),
        licence="CC BY 4.0 (https://creativecommons.org/licenses/by/4.0/): credit the authors when you use it",
        note=(f"Frame_Cuts.csv and Dataset_List.csv are also in the authors' repository ianxmason/local-phases, "
              f"folder data-labelling/Unity/Assets/Data/ ({_LOCAL_PHASES_CSVS}); put them beside the style folders"),
    ),
}


# --- checksums ---------------------------------------------------------------------------------------------------

def file_md5(path: str | os.PathLike, *, progress: bool = False) -> str:
    """The md5 hex digest of a file, read in 1 MiB chunks (with a tqdm bar if ``progress``)."""
    path = Path(path)
    digest = hashlib.md5(usedforsecurity=False)
    with open(path, "rb") as f, _bar(progress, path.stat().st_size, 0, f"md5 {path.name}") as bar:
        while chunk := f.read(CHUNK):
            digest.update(chunk)
            bar.update(len(chunk))
    return digest.hexdigest()


def verify_md5(path: str | os.PathLike, md5: str, *, progress: bool = False) -> bool:
    """Whether the file's md5 equals ``md5`` (case-insensitive); ``False`` if the file is missing."""
    if not Path(path).is_file():
        return False
    return file_md5(path, progress=progress) == md5.strip().lower()


# --- the public entry point --------------------------------------------------------------------------------------

def fetch(name: str, dest: str | os.PathLike, *, url: str | None = None, timeout: float = 10.0,
          progress: bool = True, unpack: bool = True, resume_attempts: int = 3) -> Path:
    """Download dataset ``name`` (a key of :data:`REMOTES`) into ``dest``, verify and unpack it.

    Returns the folder holding the data (for 100STYLE, the one with the style sub-folders and
    ``Frame_Cuts.csv``/``Dataset_List.csv``), or the verified archive when ``unpack`` is false.
    ``url`` overrides the remote's URL (a mirror); the checksum still applies. ``timeout`` (seconds)
    bounds connecting (and name lookup) and each read. ``resume_attempts`` is how many times a
    transfer that broke off after making progress is resumed within this call.

    Raises :class:`FetchError` for an unknown name, no network, an HTTP error, a checksum mismatch
    or an unsafe archive; its message says what to do (re-run to resume, or place the file by hand).
    Warns (:class:`FetchWarning`) if the unpacked data lacks the remote's ``required`` files.
    """
    remote = _remote(name)
    dest = Path(dest).expanduser()
    url = url or remote.url
    archive = dest / remote.filename
    part = dest / (remote.filename + ".part")
    marker = dest / f".{remote.filename}.unpacked"
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise FetchError(f"cannot create the destination folder {dest}: {e}", url=url, dest=dest) from e

    if unpack and not archive.exists() and _marker_ok(marker, remote) and _unpacked_root(dest, remote).is_dir():
        # Unpacked earlier, archive since deleted: nothing to download.
        log.info("%s already unpacked in %s", remote.name, dest)
        return _data_root(dest, remote, warn=True)

    if archive.exists():
        _check_md5(archive, remote, f"{archive} is not the expected {remote.name} archive", "It was moved to {bad}",
                   "Re-run to download it again.", help_text=_manual_help(name, remote, url, dest), url=url, dest=dest,
                   progress=progress)
    else:
        _download(remote, name, url, part, dest, timeout=timeout, progress=progress, attempts=resume_attempts)
        _check_md5(part, remote, f"checksum mismatch for {remote.filename} downloaded from {url}",
                   "The file was moved to {bad}", "Re-run to download it again; if it keeps failing, the server or "
                   "a proxy is altering the file.", help_text=_manual_help(name, remote, url, dest), url=url,
                   dest=dest, progress=progress)
        os.replace(part, archive)

    if not unpack:
        return archive
    if not (_marker_ok(marker, remote) and _unpacked_root(dest, remote).is_dir()):
        marker.unlink(missing_ok=True)
        unpack_archive(archive, dest, progress=progress)
        marker.write_text(remote.md5.lower() + "\n")
    return _data_root(dest, remote, warn=True)


def missing_files(folder: str | os.PathLike, remote: Remote | str) -> list[str]:
    """The remote's ``required`` files absent from ``folder`` (a :class:`Remote` or a REMOTES key)."""
    remote = _remote(remote) if isinstance(remote, str) else remote
    return [f for f in remote.required if not (Path(folder) / f).is_file()]


# --- unpacking ---------------------------------------------------------------------------------------------------

def unpack_archive(archive: str | os.PathLike, dest: str | os.PathLike, *, progress: bool = False) -> None:
    """Unpack a zip or tar archive into ``dest``, refusing (before writing anything) any member whose
    path is absolute or contains ``..``; tar links must stay inside too (tarfile's ``data`` filter)."""
    archive, dest = Path(archive), Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    if zipfile.is_zipfile(archive):
        with zipfile.ZipFile(archive) as zf:
            members = zf.infolist()
            for m in members:
                _check_member(m.filename, archive, dest)
            with _bar(progress, len(members), 0, f"unpack {archive.name}", unit="file") as bar:
                for m in members:
                    zf.extract(m, dest)
                    bar.update(1)
    elif tarfile.is_tarfile(archive):
        with tarfile.open(archive) as tf:
            members = tf.getmembers()
            for m in members:
                _check_member(m.name, archive, dest)
                if m.issym() or m.islnk():
                    _check_member(m.linkname, archive, dest, what="link target")
            kwargs = {"filter": "data"} if hasattr(tarfile, "data_filter") else {}
            with _bar(progress, len(members), 0, f"unpack {archive.name}", unit="file") as bar:
                for m in members:
                    try:
                        tf.extract(m, dest, **kwargs)
                    except tarfile.FilterError as e:
                        raise FetchError(f"refusing to unpack {archive}: {e}", dest=dest) from e
                    bar.update(1)
    else:
        raise FetchError(f"{archive} is neither a zip nor a tar archive; cannot unpack it", dest=dest)


def _check_member(name: str, archive: Path, dest: Path, what: str = "member") -> None:
    norm = name.replace("\\", "/")
    if norm.startswith("/") or re.match(r"^[A-Za-z]:", norm) or ".." in norm.split("/"):
        raise FetchError(f"refusing to unpack {archive}: {what} {name!r} would be written outside {dest} "
                         f"(absolute path or '..'); nothing was unpacked", dest=dest)


def _unpacked_root(dest: Path, remote: Remote) -> Path:
    return dest / remote.folder if remote.folder else dest


def _data_root(dest: Path, remote: Remote, *, warn: bool) -> Path:
    """The folder holding the data: ``dest/folder`` when it has the required files, else the first folder
    (up to three levels down) that does, else ``dest/folder`` (or ``dest``) with a warning."""
    root = _unpacked_root(dest, remote)
    if not remote.required or (root.is_dir() and not missing_files(root, remote)):
        return root
    for base in (root, dest):
        for depth in range(4):
            for hit in sorted(base.glob("/".join(["*"] * depth + [remote.required[0]]))):
                if hit.is_file() and not missing_files(hit.parent, remote):
                    return hit.parent
    if not root.is_dir():
        root = dest
    if warn:
        missing = missing_files(root, remote)
        warnings.warn(f"{remote.name} was unpacked into {root}, but {', '.join(missing)} "
                      f"{'is' if len(missing) == 1 else 'are'} missing; jaxstyle needs "
                      f"{'it' if len(missing) == 1 else 'them'} there. {remote.note}", FetchWarning, stacklevel=3)
    return root


def _marker_ok(marker: Path, remote: Remote) -> bool:
    try:
        return marker.read_text().strip() == remote.md5.lower()
    except OSError:
        return False


# --- downloading -------------------------------------------------------------------------------------------------

class _Unreachable(Exception):
    """The request failed before any data came (offline, DNS, refused, timeout, HTTP error)."""


class _Interrupted(Exception):
    """The transfer broke off; ``size`` bytes are in the part file."""

    def __init__(self, size: int, reason: str):
        super().__init__(reason)
        self.size = size


def _download(remote: Remote, name: str, url: str, part: Path, dest: Path, *, timeout: float, progress: bool,
              attempts: int) -> None:
    tries = 0
    while True:
        start = part.stat().st_size if part.exists() else 0
        if remote.size is not None and start == remote.size:
            return  # complete already; the checksum decides
        try:
            _check_resolves(url, timeout)
            _download_once(url, part, start, timeout=timeout, progress=progress, label=remote.filename)
            return
        except _Unreachable as e:
            kept = f"\n{_size(part)} already downloaded in {part} are kept; a re-run resumes from there." \
                if part.exists() and part.stat().st_size else ""
            raise FetchError(f"cannot download {remote.name} from {url}: {e}.{kept}\n"
                             + _manual_help(name, remote, url, dest), url=url, dest=dest) from None
        except _Interrupted as e:
            tries += 1
            if e.size <= start or tries > attempts:
                raise FetchError(f"the download of {remote.name} from {url} broke off after {_size(part)} ({e}). "
                                 f"The partial file {part} is kept: re-run to resume it.\n"
                                 + _manual_help(name, remote, url, dest), url=url, dest=dest) from None
            log.warning("download broke off after %d bytes (%s); resuming", e.size, e)


def _download_once(url: str, part: Path, start: int, *, timeout: float, progress: bool, label: str,
                   use_range: bool = True) -> None:
    """One HTTP request appending to (or restarting) ``part``; raises _Unreachable or _Interrupted."""
    from_byte = start if use_range else 0
    headers = {"User-Agent": USER_AGENT, "Accept-Encoding": "identity"}
    if from_byte:
        headers["Range"] = f"bytes={from_byte}-"
    try:
        response = urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=timeout)
    except urllib.error.HTTPError as e:
        content_range = e.headers.get("Content-Range", "") if e.headers else ""
        e.close()
        if e.code == 416 and from_byte:
            total = _range_total(content_range)
            if total is None or total == from_byte:
                return  # the part is already complete
            return _download_once(url, part, 0, timeout=timeout, progress=progress, label=label, use_range=False)
        raise _Unreachable(f"the server answered HTTP {e.code} {e.reason}") from None
    except urllib.error.URLError as e:
        raise _Unreachable(_describe(e.reason)) from None
    except (OSError, http.client.HTTPException) as e:
        raise _Unreachable(_describe(e)) from None

    with response:
        if response.status == 206:
            first = _range_first(response.headers.get("Content-Range", ""))
            if first != from_byte:  # not the range asked for: start again without Range
                response.close()
                return _download_once(url, part, 0, timeout=timeout, progress=progress, label=label,
                                      use_range=False)
            mode = "ab"
        else:  # 200: the whole file (no Range sent, or the server ignored it)
            from_byte, mode = 0, "wb"
        length = response.headers.get("Content-Length")
        total = from_byte + int(length) if length and length.isdigit() else None
        received = from_byte
        with open(part, mode) as f, _bar(progress, total, from_byte, label) as bar:
            try:
                while chunk := response.read1(CHUNK):  # read1: what has arrived, so a stall loses nothing
                    f.write(chunk)
                    received += len(chunk)
                    bar.update(len(chunk))
            except (OSError, http.client.HTTPException) as e:
                raise _Interrupted(received, _describe(e)) from None
        if total is not None and received < total:
            raise _Interrupted(received, f"connection closed at {received} of {total} bytes")


def _check_resolves(url: str, timeout: float) -> None:
    """Resolve the URL's host within ``timeout`` seconds (name lookup ignores socket timeouts), unless a
    proxy will do it for us. Raises _Unreachable on failure."""
    parts = urllib.parse.urlsplit(url)
    host = parts.hostname
    if not host or parts.scheme not in ("http", "https"):
        return
    try:
        ipaddress.ip_address(host)
        return
    except ValueError:
        pass
    if parts.scheme in urllib.request.getproxies() and not urllib.request.proxy_bypass(host):
        return
    outcome: dict[str, BaseException] = {}

    def lookup() -> None:
        try:
            socket.getaddrinfo(host, parts.port or (443 if parts.scheme == "https" else 80), type=socket.SOCK_STREAM)
        except BaseException as e:  # reported to the caller
            outcome["error"] = e

    worker = threading.Thread(target=lookup, name=f"resolve {host}", daemon=True)
    worker.start()
    worker.join(timeout)
    if worker.is_alive():
        raise _Unreachable(f"could not resolve the host {host} within {timeout:g} s (offline, or no DNS?)")
    if "error" in outcome:
        raise _Unreachable(f"cannot resolve the host {host} ({_describe(outcome['error'])}; offline?)")


def _describe(reason: object) -> str:
    if isinstance(reason, socket.gaierror):
        return f"name lookup failed: {reason.strerror or reason}"
    if isinstance(reason, ConnectionRefusedError):
        return "connection refused"
    if isinstance(reason, TimeoutError):
        return "timed out"
    text = str(reason) or type(reason).__name__
    return text


def _range_first(content_range: str) -> int | None:
    m = re.match(r"\s*bytes\s+(\d+)-\d+/(\d+|\*)", content_range)
    return int(m.group(1)) if m else None


def _range_total(content_range: str) -> int | None:
    m = re.match(r"\s*bytes\s+(?:\*|\d+-\d+)/(\d+)", content_range)
    return int(m.group(1)) if m else None


# --- small helpers -----------------------------------------------------------------------------------------------

def _remote(name: str) -> Remote:
    key = name.strip().lower()
    if key not in REMOTES:
        raise FetchError(f"unknown dataset {name!r}; known datasets: {', '.join(sorted(REMOTES))}")
    return REMOTES[key]


def _check_md5(path: Path, remote: Remote, problem: str, moved: str, advice: str, *, help_text: str, url: str,
               dest: Path, progress: bool) -> None:
    """Raise :class:`FetchError` (``problem``, both checksums, where the file was moved, ``advice``)
    unless ``path`` has the remote's md5; a bad file is moved aside first (:func:`_quarantine`)."""
    got = file_md5(path, progress=progress)
    if got != remote.md5.lower():
        bad = _quarantine(path)
        raise FetchError(f"{problem}: md5 expected {remote.md5}, got {got}. {moved.format(bad=bad)} (not trusted; "
                         f"delete it). {advice}\n" + help_text, url=url, dest=dest)


def _quarantine(path: Path) -> Path:
    bad = path.with_name(path.name.removesuffix(".part") + ".bad")
    os.replace(path, bad)
    return bad


def _size(path: Path) -> str:
    n = path.stat().st_size if path.exists() else 0
    return f"{n} bytes" if n < 1 << 20 else f"{n / (1 << 20):.1f} MiB"


def _manual_help(name: str, remote: Remote, url: str, dest: Path) -> str:
    folder = _unpacked_root(dest, remote)
    return (f"To put the files in place by hand (destination {dest}):\n"
            f"  1. open {remote.homepage} in a browser and download {remote.filename} (md5 {remote.md5}; direct link "
            f"{url});\n"
            f"  2. save it as {dest / remote.filename} and re-run `jaxstyle data fetch {name} --dest {dest}` "
            f"(or jaxstyle.data.fetch.fetch({name!r}, {str(dest)!r})): it verifies and unpacks it without a network;\n"
            f"  or unpack it yourself and point JAXSTYLE_MOCAP (or --data) at the unpacked folder ({folder}).")


class _NoBar:
    def __enter__(self) -> _NoBar:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def update(self, n: int) -> None:
        return None


def _bar(progress: bool, total: int | None, initial: int, desc: str, unit: str = "B"):
    """A tqdm progress bar (bytes, resumed from ``initial``), or a do-nothing stand-in."""
    if not progress:
        return _NoBar()
    from tqdm import tqdm

    if unit == "B":
        return tqdm(total=total, initial=initial, unit="B", unit_scale=True, unit_divisor=1024, desc=desc,
                    leave=not desc.startswith("md5"), dynamic_ncols=True)
    return tqdm(total=total, initial=initial, unit=unit, desc=desc, leave=False, dynamic_ncols=True)
