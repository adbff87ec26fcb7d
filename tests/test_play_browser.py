"""``jaxstyle play`` in a real browser: headless Chromium (the Debian package, driven by Python
playwright through its executable path) loads the page, steers by a click on the ground and by a
key, switches the style from the dropdown, and sends bad input; the test checks the server's
state and the page's text, and that a screenshot is not blank.

Skips (with the reason) only when /usr/bin/chromium is missing and JAXSTYLE_REQUIRE_BROWSER is
unset; CI installs Chromium (.ci/run), so there it runs."""

from __future__ import annotations

import io
import os
import socket
import time
from pathlib import Path

import numpy as np
import pytest

from jaxstyle.play.guard import Serving
from jaxstyle.play.learn_panel import Learning
from jaxstyle.play.server import PlayServer
from tests.test_play import other_skeleton_bvh, tiny_model

CHROMIUM = Path(os.environ.get("JAXSTYLE_CHROMIUM", "/usr/bin/chromium"))
ARGS = ["--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic"]


def _chromium_or_skip() -> Path:
    if CHROMIUM.is_file():
        return CHROMIUM
    reason = f"no browser at {CHROMIUM} (apt-get install chromium; .ci/run does)"
    if os.environ.get("JAXSTYLE_REQUIRE_BROWSER") == "1":
        pytest.fail(reason + "; JAXSTYLE_REQUIRE_BROWSER=1 makes this an error")
    pytest.skip(reason)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# How long to wait for something the page or the server's render loop must do (render, report its
# camera, show a text, advance frames); every wait is on a condition, none is a fixed sleep. The
# page draws its WebGL in software (SwiftShader; no GPU): on the 2-core machine with the other
# test process busy it renders at about 4 frames/s at 1280x720 (measured with requestAnimationFrame
# while a training job ran), and a page that slow once needed over 10 s to show a new status line.
PAGE_SECONDS = 30.0
# The page's own report of its camera comes after it has drawn the change, which under load can take
# tens of seconds, so that one wait allows twice as long. It still fails when the page never
# reports, or reports the wrong view.
REPORT_SECONDS = 2 * PAGE_SECONDS


def wait_for(condition, timeout: float, what: str, poll: float = 0.1, detail=None):
    """The first truthy value of ``condition()`` within ``timeout`` seconds; else an
    AssertionError naming ``what`` (and ``detail()``, what was seen, when given)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        value = condition()
        if value:
            return value
        time.sleep(poll)
    seen = f"; {detail()}" if detail is not None else ""
    raise AssertionError(f"timed out after {timeout:g} s waiting for {what}{seen}")


@pytest.fixture(scope="module")
def browser():
    executable = _chromium_or_skip()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(executable), args=ARGS)
        yield b
        b.close()


def open_page(browser, server: PlayServer):
    # 960x540: SwiftShader's cost grows with the pixels (640x360 rendered twice as fast as 1280x720)
    page = browser.new_page(viewport={"width": 960, "height": 540})
    page.goto(server.url)
    page.wait_for_selector("canvas", timeout=60_000)
    wait_for(lambda: server._server.get_clients(), PAGE_SECONDS, "the page to connect")
    return page


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    folder = tmp_path_factory.mktemp("play_browser")
    server = PlayServer(folder, Serving(port=free_port()), Learning(epochs=1, rates=(0.3,)))
    server.start(model=tiny_model(folder))
    yield server
    server.stop()


def text_field(page, label: str):
    """The text input of a viser GUI row by its label (viser's label ``for`` does not name the
    text input's id, so ``get_by_label`` cannot find it)."""
    return page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::p/parent::div"
                        "/following-sibling::div//input").first


def not_blank(png: bytes) -> float:
    from PIL import Image

    pixels = np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=np.float64)
    return float(pixels.std())


