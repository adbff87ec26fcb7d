"""The package's structure: the layer contracts (import-linter: the packages, and the modules inside
``cli``, ``output``, ``play`` and ``control``) hold and catch an upward import, the import graph has no
cycle, and ``import jaxstyle`` stays light while every public name resolves."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT = shutil.which("lint-imports", path=os.pathsep.join([str(Path(sys.executable).parent), os.environ["PATH"]]))


def _lint(tree: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(tree))
    return subprocess.run([LINT, "--config", str(tree / "pyproject.toml"), "--no-cache"], cwd=tree, env=env,
                          capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def tree_copy(tmp_path_factory) -> Path:
    dst = tmp_path_factory.mktemp("tree")
    shutil.copytree(ROOT / "jaxstyle", dst / "jaxstyle", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", dst / "pyproject.toml")
    return dst


def test_layers_contract_is_kept(tree_copy):
    assert LINT, "lint-imports (import-linter) is a test dependency"
    result = _lint(tree_copy)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "5 kept, 0 broken" in result.stdout


@pytest.mark.parametrize("module, upward", [
    ("motion/clip.py", "from jaxstyle.output import metrics"),
    ("nn/pfnn.py", "from jaxstyle.control import controller"),
    ("mason2022/train.py", "from jaxstyle.mason2018 import fewshot"),
    ("cli/play.py", "from jaxstyle.cli.main import build_parser"),
    ("output/quality.py", "from jaxstyle.output import synthesis"),
    ("output/quality.py", "from jaxstyle.output import report"),
    ("play/models.py", "from jaxstyle.play import session"),
    ("play/learn_panel.py", "from jaxstyle.play import server"),
    ("control/controller.py", "from jaxstyle.control import model"),
])
def test_an_upward_import_breaks_the_contract(tree_copy, tmp_path, module, upward):
    tree = tmp_path / "t"
    shutil.copytree(tree_copy, tree)
    path = tree / "jaxstyle" / module
    path.write_text(path.read_text() + f"\n{upward}  # noqa\n")
    result = _lint(tree)
    assert result.returncode != 0
    assert "BROKEN" in result.stdout


def _cycles(imports: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]
    for root in sorted(imports):
        if root in index:
            continue
        work = [(root, iter(sorted(imports[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(imports.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_cycle_finder_finds_a_planted_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set(), "c": {"a", "b"}}) == []


def test_the_import_graph_has_no_cycle():
    """No module imports, directly or through others (imports inside functions included), a module
    that imports it back (grimp's graph, the one import-linter checks)."""
    import grimp

    graph = grimp.build_graph("jaxstyle")
    imports = {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    assert _cycles(imports) == []


def test_import_jaxstyle_loads_no_jax_or_plotting_and_every_public_name_resolves():
    code = ("import sys, jaxstyle as js\n"
            "heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'matplotlib', 'PIL', 'optax', "
            "'orbax', 'scipy', 'flax'))\n"
            "print('heavy', heavy)\n"
            "missing = [n for n in js.__all__ if getattr(js, n, None) is None]\n"
            "print('missing', missing)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert "heavy []" in out.stdout
    assert "missing []" in out.stdout


def test_unknown_attribute_is_an_attribute_error():
    import jaxstyle

    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        jaxstyle.nonexistent  # noqa: B018
    with pytest.raises(AttributeError):
        jaxstyle.motion.nonexistent  # noqa: B018
