"""Bad input to every ``jaxstyle`` subcommand: one line on stderr naming the flag, setting or path
at fault, a non-zero exit status, no traceback (``--debug`` aside).

Every case fails before any data is read or any network trained, so the table is cheap. The
placeholders in the arguments: ``{tmp}`` the test's folder, ``{file}`` a regular file there,
``{dir}`` an empty folder, ``{styles}`` a folder of two (empty) style folders, ``{ro}`` a read-only
folder, ``{cfg}`` the ``settings.toml`` written from the case's TOML text (``{bin}``: a binary one).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from jaxstyle import cli
from jaxstyle.cli import bench
from jaxstyle.cli.main import build_parser, config_value

ROOT = os.geteuid() == 0 if hasattr(os, "geteuid") else False
AS_ROOT = pytest.mark.skipif(ROOT, reason="running as root, where a read-only folder is still writable; the "
                                          "{file}/sub cases and test_unwritable_folders_even_as_root cover it")


@pytest.fixture
def places(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # default output folders (runs/, data/) land here, never in the checkout
    (tmp_path / "afile").write_text("not a folder\n")
    (tmp_path / "adir").mkdir()
    (tmp_path / "folder.gif").mkdir()
    for style in ("Neutral", "Crouched"):
        (tmp_path / "styles" / style).mkdir(parents=True)
        (tmp_path / "styles" / style / f"{style}_FW.bvh").write_text("")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    (tmp_path / "bin.toml").write_bytes(b"\x00\x01\xff\xfe\x89PNG\r\n")
    (tmp_path / "nul.toml").write_bytes(b"hidden = 1\x00\n")
    yield {"tmp": str(tmp_path), "file": str(tmp_path / "afile"), "dir": str(tmp_path / "adir"),
           "styles": str(tmp_path / "styles"), "ro": str(ro), "bin": str(tmp_path / "bin.toml"),
           "nul": str(tmp_path / "nul.toml"), "cfg": str(tmp_path / "settings.toml")}
    ro.chmod(0o755)


def run_cli(argv, capsys) -> tuple[int, str]:
    """``jaxstyle ARGV`` in this process: its exit status and its stderr."""
    capsys.readouterr()
    try:
        rc = cli.main([str(a) for a in argv])
    except SystemExit as e:  # argparse's own errors
        rc = e.code
    return rc, capsys.readouterr().err


def assert_one_line(rc, err, *names):
    lines = [line for line in err.splitlines() if line.strip()]
    assert rc not in (0, None), err
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    for name in names:
        assert name in lines[0], (name, lines[0])


# (arguments, TOML text of {cfg} or None, what the line must name)
CASES = [
    # demo
    (["demo", "--run", "{file}"], None, ["--run {file}: is a file, not a folder"]),
    (["demo", "--run", "{file}/sub"], None, ["--run {file}/sub", "{file} is a file"]),
    pytest.param(["demo", "--run", "{ro}/r"], None, ["--run {ro}/r", "permission denied"], marks=AS_ROOT),
    (["demo", "--data", "{file}", "--run", "{tmp}/r"], None, ["--data {file}: is a file"]),
    (["demo", "--config", "{dir}"], None, ["--config {dir}: is a folder"]),
    (["demo", "--config", "{tmp}/none.toml"], None, ["--config {tmp}/none.toml: no such file"]),
    (["demo", "--config", "{cfg}", "--run", "{tmp}/r"], "hidden = 64.5",
     ["{cfg}: hidden: expected an integer, got 64.5"]),
    (["demo", "--config", "{cfg}", "--run", "{tmp}/r"], "[demo]\npaths = \"moon\"",
     ["{cfg}: demo.paths: invalid choice \"moon\"", "circle"]),
    (["demo", "--config", "{cfg}", "--run", "{tmp}/r"], "mp4 = 1", ["{cfg}: mp4: expected true or false, got 1"]),
    # data generate / fetch / prepare
    (["data", "generate", "--out", "{file}"], None, ["--out {file}: is a file"]),
    (["data", "generate", "--out", "{file}/x"], None, ["--out {file}/x", "{file} is a file"]),
    pytest.param(["data", "generate", "--out", "{ro}/x"], None, ["--out {ro}/x", "permission denied"], marks=AS_ROOT),
    (["data", "generate", "--config", "{bin}"], None, ["--config {bin}: not a text file"]),
    (["data", "generate", "--config", "{cfg}"], "[data.generate]\nseed = \"x\"",
     ["{cfg}: data.generate.seed: expected an integer, got \"x\""]),
    (["data", "fetch", "100style", "--dest", "{file}"], None, ["--dest {file}: is a file"]),
    (["data", "fetch", "100style", "--dest", "{file}/d"], None, ["--dest {file}/d", "{file} is a file"]),
    (["data", "fetch", "100style", "--config", "{cfg}"], "timeout = \"soon\"",
     ["{cfg}: timeout: expected a number, got \"soon\""]),
    (["data", "prepare", "--data", "{file}", "--run", "{tmp}/r"], None, ["--data {file}: is a file"]),
    (["data", "prepare", "--data", "{dir}", "--run", "{file}"], None, ["--run {file}: is a file"]),
    (["data", "prepare", "--data", "{tmp}/nowhere", "--run", "{tmp}/r"], None, ["{tmp}/nowhere not found"]),
    (["data", "prepare", "--data", "{file}/x", "--run", "{tmp}/r"], None, ["--data {file}/x", "{file} is a file"]),
    # train-base
    (["train-base", "--data", "{styles}", "--run", "{file}/sub"], None, ["--run {file}/sub", "{file} is a file"]),
    (["train-base", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{cfg}"], "hidden = [1, 2]",
     ["{cfg}: hidden: expected an integer, got [1, 2]"]),
    (["train-base", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{cfg}"], "hidden = \"abc\"",
     ["{cfg}: hidden: expected an integer, got \"abc\""]),
    (["train-base", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{cfg}"], "[train-base]\nrank = true",
     ["{cfg}: train-base.rank: expected an integer, got true"]),
    # a string where a list is expected: ONE style (not the letters N, o, p, e)
    (["train-base", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{cfg}"], "styles = \"Nope\"",
     ["unknown base style(s) Nope;", "Crouched, Neutral"]),
    (["train-base", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{cfg}"], "styles = []",
     ["{cfg}: styles: expected at least one value"]),
    (["train-base", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{nul}"], None,
     ["--config {nul}: not a text file"]),
    (["train-base", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{cfg}"], "hidden = ",
     ["--config {cfg}: not valid TOML"]),
    # sweep (its path checks come before its need of a base model)
    (["sweep", "--run", "{tmp}/r", "--clip", "{dir}"], None, ["--clip {dir}: is a folder, not a BVH file"]),
    (["sweep", "--run", "{tmp}/r", "--clip", "{tmp}/none.bvh"], None, ["--clip {tmp}/none.bvh: no such file"]),
    (["sweep", "--run", "{file}"], None, ["--run {file}: is a file"]),
    (["sweep", "--run", "{tmp}/r", "--config", "{cfg}"], "clip-range = [1]",
     ["{cfg}: clip-range: expected a list of 2 numbers, got [1]"]),
    (["sweep", "--run", "{tmp}/r", "--config", "{cfg}"], "[sweep]\nrates = [0.1, \"fast\"]",
     ["{cfg}: sweep.rates[1]: expected a number, got \"fast\""]),
    # lpn
    (["lpn", "--data", "{file}", "--run", "{tmp}/r"], None, ["--data {file}: is a file"]),
    (["lpn", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{cfg}"], "epochs = 1.5",
     ["{cfg}: epochs: expected an integer, got 1.5"]),
    (["lpn", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{cfg}"], "[lpn]\nquiet = \"yes\"",
     ["{cfg}: lpn.quiet: expected true or false, got \"yes\""]),
    (["lpn", "--data", "{styles}", "--run", "{tmp}/r", "--config", "{cfg}"], "data = 3",
     ["{cfg}: data: expected a path, got 3"]),
    # synthesize
    (["synthesize", "--run", "{file}/sub"], None, ["--run {file}/sub", "{file} is a file"]),
    (["synthesize", "--run", "{tmp}/r", "--config", "{cfg}"], "paths = \"moon\"",
     ["{cfg}: paths: invalid choice \"moon\""]),
    (["synthesize", "--run", "{tmp}/r", "--config", "{cfg}"], "[synthesize]\nspeed = {fast = 1}",
     ["{cfg}: synthesize.speed: expected a number"]),
    # render
    (["render", "{dir}"], None, ["{dir}: is a folder, not a BVH file"]),
    (["render", "{tmp}/none.bvh"], None, ["{tmp}/none.bvh: no such file"]),
    (["render", "{file}/x.bvh"], None, ["{file}/x.bvh: no such file", "{file} is a file"]),
    (["render", "{file}", "--out", "{tmp}/folder.gif"], None, ["--out {tmp}/folder.gif: is a folder"]),
    (["render", "{file}", "--out", "{file}/x.gif"], None, ["--out {file}/x.gif", "{file} is a file"]),
    pytest.param(["render", "{file}", "--out", "{ro}/x.gif"], None, ["--out {ro}/x.gif", "permission denied"],
                 marks=AS_ROOT),
    (["render", "{file}", "--config", "{cfg}"], "[render]\nevery = 2.5",
     ["{cfg}: render.every: expected an integer, got 2.5"]),
    (["render", "{file}", "--config", "{dir}"], None, ["--config {dir}: is a folder"]),
    # play (its checks come before it serves anything)
    (["play", "--run", "{file}"], None, ["--run {file}: is a file"]),
    (["play", "--run", "{tmp}/r", "--port", "0"], None, ["--port must be in 1 .. 65535, got 0"]),
    (["play", "--run", "{tmp}/r", "--rates", "1.5"], None, ["--rates must be in [0, 1), got 1.5"]),
    (["play", "--run", "{tmp}/r", "--config", "{cfg}"], "[play]\nport = \"web\"",
     ["{cfg}: play.port: expected an integer, got \"web\""]),
    # bench
    (["bench", "--run", "{file}"], None, ["--run {file}: is a file"]),
    (["bench", "--run", "{file}/sub"], None, ["--run {file}/sub", "{file} is a file"]),
    pytest.param(["bench", "--run", "{ro}"], None, ["--run {ro}", "permission denied"], marks=AS_ROOT),
    (["bench", "--run", "{tmp}/r", "--config", "{bin}"], None, ["--config {bin}: not a text file"]),
    (["bench", "--run", "{tmp}/r", "--config", "{cfg}"], "hidden = 64.5",
     ["{cfg}: hidden: expected an integer, got 64.5"]),
    (["bench", "--run", "{tmp}/r", "--config", "{cfg}"], "[bench]\nhiden = 64", ["{cfg}", "unknown setting 'hiden'"]),
    # argparse's own errors stay one line too
    (["bench", "--hidden", "64.5"], None, ["--hidden", "invalid int value"]),
    (["render"], None, ["files"]),
]


@pytest.mark.parametrize("argv, toml, names", CASES)
def test_bad_input_gives_one_line(argv, toml, names, places, capsys):
    if toml is not None:
        Path(places["cfg"]).write_text(toml + "\n")
    fill = lambda s: s.format(**places)  # noqa: E731
    rc, err = run_cli([fill(a) for a in argv], capsys)
    assert_one_line(rc, err, *(fill(n) for n in names))


def test_every_subcommand_is_in_the_table():
    _, subs = build_parser()
    covered = {" ".join(a for a in (c.values[0] if hasattr(c, "values") else c[0])[:2] if not a.startswith("-")
                        and "{" not in a) for c in CASES}
    assert set(subs) - {"data"} <= covered


def test_a_string_setting_of_a_list_flag_is_one_item():
    _, subs = build_parser()
    actions = {a.dest: a for a in subs["train-base"]._actions}
    assert config_value(actions["styles"], "Neutral", "f: styles") == ["Neutral"]
    assert config_value(actions["styles"], ["Neutral", "Angry"], "f: styles") == ["Neutral", "Angry"]
    assert config_value(actions["hidden"], "64", "f: hidden") == 64
    assert config_value(actions["max_seconds"], 3, "f: max-seconds") == 3.0
    rates = {a.dest: a for a in subs["sweep"]._actions}["rates"]
    assert config_value(rates, 0.3, "f: rates") == [0.3]


def test_an_os_error_names_its_path(places, capsys, monkeypatch):
    def fails(args, run):
        raise PermissionError(13, "Permission denied", "/somewhere/model.npz")

    monkeypatch.setattr(bench, "run", fails)
    rc, err = run_cli(["bench", "--run", Path(places["tmp"]) / "r"], capsys)
    assert_one_line(rc, err, "jaxstyle bench: error: /somewhere/model.npz: permission denied")


def test_an_unexpected_error_is_one_line_unless_debug(places, capsys, monkeypatch):
    def fails(args, run):
        raise ZeroDivisionError("division by zero\nsecond line")

    monkeypatch.setattr(bench, "run", fails)
    rc, err = run_cli(["bench", "--run", Path(places["tmp"]) / "r"], capsys)
    assert_one_line(rc, err, "jaxstyle bench: internal error: ZeroDivisionError: division by zero second line "
                             "(run with --debug for the traceback)")
    with pytest.raises(ZeroDivisionError):
        cli.main(["bench", "--run", str(Path(places["tmp"]) / "r"), "--debug"])


def test_console_path_in_a_fresh_process(tmp_path):
    """``python -m jaxstyle.cli`` as a user runs it: a bad config value, one line, status 1."""
    config = tmp_path / "settings.toml"
    config.write_text("hidden = 64.5\n")
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, "-m", "jaxstyle.cli", "bench", "--run", str(tmp_path / "r"), "--config",
                           str(config)], capture_output=True, text=True, env=env, timeout=120, cwd=tmp_path)
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.strip().splitlines() == [f"jaxstyle bench: error: {config}: hidden: expected an integer, "
                                                "got 64.5"], proc.stderr


@pytest.mark.parametrize("argv, names", [
    (["bench", "--run", "{tmp}/r"], ["--run {tmp}/r: cannot write in the folder: permission denied"]),
    (["render", "{file}", "--out", "{tmp}/out/x.gif"], ["--out {tmp}/out/x.gif: cannot write in the folder {tmp}/out"]),
    (["data", "generate", "--out", "{tmp}/d"], ["--out {tmp}/d: cannot write in the folder: permission denied"]),
])
def test_unwritable_folders_even_as_root(argv, names, places, capsys, monkeypatch):
    """A folder that refuses files (read-only for a user, or a read-only file system even for root),
    simulated where the command probes it."""
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", kwargs.get("dir"))

    monkeypatch.setattr(tempfile, "TemporaryFile", refuse)
    fill = lambda s: s.format(**places)  # noqa: E731
    rc, err = run_cli([fill(a) for a in argv], capsys)
    assert_one_line(rc, err, *(fill(n) for n in names))