def test_steer_switch_style_and_screenshot(browser, served, tmp_path):
    server = served
    page = open_page(browser, server)
    reported = []  # the views the page itself reports (not the server's copy of what it was sent)
    # every connection's reports: under load the page may miss websocket pings and reconnect as a
    # new client (viser replays this registration for the clients already connected)
    server._server.on_client_connect(lambda client: client.camera.on_update(
        lambda cam: reported.append((np.asarray(cam.position), np.asarray(cam.look_at)))))
    # the character is drawn: the render loop runs and its scene nodes exist
    frames = server.session.frames
    wait_for(lambda: server.session.frames > frames + 30 and server._nodes, PAGE_SECONDS, "the character")
    wait_for(lambda: "Controller step" in page.inner_text("body"), PAGE_SECONDS, "the status line")
    # a click on the middle of the 3-D view: a ray through the camera's look-at point meets the
    # floor a little beyond the character; the server walks the character there
    box = page.locator("canvas").first.bounding_box()
    server.session.stop()
    wait_for(lambda: server.session.characters[0].stand > 0.999, PAGE_SECONDS, "the character to stand")

    asked = [0.0, 0]

    def page_views_character():
        here = server.session.origin()[0]
        if reported and np.hypot(*(reported[-1][1][[0, 2]] - here)) < 0.05:
            return reported[-1]
        if time.monotonic() - asked[0] > 2.0:
            # ask the page for its view: viser's page reports its camera at once when told its field
            # of view (a page that renders slowly, under load, may otherwise report only when moved).
            # viser sends nothing when the value is unchanged, so the request alternates the field of
            # view by 0.001 rad (the ray through the middle of the view, used below, does not depend on it)
            asked[0], asked[1] = time.monotonic(), asked[1] + 1
            for client in server._server.get_clients().values():
                client.camera.fov = fov0 + 1e-3 * (asked[1] % 2)
        return None

    # the camera follows: the page's own report puts its look-at point on the standing character
    # (a regression test: the follow once set look_at before position, and viser's position
    # setter moves look_at along, so the page looked at the wrong place)
    clients = server._server.get_clients
    fov0 = next(iter(clients().values())).camera.fov
    position, look_at = wait_for(page_views_character, REPORT_SECONDS, "the page's camera to follow the character",
                                 detail=lambda: f"{len(reported)} camera reports, the last {reported[-1:]}, the "
                                                f"character at {server.session.origin()[0]}, the server's copy of the "
                                                f"pages' cameras {[c.camera.look_at for c in clients().values()]}")
    ray = look_at - position
    floor = (position + ray * (-position[1] / ray[1]))[[0, 2]]  # where the middle of the view meets y = 0
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    targets = wait_for(lambda: server.session.targets()[0], PAGE_SECONDS, "the click to set a target")
    target = np.asarray(targets[0])
    assert np.linalg.norm(target - floor) < 0.05, (target, floor)  # the click's ray met the floor there
    with server.lock:
        start = server.session.origin()[0]
        wanted = np.asarray(server.session.controls().offsets[0, -1])  # where the network is told to go
    assert 0.5 < np.linalg.norm(target - start) < 10.0, (start, target)
    toward = (target - start) / np.linalg.norm(target - start)
    assert wanted @ toward > 0.999 * np.linalg.norm(wanted), (wanted, toward)
    wait_for(lambda: np.linalg.norm(target - server.session.origin()[0]) < np.linalg.norm(target - start) - 0.1,
             PAGE_SECONDS, "the character to walk 0.1 m towards the target",
             detail=lambda: f"start {start}, now {server.session.origin()[0]}, target {target}")
    # a key: D walks to the camera's right
    page.keyboard.press("d")
    steering = wait_for(lambda: server.session.characters[0].steering.mode == "direction"
                        and server.session.characters[0].steering, PAGE_SECONDS, "the key to steer")
    assert abs(np.cos(steering.heading - (server.camera_yaw() - np.pi / 2)) - 1) < 1e-6
    # the style dropdown
    before = server.session.characters[0].style
    other = next(name for name in server.session.styles if name != before)
    page.get_by_label("Style", exact=True).click()
    page.get_by_role("option", name=other, exact=True).click()
    wait_for(lambda: server.session.characters[0].style == other, PAGE_SECONDS, "the style switch")
    wait_for(lambda: f"Style: {other}" in page.inner_text("body"), PAGE_SECONDS, "the page to show it",
             detail=lambda: f"the page shows {page.inner_text('body')[:300]!r}")
    # a screenshot that shows something, once the page has drawn the switched style for a few frames
    frames = server.session.frames
    wait_for(lambda: server.session.frames > frames + 10, PAGE_SECONDS, "the render loop to go on")
    png = page.screenshot(path=str(tmp_path / "play.png"))
    canvas = page.locator("canvas").first.screenshot()
    assert not_blank(png) > 5.0 and not_blank(canvas) > 2.0
    page.close()


