"""The ``jaxstyle`` command line: every subcommand run on tiny data, config files, and one-line errors.

The tiny data is the procedural generator's (3 styles x 2 gaits x 10 s); the networks are a few
units wide and train for one epoch, so these check the plumbing (files written, settings
recorded, resuming), not the quality, which the library's own tests cover.
"""

from __future__ import annotations

import csv
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jaxstyle as js
from jaxstyle import cli
from jaxstyle.data import clips
from jaxstyle.train import defaults

# the tiny few-shot clips hold fewer rows than a cycle's worth for validation; selection says so
pytestmark = pytest.mark.filterwarnings("ignore:style .* the last 1 cycle:UserWarning")

TINY_NET = ["--hidden", "16", "--rank", "2", "--base-epochs", "1"]
TINY_SWEEP = ["--seconds", "3", "--sweep-epochs", "1", "--rates", "0.3", "0.5"]


def run_cli(*argv) -> int:
    return cli.main([str(a) for a in argv])


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("data") / "procedural"
    assert run_cli("data", "generate", "--out", out, "--styles", "Neutral", "Crouched", "Limping", "--seconds", 10,
                   "--quiet") == 0
    return out


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory, tiny_data) -> Path:
    """The demo end to end on the tiny data (base Neutral + Crouched, few-shot Limping). A one-epoch base
    of 16 units fails the closed-loop check at every rate, so its sets are used with --allow-failed."""
    run = tmp_path_factory.mktemp("runs") / "demo"
    rc = run_cli("demo", "--data", tiny_data, "--run", run, *TINY_NET, *TINY_SWEEP, "--synth-seconds", 1, "--quiet",
                 "--allow-failed")
    assert rc == 0
    return run


def test_data_generate_writes_the_100style_layout(tiny_data):
    specs = clips.specs_100style(tiny_data)
    assert {s.style for s in specs} == {"Neutral", "Crouched", "Limping"}
    assert {s.gait for s in specs} == {"FW", "FR"}
    # Limping is asymmetric: not mirrored; the others are
    assert not any(s.mirror for s in specs if s.style == "Limping")
    assert any(s.mirror for s in specs if s.style == "Neutral")
    m = js.read_bvh(tiny_data / "Neutral" / "Neutral_FW.bvh")
    assert m.num_frames == 600 and m.fps == 60.0


