"""The live server's trust boundary: only the page's own origin connects (and with a token only
with it), the page names files and run folders only under the allowed roots and learns nothing
about others, uploads are capped and removed when refused, and reading a large file does not stop
the render loop."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from jaxstyle.play import guard
from jaxstyle.play.guard import Serving
from jaxstyle.play.learn_panel import Learning
from jaxstyle.play.models import PlayError
from jaxstyle.play.server import PlayServer
from tests.test_play import other_skeleton_bvh, tiny_model
from tests.test_play_browser import wait_for


def test_admission_accepts_only_the_pages_own_origin():
    local = guard.Admission("127.0.0.1", 8080)
    ok = {"Host": "127.0.0.1:8080", "Origin": "http://127.0.0.1:8080"}
    assert local.refusal(ok, "/") is None
    assert local.refusal({"Host": "localhost:8080", "Origin": "http://localhost:8080"}, "/") is None
    refused = {
        "foreign origin": {"Host": "127.0.0.1:8080", "Origin": "http://evil.example.com"},
        "another port": {"Host": "127.0.0.1:8080", "Origin": "http://127.0.0.1:9999"},
        "DNS rebinding": {"Host": "evil.example.com:8080", "Origin": "http://evil.example.com:8080"},
        "no origin": {"Host": "127.0.0.1:8080"},
        "no host": {"Origin": "http://127.0.0.1:8080"},
        "file page": {"Host": "127.0.0.1:8080", "Origin": "null"},
    }
    for what, headers in refused.items():
        assert local.refusal(headers, "/") is not None, what
    every = guard.Admission("0.0.0.0", 8080)
    assert every.refusal({"Host": "10.0.0.5:8080", "Origin": "http://10.0.0.5:8080"}, "/") is None
    assert every.refusal({"Host": "10.0.0.5:8080", "Origin": "http://evil.example.com"}, "/") is not None
    assert every.refusal({"Host": "10.0.0.5:9999", "Origin": "http://10.0.0.5:9999"}, "/") is not None
    token = guard.Admission("0.0.0.0", 8080, token="s3cret-token")
    same = {"Host": "10.0.0.5:8080", "Origin": "http://10.0.0.5:8080"}
    assert token.refusal(same, "/s3cret-token") is None
    for path in ("/", "/s3cret", "/s3cret-token-2", "/other"):
        assert "token" in token.refusal(same, path)
    assert token.page_url("10.0.0.5") == "http://10.0.0.5:8080/?websocket=ws://10.0.0.5:8080/s3cret-token"


def test_confine_refuses_alike_whether_or_not_the_path_exists(tmp_path):
    root = tmp_path / "run"
    (root / "clips").mkdir(parents=True)
    inside = root / "clips" / "a.bvh"
    inside.write_text("x")
    secret = tmp_path / "secret.txt"
    secret.write_text("SECRET")
    (root / "link.bvh").symlink_to(secret)
    assert guard.confine(str(inside), [root]) == inside.resolve()
    assert guard.confine(str(root / "clips" / ".." / "clips" / "missing.bvh"), [root]).name == "missing.bvh"
    messages = []
    for path in (secret, tmp_path / "missing.txt", root / ".." / "secret.txt", root / "link.bvh", "/dev/zero"):
        with pytest.raises(PlayError) as e:
            guard.confine(str(path), [root])
        messages.append(str(e.value).replace(str(path), "PATH"))
    assert len(set(messages)) == 1 and "SECRET" not in messages[0], messages
    assert guard.without_content("a.bvh, line 2: unexpected token 'SECRET=1' in \"x y\"") == \
        "a.bvh, line 2: unexpected token '…' in '…'"


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.one_of(st.text(max_size=40), st.lists(st.sampled_from(["..", ".", "run", "clips", "a.bvh", "~",
                                                                      "~nobody", "\x00", "/", "link.bvh"]),
                                                       max_size=8).map("/".join)))
def test_confine_fuzzed(tmp_path, text):
    """Whatever the page sends: a path under the root, or the one refusal (that names no more than
    the text sent), never another exception."""
    root = tmp_path / "run"
    root.mkdir(exist_ok=True)
    if not (root / "link.bvh").is_symlink():
        (root / "link.bvh").symlink_to(tmp_path / "secret.txt")
    try:
        got = guard.confine(text, [root])
    except PlayError as e:
        assert str(e) in (f"the page may only name a file under {root.resolve()}; {text.strip()} is not read",
                          "give the path of a file")
        return
    assert got == root.resolve() or root.resolve() in got.parents


@settings(max_examples=300, deadline=None)
@given(host=st.one_of(st.text(max_size=30), st.sampled_from(["127.0.0.1:8080", "localhost:8080", "LOCALHOST:8080",
                                                               "127.0.0.1", "evil.example.com:8080", "[::1]:8080"])),
       origin=st.one_of(st.text(max_size=40), st.builds(
           "{}{}{}{}".format, st.sampled_from(["http://", "https://", "ws://", "", "file://"]),
           st.sampled_from(["127.0.0.1", "localhost", "evil.example.com", "user@127.0.0.1", "[::1]"]),
           st.sampled_from([":8080", "", ":80", ":9999"]), st.sampled_from(["", "/", "/x", "?a=1", "#f"]))))
def test_admission_fuzzed(host, origin):
    """Random Host and Origin headers: admitted only when both are the page's own address."""
    local = guard.Admission("127.0.0.1", 8080)
    allowed = {"127.0.0.1:8080", "localhost:8080", "[::1]:8080"}
    admitted = local.refusal({"Host": host, "Origin": origin}, "/") is None
    if admitted:
        assert host.strip().lower() in allowed
        assert origin.strip().lower().split("://", 1)[-1].rstrip("/") in allowed, (host, origin)


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    folder = tmp_path_factory.mktemp("guarded") / "run"
    folder.mkdir()
    logged = []
    server = PlayServer(folder, Serving(port=0), Learning(epochs=1, rates=(0.3,), max_upload_bytes=100_000),
                        log=logged.append)
    server.start(model=tiny_model(folder))
    server.logged = logged
    wait_for(lambda: server.session.frames > 10, 30, "the render loop")
    yield server
    server.stop()