def test_bad_input_shows_a_message_in_the_page(browser, served, tmp_path):
    server = served
    page = open_page(browser, server)
    # a BVH of another skeleton, by path (in the run folder, where the page may name files)
    text_field(page, "BVH path").fill(str(other_skeleton_bvh(server.run_dir / "robot.bvh")))
    page.get_by_text("Learn the style of this file").click()
    page.get_by_text("another skeleton", exact=False).first.wait_for(timeout=1000 * PAGE_SECONDS)
    # a path outside the run folder: refused before it is looked at
    text_field(page, "BVH path").fill(str(other_skeleton_bvh(tmp_path / "robot.bvh")))
    page.get_by_text("Learn the style of this file").click()
    page.get_by_text(f"{tmp_path / 'robot.bvh'} is not read", exact=False).first.wait_for(
        timeout=1000 * PAGE_SECONDS)
    # a file that is not BVH, uploaded: refused without quoting it, and removed
    notes = tmp_path / "notes.bvh"
    notes.write_text("HIERARCHY\nSECRET_TOKEN=1234 just some notes\nMOTION\n")
    page.set_input_files("input[type=file]", str(notes))
    wait_for(lambda: "notes.bvh" in server.message, PAGE_SECONDS, "the upload to be refused")
    assert "SECRET" not in server.message and "unexpected token" in server.message
    reason = server.message.rsplit(": ", 1)[-1]  # after "<file>, line N: "
    page.get_by_text(reason, exact=False).first.wait_for(timeout=1000 * PAGE_SECONDS)
    assert "SECRET" not in page.inner_text("body")
    assert not [p for p in (server.run_dir / "play" / "uploads").rglob("*") if p.is_file()]
    # a run folder with no model (beside the run folder: the page may load those)
    empty = server.run_dir.parent / "empty_run"
    empty.mkdir()
    text_field(page, "Run folder").fill(str(empty))
    page.get_by_role("button", name="Load this run folder", exact=True).click()
    page.get_by_text("no base model", exact=False).first.wait_for(timeout=1000 * PAGE_SECONDS)
    # the server is alive and still plays the model it had
    frames = server.session.frames
    wait_for(lambda: server.session.frames > frames + 10, PAGE_SECONDS, "the render loop to go on")
    assert server.learner.state == "idle"
    page.close()


@pytest.mark.slow
def test_learn_a_style_live_and_record(browser, tmp_path):
    """A trained tiny base in a run folder: learn a style from an uploaded clip while the
    character walks, pick it from the dropdown, record BVH + GIF."""
    from jaxstyle.data import procedural
    from jaxstyle.mason2018 import base_model

    root = procedural.write_dataset(tmp_path / "run" / "data", ["Neutral", "Crouched", "Proud"], ["FW"], seconds=10)
    base_model.train_base(base_model.BaseSettings(data=str(root), styles=("Neutral", "Crouched"), hidden=32, rank=4,
                                              epochs=2), tmp_path / "run" / "base", progress=False, log=lambda _: None)
    server = PlayServer(tmp_path / "run", Serving(port=free_port()), Learning(epochs=2)).start()
    try:
        page = open_page(browser, server)
        frames = server.session.frames
        page.set_input_files("input[type=file]", str(root / "Proud" / "Proud_FW.bvh"))
        wait_for(lambda: server.learner.state == "running", PAGE_SECONDS, "learning to start")
        wait_for(lambda: server.learner.state != "running", 600, "learning to finish", poll=1.0)
        assert server.learner.state == "done", server.learner.message
        assert server.session.frames > frames + 60  # the character walked on meanwhile
        assert "Proud_FW" in server.session.styles and server.session.styles["Proud_FW"].kind == "learned"
        page.get_by_text("learned Proud_FW", exact=False).first.wait_for(timeout=1000 * PAGE_SECONDS)
        page.get_by_label("Style", exact=True).click()
        page.get_by_role("option", name="Proud_FW", exact=True).click()
        wait_for(lambda: server.session.characters[0].style == "Proud_FW", PAGE_SECONDS, "the learned style to play")
        frames = server.session.frames
        wait_for(lambda: server.session.frames > frames + 90, PAGE_SECONDS, "1.5 s of the learned style to record")
        page.get_by_text("Save the last seconds").click()
        wait_for(lambda: server.last_recording, 120, "the recording")
        assert {f.suffix for f in server.last_recording} == {".bvh", ".npz", ".gif"}
        page.close()
    finally:
        server.stop()