def test_demo_leaves_gif_bvh_and_sweep_report(demo_run, capsys):
    syn, sweep = demo_run / "synthesis", demo_run / "sweep"
    gif = syn / "circle.gif"
    assert gif.is_file() and gif.read_bytes()[:6] == b"GIF89a"
    bvhs = sorted((syn / "bvh").glob("*.bvh"))
    # Neutral and Crouched (base) and the few-shot Limping walk
    assert [b.stem for b in bvhs] == ["Crouched_circle", "Limping_FW_circle", "Neutral_circle"]
    m = js.read_bvh(bvhs[0])
    assert m.num_frames == 60 and np.isfinite(m.rotations).all()
    with open(sweep / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {(r["style"], float(r["rate"])) for r in rows} == {(s, r) for s in ("Limping_FR", "Limping_FW")
                                                              for r in (0.3, 0.5)}
    assert all(np.isfinite(float(r["validation_loss"])) for r in rows)
    assert (sweep / "heatmap.png").is_file()
    config = json.loads((demo_run / "config.json").read_text())
    assert config["demo"]["hidden"] == 16 and config["demo"]["rates"] == [0.3, 0.5]
    log = (demo_run / "log.txt").read_text()
    assert "demo finished" in log and str(gif) in log
    base = json.loads((demo_run / "base" / "base.json").read_text())
    assert base["styles"] == ["Crouched", "Neutral"] and base["hidden"] == 16


def test_demo_again_reuses_the_base_and_refuses_other_settings(demo_run, tiny_data, capsys):
    # same settings: the trained base is loaded (no epoch bar, same result); other settings: refused
    rc = run_cli("demo", "--data", tiny_data, "--run", demo_run, "--hidden", 32, "--rank", 2, "--base-epochs", 1,
                 *TINY_SWEEP, "--synth-seconds", 1, "--quiet")
    err = capsys.readouterr().err
    assert rc == 1 and "hidden differ" in err and err.count("\n") == 1


def test_train_base_then_sweep_and_synthesize(demo_run, tiny_data, tmp_path, capsys):
    run = tmp_path / "run"
    assert run_cli("train-base", "--data", tiny_data, "--run", run, "--styles", "Neutral", "--fewshot-styles",
                   "Limping", "--gaits", "FW", *TINY_NET, "--quiet") == 0
    saved = json.loads((run / "base" / "base.json").read_text())
    assert saved["styles"] == ["Neutral"] and saved["gaits"] == ["FW"]
    assert (run / "base" / "log.csv").is_file()
    # the sweep's default sets: the styles the base was not trained on, with the base's gaits
    assert run_cli("sweep", "--run", run, *TINY_SWEEP, "--quiet") == 0
    chosen = json.loads((run / "sweep" / "chosen_rates.json").read_text())
    assert sorted(chosen) == ["Crouched_FW", "Limping_FW"]
    assert all(c["rate"] in (0.3, 0.5) for c in chosen.values())
    assert run_cli("synthesize", "--run", run, "--paths", "straight", "zigzag", "--synth-seconds", 1, "--blend",
                   "--sets", "Crouched_FW", "Limping_FW", "--quiet", "--allow-failed") == 0
    out = run / "synthesis"
    assert (out / "straight.gif").is_file() and (out / "zigzag.gif").is_file()
    names = sorted(p.stem for p in (out / "bvh").glob("*.bvh"))
    assert len(names) == 8 and "blend_Crouched_FW50_Limping_FW50_zigzag" in names
    with open(out / "quality.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    # 8 characters x paths, then one real clip each of Neutral, Crouched and Limping
    assert len(rows) == 8 + 3 and "foot_skating_locked_m_s" in rows[0] and rows[0]["foot_lock"] == "True"
    # a user clip as a new style
    clip = tiny_data / "Limping" / "Limping_FR.bvh"
    assert run_cli("sweep", "--run", run, "--clip", clip, "--clip-range", 0, 5, "--asymmetric", *TINY_SWEEP,
                   "--quiet") == 0
    # added to the earlier sets, not replacing them
    assert list(json.loads((run / "sweep" / "chosen_rates.json").read_text())) == [
        "Crouched_FW", "Limping_FW", "Limping_FR"]
    capsys.readouterr()
    assert run_cli("sweep", "--run", run, "--sets", "Nope", "--quiet") == 1
    assert "unknown few-shot style(s) Nope" in capsys.readouterr().err


def test_demo_keeps_large_folders_small():
    many = [f"S{i:02d}" for i in range(20)]
    assert cli.demo_base_styles(many[:8]) == many[:8]
    assert cli.demo_base_styles(many) == many[:8]
    assert cli.demo_base_styles(many + ["Neutral", "Angry"]) == ["Angry", "Neutral"]


def test_data_prepare_summarises_and_caches(tiny_data, tmp_path, capsys):
    run = tmp_path / "run"
    assert run_cli("data", "prepare", "--data", tiny_data, "--run", run, "--styles", "Neutral", "Limping",
                   "--gaits", "FW", "--lpn", "--quiet") == 0
    out = capsys.readouterr().out
    assert "| Neutral | 2 |" in out and "| Limping | 1 |" in out  # Neutral mirrored, Limping not
    assert "LPN rows" in out
    assert len(list((run / "cache").glob("pfnn-*.npz"))) == 1 and len(list((run / "cache").glob("lpn-*.npz"))) == 1


def test_own_style_folder_without_csv_files(tiny_data, tmp_path, capsys):
    """<root>/<Style>/<Style>_<GAIT>.bvh without Frame_Cuts.csv: whole files, every gait found,
    mirrored unless Dataset_List.csv says the style is not symmetric."""
    import shutil

    root = tmp_path / "mine"
    for style, gait, name in (("Neutral", "FW", "walk"), ("Neutral", "FR", "run"), ("Limping", "FW", "walk")):
        (root / style).mkdir(parents=True, exist_ok=True)
        shutil.copy(tiny_data / style / f"{style}_{gait}.bvh", root / style / f"{style}_{name}.bvh")
    run = tmp_path / "run"
    assert run_cli("data", "prepare", "--data", root, "--run", run, "--quiet") == 0
    out = capsys.readouterr().out
    assert "| Neutral | 4 |" in out and "| Limping | 2 |" in out  # everything mirrored
    (root / "Dataset_List.csv").write_text("Style Name,Description,Stochastic,Symmetric,Notes\n"
                                           "Limping,a limp,No,No,\nNeutral,plain,No,Yes,\n")
    assert run_cli("data", "prepare", "--data", root, "--run", run, "--gaits", "walk", "--quiet") == 0
    out = capsys.readouterr().out
    assert "| Neutral | 2 |" in out and "| Limping | 1 |" in out


def test_lpn_trains_tests_and_finetunes(tiny_data, tmp_path, capsys):
    run = tmp_path / "run"
    tiny = ("--data", tiny_data, "--styles", "Neutral", "Crouched", "--new-styles", "Limping", "--gaits", "FW",
            "--hidden", 8, "--generator-hidden", 16, "--filters", 4, "--quiet")
    assert run_cli("lpn", *tiny, "--epochs", 2, "--run", run, "--finetune-steps", 2, "--rates", 0.1, 0.5) == 0
    out = capsys.readouterr().out
    assert "| Neutral |" in out and "| Limping |" in out
    results = (run / "lpn" / "results.md").read_text()
    # the epoch of the two whose training styles step best (the rule: test_synthesis_lpn.py), said and recorded
    record = json.loads((run / "lpn" / "chosen_epoch.json").read_text())
    assert record["trained_epochs"] == 2 and record["epoch"] in (1, 2)
    assert set(record["lifted_step_ratio"]) == {"1", "2"}
    said = f"epoch chosen by the closed loop: {record['epoch']} of 2 ("
    assert results.startswith(said) and said in out
    table = [line.split(" | ")[0] for line in results.splitlines()[2:6]]
    assert table == ["| epoch", "|---|---|---|---|---|---|", "| 1", "| 2"]
    assert "| new style | test MSE before | after @ 0.1 | after @ 0.5 | chosen rate |" in results
    assert "(chosen)" in results and (run / "lpn" / "figure11.png").is_file()
    chosen = json.loads((run / "lpn" / "chosen_rates.json").read_text())
    assert list(chosen) == ["Limping"] and chosen["Limping"]["rate"] in (0.1, 0.5)
    # each rate walked (the rule: test_synthesis_lpn.py), its figures written and shown
    assert set(chosen["Limping"]["lifted_step_ratio"]) == {"0.1", "0.5"}
    assert "| new style | lifted steps / capture's @ 0.1 | lifted steps / capture's @ 0.5 |" in results
    assert "then every pair walked 8 s along a straight line (" in out
    # the closing check: every style walked, said and written (its rows: test_synthesis_lpn.py)
    check = results[results.index("closed loop of every style: 8 s along a straight line"):].splitlines()
    assert [line.split(" | ")[0].split(" ")[1] for line in check[4:7]] == ["Crouched", "Neutral", "Limping"]
    assert check[-1].startswith(("not stepping (lifted steps under 0.5", "every style steps")) and check[-1] in out
    with np.load(run / "lpn" / "finetuned_generators.npz") as z:  # (new styles, rates)
        assert all(z[k].shape[:2] == (1, 2) for k in z.files)
    # --choose-epoch 0 on the trained folder: the last epoch, and the record goes (synthesize follows it)
    assert run_cli("lpn", *tiny, "--epochs", 2, "--run", run, "--finetune-steps", 0, "--no-style-check",
                   "--choose-epoch", 0) == 0
    assert "epoch chosen" not in capsys.readouterr().out and not (run / "lpn" / "chosen_epoch.json").exists()
    # --seed: recorded, and another seed trains another model (its first epoch's losses differ)
    def first_epoch(folder):
        return (folder / "lpn" / "log.csv").read_text().splitlines()[1].split(",")[1:6]  # losses, not seconds

    run2 = tmp_path / "run2"
    assert run_cli("lpn", *tiny, "--epochs", 1, "--run", run2, "--finetune-steps", 0, "--seed", 1,
                   "--no-style-check") == 0
    out2 = capsys.readouterr().out
    assert "closed loop of every style" not in out2 and "epoch chosen" not in out2  # one epoch: nothing to choose
    assert not (run2 / "lpn" / "chosen_epoch.json").exists()
    assert json.loads((run2 / "lpn" / "config.json").read_text())["train"]["seed"] == 1
    assert all(a != b for a, b in zip(first_epoch(run), first_epoch(run2), strict=True))


@pytest.mark.slow
def test_demo_lpn_film_chooses_the_epoch(tiny_data, tmp_path, capsys):
    """``jaxstyle demo --model lpn-film --choose-epoch 2`` with tiny sizes: the epoch of the last two
    that steps best is chosen, said, recorded and driven (the synthesis line names it), and the new
    style's rates are walked; ``--choose-epoch 0 --choose-rate validation`` on the same folder drive
    the last epoch, remove the record and walk no rate."""
    run = tmp_path / "run"
    tiny = ("demo", "--model", "lpn-film", "--data", tiny_data, "--run", run, "--styles", "Neutral", "Crouched",
            "--fewshot-styles", "Limping", "--gaits", "FW", "--hidden", 8, "--generator-hidden", 16, "--filters", 4,
            "--lpn-epochs", 2, "--finetune-steps", 2, "--synth-seconds", 1, "--no-quality", "--quiet")
    assert run_cli(*tiny, "--choose-epoch", 2) == 0
    out = capsys.readouterr().out
    assert "then every pair walked 8 s along a straight line" in out
    assert set(json.loads((run / "lpn" / "chosen_rates.json").read_text())["Limping"]["lifted_step_ratio"]) == {
        "0.1", "0.3"}
    record = json.loads((run / "lpn" / "chosen_epoch.json").read_text())
    assert record["trained_epochs"] == 2 and set(record["lifted_step_ratio"]) == {"1", "2"}
    assert f"epoch chosen by the closed loop: {record['epoch']} of 2 (" in out
    driven = "epoch 1 of 2" if record["epoch"] == 1 else "2 epochs"
    assert f"synthesis with LPN FiLM ({driven}, " in out
    assert run_cli(*tiny, "--choose-epoch", 0, "--choose-rate", "validation") == 0
    out = capsys.readouterr().out
    assert "epoch chosen" not in out and "synthesis with LPN FiLM (2 epochs, " in out
    assert not (run / "lpn" / "chosen_epoch.json").exists() and "walked" not in out
    assert "lifted_step_ratio" not in json.loads((run / "lpn" / "chosen_rates.json").read_text())["Limping"]


def test_render_bvh_files(tiny_data, tmp_path, capsys):
    files = [tiny_data / "Neutral" / "Neutral_FW.bvh", tiny_data / "Crouched" / "Crouched_FW.bvh"]
    out = tmp_path / "two.gif"
    assert run_cli("render", *files, "--out", out, "--seconds", 1, "--every", 3, "--quiet") == 0
    assert out.read_bytes()[:6] == b"GIF89a"
    capsys.readouterr()
    assert run_cli("render", files[0], "--out", tmp_path / "x.png") == 1
    assert "must end in .gif or .mp4" in capsys.readouterr().err
    assert run_cli("render", tmp_path / "missing.bvh", "--out", out) == 1
    assert "missing.bvh: no such file" in capsys.readouterr().err


def test_bench_prints_side_by_side_figures(tmp_path, capsys):
    run = tmp_path / "run"
    assert run_cli("bench", "--run", run, "--sets", 2, "--rates", 0.3, "--frames", 64, "--sweep-epochs", 1,
                   "--hidden", 16) == 0
    out = capsys.readouterr().out
    assert "one jit(vmap) sweep" in out and "loop of single runs" in out and "batch 1024" in out
    figures = json.loads((run / "bench.json").read_text())
    assert figures["sweep"] > 0 and figures["loop"] > 0


def _closed_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_data_fetch_offline_fails_with_instructions(tmp_path, capsys):
    url = f"http://127.0.0.1:{_closed_port()}/100STYLE.zip"
    assert run_cli("data", "fetch", "100style", "--dest", tmp_path, "--url", url, "--timeout", 2) == 1
    err = capsys.readouterr().err
    assert url in err and "by hand" in err and "Traceback" not in err
    assert run_cli("data", "fetch", "nope", "--dest", tmp_path) == 1
    assert "100style" in capsys.readouterr().err


def test_config_file_sets_defaults_and_flags_win(tiny_data, tmp_path, capsys):
    config = tmp_path / "settings.toml"
    config.write_text('quiet = true\n[render]\nseconds = 0.5\nevery = 4\nout = "from_config.gif"\n')
    out = tmp_path / "flag.gif"
    assert run_cli("render", tiny_data / "Neutral" / "Neutral_FW.bvh", "--config", config, "--out", out) == 0
    assert out.is_file() and not Path("from_config.gif").exists()
    config.write_text("[render]\nsecnds = 1\n")
    capsys.readouterr()
    assert run_cli("render", tiny_data / "Neutral" / "Neutral_FW.bvh", "--config", config) == 1
    err = capsys.readouterr().err
    assert "unknown setting 'secnds'" in err and "seconds" in err


@pytest.mark.parametrize("command", [[], ["demo"], ["data"], ["data", "generate"], ["data", "fetch"],
                                     ["data", "prepare"], ["train-base"], ["sweep"], ["lpn"], ["synthesize"],
                                     ["render"], ["bench"]])
def test_help_everywhere(command, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(command + ["--help"])
    assert e.value.code == 0
    assert "usage: jaxstyle" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["demo", "--bogus"], "unrecognized arguments: --bogus"),
    (["demo", "--base-epochs", "x"], "invalid int value"),
    (["train-base"], "the following arguments are required: --data"),
    (["train-base", "--data", "/nonexistent/folder", "--run", "{tmp}/r"], "data folder /nonexistent/folder not found"),
    (["train-base", "--data", "{tmp}", "--run", "{tmp}/r"], "holds no style folders"),
    (["synthesize", "--run", "{tmp}/empty"], "no base model in"),
    (["render", "{tmp}/none.bvh"], "none.bvh: no such file"),
    (["demo", "--run", "{tmp}/r", "--seconds", "-1"], "--seconds must be positive"),
    (["lpn", "--data", "{tmp}", "--run", "{tmp}/r", "--finetune-steps", "-1"], "--finetune-steps must be >= 0"),
    (["lpn", "--data", "{tmp}", "--run", "{tmp}/r", "--choose-epoch", "-1"], "--choose-epoch must be >= 0"),
    (["demo", "--model", "lpn-film", "--run", "{tmp}/r", "--choose-epoch", "-1"], "--choose-epoch must be >= 0"),
])
def test_bad_arguments_give_one_line_errors(argv, message, tmp_path, capsys):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    try:
        rc = cli.main(argv)
    except SystemExit as e:  # argparse's own errors
        rc = e.code
    assert rc != 0
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert message in err and "Traceback" not in err