def _viser_protocol() -> str:
    import viser

    return f"viser-v{viser.__version__}"


def _stays_open(url: str, origin: str | None, seconds: float = 1.0) -> bool:
    """Whether a websocket client with ``origin`` stays connected for ``seconds`` (receiving what
    the server sends)."""
    headers = {} if origin is None else {"Origin": origin}
    try:
        with connect(url, additional_headers=headers, subprotocols=[_viser_protocol()], open_timeout=10) as ws:
            t0 = time.monotonic()
            while time.monotonic() - t0 < seconds:
                try:
                    ws.recv(timeout=0.2)
                except TimeoutError:
                    pass
            return True
    except (ConnectionClosed, InvalidStatus):
        return False


def test_a_foreign_origin_is_refused_and_logged(live):
    url = f"ws://127.0.0.1:{live.port}"
    assert _stays_open(url, f"http://127.0.0.1:{live.port}")  # the page's own origin
    assert not _stays_open(url, "http://evil.example.com")
    assert not _stays_open(url, None)
    assert any("refused a connection: foreign origin 'http://evil.example.com'" in line for line in live.logged)


def test_a_token_server_admits_only_its_url(tmp_path):
    server = PlayServer(tmp_path, Serving(port=0, token="a-token-123"))
    server.start(load=False, loop=False)
    try:
        assert server.url == f"http://127.0.0.1:{server.port}/?websocket=ws://127.0.0.1:{server.port}/a-token-123"
        origin = f"http://127.0.0.1:{server.port}"
        assert _stays_open(f"ws://127.0.0.1:{server.port}/a-token-123", origin)
        assert not _stays_open(f"ws://127.0.0.1:{server.port}", origin)
        assert not _stays_open(f"ws://127.0.0.1:{server.port}/wrong-token", origin)
    finally:
        server.stop()


def test_an_unknown_host_fails_at_once(tmp_path):
    t0 = time.monotonic()
    with pytest.raises(PlayError, match=r"--host 999\.1\.1\.1: not an address"):
        PlayServer(tmp_path, Serving(host="999.1.1.1", port=0)).start(load=False, loop=False)
    assert time.monotonic() - t0 < 10


def test_paths_outside_the_run_folder_are_refused_without_a_hint(live, tmp_path):
    messages = []
    for path in ("/root/.ssh/id_rsa", "/nonexistent/file.bvh", str(tmp_path), "/etc/passwd",
                 str(live.run_dir / ".." / "outside.bvh")):
        with pytest.raises(PlayError) as e:
            live.learn(path)
        messages.append(str(e.value).replace(path, "PATH"))
    assert len(set(messages)) == 1, messages
    # the page's "Run folder": beside the run folder only
    live._gui["run"].value = "/etc"
    live._guarded_load()
    assert "may only name a run folder under" in live.message and live.run_dir.name == "run"
    assert live.learner.state == "idle"


def test_uploads_are_capped_written_fresh_and_removed_when_refused(live, tmp_path):
    uploads = live.run_dir / "play" / "uploads"

    def files():
        return sorted(p for p in uploads.rglob("*") if p.is_file()) if uploads.exists() else []

    live._guarded(live._on_upload, reads_files=True)(SimpleNamespace(name="big.bvh", content=b"x" * 100_001))
    assert "big.bvh: the upload is 0.1 MB, more than the 0.1 MB allowed" in live.message and files() == []
    robot = other_skeleton_bvh(tmp_path / "Robot.bvh").read_bytes()
    live._guarded(live._on_upload, reads_files=True)(SimpleNamespace(name="../../Robot.bvh", content=robot))
    wait_for(lambda: "another skeleton" in live.message, 30, "the refusal")
    wait_for(lambda: files() == [], 5, "the refused upload to be removed")
    assert not (live.run_dir.parent / "Robot.bvh").exists() and live.learner.state == "idle"


def test_reading_a_large_file_does_not_stop_the_render_loop(live):
    # a 40,000-joint chain (3.5 MB, a few seconds to parse on this CPU) offered while the characters walk
    from tests.test_bvh_robust import _chain_bvh

    big = live.run_dir / "huge.bvh"
    big.write_text(_chain_bvh(40_000))
    live.session.walk_to(0.0, 5.0)
    t0 = time.monotonic()
    worker = live.learn(str(big))
    assert time.monotonic() - t0 < 0.2  # the request returns at once
    worker.join(60)
    assert "another skeleton (40000 joints" in live.message
    times = np.array([t for t in live.frame_times if t >= t0])
    assert len(times) > 20
    gaps = np.diff(np.concatenate([[t0], times]))
    print(f"{len(times)} frames, the longest gap {gaps.max():.3f} s")
    assert gaps.max() < 0.2, f"the longest gap between frames was {gaps.max():.3f} s"
