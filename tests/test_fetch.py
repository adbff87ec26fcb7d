"""jaxstyle.data.fetch against a local HTTP server in a thread: download, resume, checksums, unpacking, offline errors.

No internet: the archives are tiny zips made here, served from memory, and the 100STYLE entry of REMOTES is
patched with their md5.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import re
import shutil
import socket
import tarfile
import threading
import time
import zipfile
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from jaxstyle.data import fetch as F
from jaxstyle.errors import JaxstyleError

BVH = "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n}\nMOTION\nFrames: 1\nFrame Time: 0.0166667\n" + "0.0 " * 5000 + "\n"


def make_zip(members: dict[str, str]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        for name, text in members.items():
            zf.writestr(zipfile.ZipInfo(name), text)
    return buf.getvalue()


DATASET = {
    "100STYLE/Neutral/Neutral_FW.bvh": BVH,
    "100STYLE/Frame_Cuts.csv": "STYLE_NAME,FW_START,FW_STOP\nNeutral,0,1\n",
    "100STYLE/Dataset_List.csv": "Style Name,Symmetric\nNeutral,Yes\n",
}
ZIP = make_zip(DATASET)
MD5 = hashlib.md5(ZIP).hexdigest()


class Server:
    """Serves ``data`` at any path (``/redirect/<path>`` answers 302 to ``/<path>``); supports Range; can cut the
    first file response after ``cut_after`` bytes (after a ``stall`` with the connection open), ignore Range, or
    answer with an HTTP error. ``log`` holds (path, Range header) per request."""

    def __init__(self, data: bytes):
        self.data = data
        self.log: list[tuple[str, str | None]] = []
        self.cut_after: int | None = None
        self.ignore_range = False
        self.error: int | None = None
        self.served = 0  # file responses (not redirects or errors) so far
        self.stall = 0.0  # seconds the first response pauses after cut_after bytes, connection open
        state = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):
                pass

            def do_GET(self):
                rng = self.headers.get("Range")
                state.log.append((self.path, rng))
                if state.error:
                    self.send_error(state.error)
                    return
                if self.path.startswith("/redirect/"):
                    self.send_response(302)
                    self.send_header("Location", self.path[len("/redirect"):])
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                data, start, status = state.data, 0, 200
                if rng and not state.ignore_range:
                    start = int(re.fullmatch(r"bytes=(\d+)-", rng).group(1))
                    if start >= len(data):
                        self.send_response(416)
                        self.send_header("Content-Range", f"bytes */{len(data)}")
                        self.send_header("Content-Length", "0")
                        self.end_headers()
                        return
                    status = 206
                body = data[start:]
                self.send_response(status)
                self.send_header("Content-Type", "application/octet-stream")
                self.send_header("Content-Length", str(len(body)))
                if status == 206:
                    self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
                self.end_headers()
                state.served += 1
                if state.cut_after is not None and state.served == 1:
                    self.wfile.write(body[:state.cut_after])
                    self.wfile.flush()
                    time.sleep(state.stall)
                    self.close_connection = True
                    return
                self.wfile.write(body)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/files/100STYLE.zip?download=1"
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True)
        self.thread.start()

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture(autouse=True)
def no_proxy(monkeypatch):
    for var in ("http_proxy", "https_proxy", "all_proxy", "HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY"):
        monkeypatch.delenv(var, raising=False)


@pytest.fixture
def server():
    s = Server(ZIP)
    yield s
    s.close()


def use_md5(monkeypatch, md5: str) -> F.Remote:
    """The real 100STYLE entry with the md5 of the test archive."""
    remote = dataclasses.replace(F.REMOTES["100style"], md5=md5, size=None)
    monkeypatch.setitem(F.REMOTES, "100style", remote)
    return remote


def closed_port_url() -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"http://127.0.0.1:{port}/100STYLE.zip"


def check_unpacked(root: Path, dest: Path):
    assert root == dest / "100STYLE"
    for name, text in DATASET.items():
        assert (dest / name).read_text() == text
    assert (dest / "100STYLE.zip").read_bytes() == ZIP
    assert not (dest / "100STYLE.zip.part").exists()


def test_remote_entry():
    r = F.REMOTES["100style"]
    assert r.md5 == "3cf627852fd8192024c04a8d0ef49583"
    assert r.filename == "100STYLE.zip" and "8127870" in r.url and r.url.split("?")[0].endswith("/100STYLE.zip")
    assert "CC BY 4.0" in r.licence and "Mason" in r.citation and r.homepage.endswith("8127870")
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.md5 = "x"


def test_full_download_verify_unpack(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    root = F.fetch("100style", tmp_path / "d", url=server.url, progress=True)
    check_unpacked(root, tmp_path / "d")
    assert server.log == [("/files/100STYLE.zip?download=1", None)]
    assert F.verify_md5(tmp_path / "d" / "100STYLE.zip", MD5.upper())
    assert not F.verify_md5(tmp_path / "d" / "100STYLE.zip", "0" * 32)
    assert F.missing_files(root, "100style") == []


def test_command_line_fetch_downloads_and_says_where(server, monkeypatch, tmp_path, capsys):
    """``jaxstyle data fetch 100style --dest D --url U`` (the command line over :func:`fetch`)."""
    from jaxstyle import cli

    use_md5(monkeypatch, MD5)
    assert cli.main(["data", "fetch", "100style", "--dest", str(tmp_path / "d"), "--url", server.url,
                     "--quiet"]) == 0
    out = capsys.readouterr().out
    root = tmp_path / "d" / "100STYLE"
    check_unpacked(root, tmp_path / "d")
    assert f"--data {root}" in out


def test_interrupted_download_resumes_on_rerun(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    server.cut_after = 7000
    with pytest.raises(F.FetchError, match="re-run to resume"):
        F.fetch("100style", tmp_path, url=server.url, progress=False, resume_attempts=0)
    part = tmp_path / "100STYLE.zip.part"
    assert part.read_bytes() == ZIP[:7000] and not (tmp_path / "100STYLE.zip").exists()
    root = F.fetch("100style", tmp_path, url=server.url, progress=False)
    assert [r for _, r in server.log] == [None, "bytes=7000-"]
    check_unpacked(root, tmp_path)


def test_interrupted_download_resumes_within_one_call(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    server.cut_after = 5000
    root = F.fetch("100style", tmp_path, url=server.url, progress=True)
    assert [r for _, r in server.log] == [None, "bytes=5000-"]
    check_unpacked(root, tmp_path)


def test_resume_through_redirect(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    server.cut_after = 4000
    url = server.url.replace("/files/", "/redirect/files/")
    root = F.fetch("100style", tmp_path, url=url, progress=False)
    assert [r for _, r in server.log] == [None, None, "bytes=4000-", "bytes=4000-"]  # Range kept across the 302
    check_unpacked(root, tmp_path)


def test_stalled_transfer_times_out_and_resumes(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    server.cut_after, server.stall = 6000, 1.5
    t0 = time.perf_counter()
    root = F.fetch("100style", tmp_path, url=server.url, timeout=0.3, progress=False)
    assert time.perf_counter() - t0 < 1.2
    assert [r for _, r in server.log] == [None, "bytes=6000-"]
    check_unpacked(root, tmp_path)


def test_server_ignoring_range_restarts(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    server.ignore_range = True
    (tmp_path / "100STYLE.zip.part").write_bytes(ZIP[:3000])
    root = F.fetch("100style", tmp_path, url=server.url, progress=False)
    assert [r for _, r in server.log] == ["bytes=3000-"]  # asked to resume, got the whole file (200)
    check_unpacked(root, tmp_path)


def test_complete_part_answered_416(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    (tmp_path / "100STYLE.zip.part").write_bytes(ZIP)
    root = F.fetch("100style", tmp_path, url=server.url, progress=False)
    assert [r for _, r in server.log] == [f"bytes={len(ZIP)}-"]
    check_unpacked(root, tmp_path)


def test_part_longer_than_the_file_restarts(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    (tmp_path / "100STYLE.zip.part").write_bytes(ZIP + b"junk")
    root = F.fetch("100style", tmp_path, url=server.url, progress=False)
    assert [r for _, r in server.log] == [f"bytes={len(ZIP) + 4}-", None]  # 416 with a smaller total, then all
    check_unpacked(root, tmp_path)


def test_wrong_checksum(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, "0123456789abcdef0123456789abcdef")
    with pytest.raises(F.FetchError) as e:
        F.fetch("100style", tmp_path, url=server.url, progress=False)
    msg = str(e.value)
    assert "0123456789abcdef0123456789abcdef" in msg and MD5 in msg and "Re-run" in msg
    assert not (tmp_path / "100STYLE.zip").exists() and not (tmp_path / "100STYLE.zip.part").exists()
    assert (tmp_path / "100STYLE.zip.bad").read_bytes() == ZIP
    assert not (tmp_path / "100STYLE").exists()


def test_bad_archive_placed_by_hand(monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    (tmp_path / "100STYLE.zip").write_bytes(b"<html>not a zip</html>")
    with pytest.raises(F.FetchError, match="expected " + MD5):
        F.fetch("100style", tmp_path, url=closed_port_url(), progress=False)
    assert not (tmp_path / "100STYLE.zip").exists() and (tmp_path / "100STYLE.zip.bad").exists()


def test_already_downloaded_makes_no_request(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    F.fetch("100style", tmp_path, url=server.url, progress=False)
    server.log.clear()
    assert F.fetch("100style", tmp_path, url=server.url, progress=False) == tmp_path / "100STYLE"
    # Offline too, and the unpacked folder comes back when deleted.
    shutil.rmtree(tmp_path / "100STYLE")
    root = F.fetch("100style", tmp_path, url=closed_port_url(), progress=False)
    check_unpacked(root, tmp_path)
    assert F.fetch("100style", tmp_path, url=server.url, unpack=False, progress=False) == tmp_path / "100STYLE.zip"
    assert server.log == []
    # The archive deleted after unpacking: still nothing to download.
    (tmp_path / "100STYLE.zip").unlink()
    assert F.fetch("100style", tmp_path, url=closed_port_url(), progress=False) == tmp_path / "100STYLE"


def test_archive_placed_by_hand_is_verified_and_unpacked_offline(monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    (tmp_path / "100STYLE.zip").write_bytes(ZIP)
    check_unpacked(F.fetch("100style", tmp_path, url=closed_port_url(), progress=False), tmp_path)


def assert_offline_error(url: str, dest: Path, **kwargs):
    t0 = time.perf_counter()
    with pytest.raises(F.FetchError) as e:
        F.fetch("100style", dest, url=url, progress=False, **kwargs)
    elapsed = time.perf_counter() - t0
    assert elapsed < 3.0, elapsed
    msg = str(e.value)
    assert url in msg and str(dest / "100STYLE.zip") in msg and "by hand" in msg
    assert "https://zenodo.org/records/8127870" in msg and "JAXSTYLE_MOCAP" in msg and "re-run" in msg
    assert isinstance(e.value, JaxstyleError) and isinstance(e.value, RuntimeError) and e.value.url == url
    assert not (dest / "100STYLE.zip").exists()
    return msg


def test_offline_connection_refused(tmp_path):
    msg = assert_offline_error(closed_port_url(), tmp_path)
    assert "refused" in msg


def test_offline_unresolvable_host(tmp_path):
    assert_offline_error("http://nonexistent.invalid/x.zip", tmp_path, timeout=2.0)


def test_offline_hanging_name_lookup_is_bounded(monkeypatch, tmp_path):
    def slow(*args, **kwargs):
        time.sleep(3)
        raise socket.gaierror(-2, "Name or service not known")

    monkeypatch.setattr(F.socket, "getaddrinfo", slow)
    msg = assert_offline_error("http://slow-dns.invalid/x.zip", tmp_path, timeout=0.3)
    assert "within 0.3 s" in msg


def test_http_error(server, monkeypatch, tmp_path):
    use_md5(monkeypatch, MD5)
    server.error = 404
    with pytest.raises(F.FetchError, match="HTTP 404") as e:
        F.fetch("100style", tmp_path, url=server.url, progress=False)
    assert "by hand" in str(e.value)


@pytest.mark.parametrize("bad", ["../evil.txt", "100STYLE/../../evil.txt", "/tmp/evil-abs.txt"])
def test_zip_member_outside_dest_is_refused(server, monkeypatch, tmp_path, bad):
    data = make_zip({"100STYLE/Frame_Cuts.csv": "x", bad: "evil"})
    server.data = data
    use_md5(monkeypatch, hashlib.md5(data).hexdigest())
    dest = tmp_path / "d"
    with pytest.raises(F.FetchError, match="refusing to unpack"):
        F.fetch("100style", dest, url=server.url, progress=False)
    assert not (tmp_path / "evil.txt").exists() and not (dest / "100STYLE").exists()


def test_tar_archive(tmp_path):
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        for name, text in DATASET.items():
            info = tarfile.TarInfo(name)
            info.size = len(text.encode())
            tf.addfile(info, io.BytesIO(text.encode()))
    (tmp_path / "a.tar.gz").write_bytes(buf.getvalue())
    F.unpack_archive(tmp_path / "a.tar.gz", tmp_path / "out")
    assert (tmp_path / "out" / "100STYLE" / "Neutral" / "Neutral_FW.bvh").read_text() == BVH

    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tf:
        info = tarfile.TarInfo("../evil.txt")
        info.size = 4
        tf.addfile(info, io.BytesIO(b"evil"))
    (tmp_path / "bad.tar").write_bytes(buf.getvalue())
    with pytest.raises(F.FetchError, match="refusing"):
        F.unpack_archive(tmp_path / "bad.tar", tmp_path / "out2")
    assert not (tmp_path / "evil.txt").exists()


def test_missing_csvs_warn(server, monkeypatch, tmp_path):
    data = make_zip({"100STYLE/Neutral/Neutral_FW.bvh": BVH})
    server.data = data
    use_md5(monkeypatch, hashlib.md5(data).hexdigest())
    with pytest.warns(F.FetchWarning, match="Frame_Cuts.csv, Dataset_List.csv are missing.*local-phases"):
        root = F.fetch("100style", tmp_path, url=server.url, progress=False)
    assert root == tmp_path / "100STYLE" and F.missing_files(root, "100style") == ["Frame_Cuts.csv",
                                                                                      "Dataset_List.csv"]


def test_data_folder_found_when_nested_differently(server, monkeypatch, tmp_path):
    data = make_zip({"release/100STYLE_v1/" + k.split("/", 1)[1]: v for k, v in DATASET.items()})
    server.data = data
    use_md5(monkeypatch, hashlib.md5(data).hexdigest())
    root = F.fetch("100style", tmp_path, url=server.url, progress=False)
    assert root == tmp_path / "release" / "100STYLE_v1" and (root / "Frame_Cuts.csv").is_file()


def test_unknown_name(tmp_path):
    with pytest.raises(F.FetchError, match="unknown dataset 'cmu'.*100style"):
        F.fetch("cmu", tmp_path)