def test_console_script_errors_in_a_fresh_process(tmp_path):
    """As a user runs it (the module behind the console script, in a new process): one line on
    stderr, no traceback, a non-zero status."""
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    for argv, message in ((["sweep", "--rates"], "expected at least one argument"),
                          (["render", str(tmp_path / "none.bvh")], "none.bvh: no such file")):
        proc = subprocess.run([sys.executable, "-m", "jaxstyle.cli", *argv], capture_output=True, text=True, env=env,
                              timeout=120)
        assert proc.returncode != 0
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], proc.stderr


def test_bad_style_names_give_one_line_errors(tiny_data, tmp_path, capsys):
    assert run_cli("train-base", "--data", tiny_data, "--run", tmp_path / "r", "--styles", "Neutrall") == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown base style(s) Neutrall" in err and "Crouched, Limping, Neutral" in err


@pytest.mark.usefixtures("mocap")
def test_demo_on_real_data(mocap, tmp_path):
    """``jaxstyle demo --data ../shared/mocap`` with tiny settings: the same pipeline on 100STYLE."""
    run = tmp_path / "run"
    assert run_cli("demo", "--data", mocap, "--run", run, "--styles", "Neutral", "Angry", "--fewshot-styles",
                   "Rushed", "--gaits", "FW", "--max-seconds", 6, *TINY_NET, *TINY_SWEEP, "--synth-seconds", 1,
                   "--quiet", "--allow-failed") == 0
    assert (run / "synthesis" / "circle.gif").is_file()
    assert sorted(p.stem for p in (run / "synthesis" / "bvh").glob("*.bvh")) == ["Neutral_circle",
                                                                                   "Rushed_FW_circle"]
    assert json.loads((run / "sweep" / "chosen_rates.json").read_text()).keys() == {"Rushed_FW"}


