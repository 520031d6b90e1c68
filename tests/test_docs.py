"""The documentation: every public name listed in the API reference, every Python snippet of
the README and of the pages runs as written, and the site builds without a warning (the
gallery's scripts run in ``tests/test_examples.py``)."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("stcgym.envs", "stcgym.adaptive", "stcgym.agents")
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SNIPPET = re.compile(r"```python\n(.*?)```", re.S)


def _public_names() -> list[tuple[str, str, object]]:
    out = []
    for package in PACKAGES:
        module = importlib.import_module(package)
        for name in module.__all__:
            out.append((package, name, getattr(module, name)))
    return out


def test_the_api_page_lists_every_public_name():
    page = (ROOT / "docs" / "api.md").read_text()
    listed = set(re.findall(r"^   (\w+)$", page, re.M))
    absent = [f"{p}.{n}" for p, n, _ in _public_names() if n not in listed]
    assert not absent, f"docs/api.md does not list {absent}"


def _snippets() -> list[tuple[str, str]]:
    out = []
    for page in PAGES:
        text = page.read_text()
        for match in SNIPPET.finditer(text):
            line = text[: match.start()].count("\n") + 1
            out.append((f"{page.relative_to(ROOT)}:{line}", match.group(1)))
    return out


@pytest.mark.parametrize(("where", "code"), _snippets(), ids=[w for w, _ in _snippets()])
def test_every_python_snippet_runs_as_written(where, code, tmp_path):
    if "stcgym.agents" in code and importlib.util.find_spec("stable_baselines3") is None:
        pytest.skip("needs the rl extra")
    script = tmp_path / "snippet.py"
    script.write_text(code)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    done = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, f"{where} failed:\n{done.stderr[-3000:]}"


def test_the_site_builds_without_warnings(tmp_path):
    pytest.importorskip("sphinx")
    pytest.importorskip("sphinx_gallery")
    done = subprocess.run(
        [
            sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
            "-D", "plot_gallery=0", "-d", str(tmp_path / "doctrees"),
            str(ROOT / "docs"), str(tmp_path / "html"),
        ],
        cwd=ROOT / "docs", capture_output=True, text=True, timeout=900,
        env={**os.environ, "MPLBACKEND": "Agg"},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-5000:]