def test_a_run_folder_copied_elsewhere_works_from_another_directory(tmp_path, monkeypatch, capsys):
    """A run whose data lies inside it (as the demo's does), made with paths relative to the working
    directory, then copied and used from another directory: the base finds its data, the sweep
    adds a set, synthesis reads the earlier and the new sets."""
    import shutil

    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert run_cli("data", "generate", "--out", "runs/a/data", "--styles", "Neutral", "Limping", "Crouched",
                   "--gaits", "FW", "--seconds", 6, "--quiet") == 0
    assert run_cli("train-base", "--data", "runs/a/data", "--run", "runs/a", "--styles", "Neutral", *TINY_NET,
                   "--quiet") == 0
    assert json.loads(Path("runs/a/base/base.json").read_text())["data"] == "../data"
    assert run_cli("sweep", "--run", "runs/a", "--sets", "Limping", *TINY_SWEEP, "--quiet") == 0
    assert all(not Path(s["path"]).is_absolute() for s in
               json.loads(Path("runs/a/sweep/sweep.json").read_text())["specs"])
    shutil.copytree("runs/a", tmp_path / "moved")
    shutil.rmtree("runs")  # the original is gone
    monkeypatch.chdir(tmp_path)
    assert run_cli("sweep", "--run", "moved", "--sets", "Crouched", *TINY_SWEEP, "--quiet") == 0
    assert sorted(json.loads((tmp_path / "moved/sweep/chosen_rates.json").read_text())) == [
        "Crouched_FW", "Limping_FW"]
    assert run_cli("synthesize", "--run", "moved", "--paths", "straight", "--synth-seconds", 1, "--sets",
                   "Limping_FW", "Crouched_FW", "--quiet", "--allow-failed") == 0
    assert (tmp_path / "moved/synthesis/straight.gif").is_file()


def test_compilation_cache_is_written_to_its_folder_and_can_be_turned_off(tmp_path):
    """``use_xla_cache`` (every ``jaxstyle`` command) stores compiled programs in
    ``$JAXSTYLE_XLA_CACHE``; ``off`` disables it. In fresh processes: JAX's cache is process-wide."""
    script = ("import jax, jax.numpy as jnp\n"
              "from jaxstyle.cli.common import use_xla_cache\n"
              "print(use_xla_cache())\n"
              "print(float(jax.jit(lambda x: jnp.sin(x) * 3)(jnp.float32(1))))\n")
    cache = tmp_path / "xla"
    for value, want in ((str(cache), str(cache)), ("off", "None")):
        env = {**os.environ, "JAXSTYLE_XLA_CACHE": value}
        out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        assert out.stdout.split()[0] == want
    entries = [p for p in cache.rglob("*") if p.is_file()]
    assert entries, "no compiled program was cached"
    assert not (tmp_path / "off").exists()


def test_compilation_cache_folder_defaults_to_the_user_cache(monkeypatch, tmp_path):
    from jaxstyle.cli.common import xla_cache_dir

    monkeypatch.delenv("JAXSTYLE_XLA_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert xla_cache_dir() == tmp_path / "jaxstyle" / "xla"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert xla_cache_dir() == Path.home() / ".cache" / "jaxstyle" / "xla"
    for off in ("off", "0", "", "No"):
        monkeypatch.setenv("JAXSTYLE_XLA_CACHE", off)
        assert xla_cache_dir() is None


def test_a_set_that_failed_every_check_is_refused_unless_allowed(demo_run, tmp_path, capsys):
    """A sweep whose every rate fails the closed-loop check (thresholds no rollout can meet: mean bone
    error <= -1) marks the set in chosen_rates.json with what failed; `jaxstyle synthesize` then
    refuses it with one line naming the set and the figure, and uses it, marked, with --allow-failed."""
    import shutil

    from jaxstyle.mason2018 import base_model, fewshot, pipeline, selection, sweep_files
    from jaxstyle.train import scan

    run = tmp_path / "run"
    shutil.copytree(demo_run, run)
    base = base_model.load_base(run / "base", cache=run / "cache", progress=False)
    _, shots = pipeline.load_sweep(run / "sweep", base, cache=run / "cache")
    config = fewshot.SweepConfig(model=base.model, rates=(0.3, 0.5), epochs=1)
    impossible = defaults.RolloutCheck(max_bone_error=-1.0)
    result = selection.fewshot_sweep(base.params, base.normalisers, shots, base.skeleton, config,
                                     selection.FewshotOptions(check=impossible, run=scan.GridRun(chunk_steps=100)))
    assert not result.chosen_passed.any()
    (name,) = [s for s in result.styles if s.startswith("Limping")][:1]
    assert result.failed(name) and result.failed(name)[0].startswith("bone error ")
    sweep_files.write_report(result, run / "sweep", config)
    saved = json.loads((run / "sweep" / "chosen_rates.json").read_text())[name]
    assert saved["passed_check"] is False and saved["failed"] == result.failed(name)
    capsys.readouterr()
    assert run_cli("synthesize", "--run", run, "--paths", "straight", "--synth-seconds", 1, "--sets", name,
                   "--quiet") == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and name in err and "failed the closed-loop check at every rate" in err
    assert "bone error " in err and "--allow-failed" in err
    assert run_cli("synthesize", "--run", run, "--paths", "straight", "--synth-seconds", 1, "--sets", name,
                   "--allow-failed", "--quiet") == 0
    with open(run / "synthesis" / "quality.csv", newline="") as f:
        styles = {r["style"] for r in csv.DictReader(f)}
    assert any(name in s and "[FAILED CHECK]" in s for s in styles)
