"""The examples gallery (``examples/plot_*.py``) runs, so a broken example fails the suite.

Each script runs in a fresh interpreter (``MPLBACKEND=Agg``, a temporary working directory,
the script's own folder not on the path) exactly as a user would run it, must exit with
status 0 and must leave at least one matplotlib figure open at its end (what sphinx-gallery
puts on the page). The scripts also have to be valid sphinx-gallery scripts: a docstring
whose first line is a title underlined with ``=``, then ``# %%`` cells. The timeout only
guards against a hang; it covers numba compiling the kernels from an empty cache.
"""

from __future__ import annotations

import ast
import importlib.util
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCRIPTS = sorted(EXAMPLES.glob("plot_*.py"))
#: Generous: one example compiles numba kernels for minutes on 2 cores from an empty cache.
TIMEOUT_S = 900
#: Optional packages an example needs beyond stcgym[plot] (the test is skipped without them).
REQUIRES = {
    "plot_06_sweep.py": ("pandas",),
    "plot_07_ppo_vs_self_tuning.py": ("stable_baselines3", "torch"),
    "plot_10_estimate_conditioned_ppo.py": ("stable_baselines3", "torch"),
}

# Runs the script as ``__main__`` and reports how many figures it left open, and what makes
# them hard to read at the page's width (tests/figure_check.py), one line per problem.
_RUNNER = textwrap.dedent(
    """
    import runpy, sys
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    runpy.run_path(sys.argv[1], run_name="__main__")
    print(f"open figures: {len(plt.get_fignums())}")
    sys.path.insert(0, sys.argv[2])
    from figure_check import problems
    for number in plt.get_fignums():
        for problem in problems(plt.figure(number)):
            print(f"unreadable figure {number}: {problem}")
    sys.exit(0 if plt.get_fignums() else 3)
    """
)


def run_example(script: Path, cwd: Path, timeout: float = TIMEOUT_S) -> subprocess.CompletedProcess:
    """Run ``script`` in a fresh interpreter in ``cwd``; the completed process (text output)."""
    env = {**os.environ, "MPLBACKEND": "Agg"}
    return subprocess.run(
        [sys.executable, "-c", _RUNNER, str(script), str(Path(__file__).parent)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _param(script: Path) -> object:
    missing = [m for m in REQUIRES.get(script.name, ()) if importlib.util.find_spec(m) is None]
    marks = pytest.mark.skipif(bool(missing), reason=f"needs {', '.join(missing)}")
    return pytest.param(script, id=script.stem, marks=marks)


def test_the_gallery_has_its_examples():
    assert len(SCRIPTS) >= 8, [s.name for s in SCRIPTS]
    assert set(REQUIRES) <= {s.name for s in SCRIPTS}, "REQUIRES names a script that is gone"


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_example_is_a_sphinx_gallery_script(script):
    source = script.read_text()
    doc = ast.get_docstring(ast.parse(source), clean=False)
    assert doc is not None, f"{script.name}: no module docstring (the gallery's title and text)"
    lines = doc.strip().splitlines()
    title, underline = lines[0], lines[1] if len(lines) > 1 else ""
    assert title.strip() and set(underline.strip()) == {"="}, f"{script.name}: title + '===='"
    assert len(underline.strip()) >= len(title.strip()), f"{script.name}: underline too short"
    assert any(line.strip() for line in lines[2:]), f"{script.name}: no text under the title"
    assert source.count("\n# %%") >= 2, f"{script.name}: cells are separated by '# %%'"


@pytest.mark.parametrize("script", [_param(s) for s in SCRIPTS])
def test_example_runs(script, tmp_path):
    pytest.importorskip("matplotlib")
    proc = run_example(script, tmp_path)
    output = f"{proc.stdout[-3000:]}\n{proc.stderr[-5000:]}"
    assert proc.returncode == 0, f"{script.name} failed (exit {proc.returncode})\n{output}"
    assert list(tmp_path.iterdir()) == [], f"{script.name} left files in its working directory"
    unreadable = [ln for ln in proc.stdout.splitlines() if ln.startswith("unreadable figure")]
    assert not unreadable, f"{script.name}: " + "\n".join(unreadable)


def test_a_failing_or_figureless_example_is_caught(tmp_path):
    pytest.importorskip("matplotlib")
    broken = tmp_path / "plot_broken.py"
    broken.write_text('"""\nBroken\n======\n\nRaises.\n"""\nraise RuntimeError("boom")\n')
    proc = run_example(broken, tmp_path)
    assert proc.returncode != 0 and "boom" in proc.stderr
    silent = tmp_path / "plot_silent.py"
    silent.write_text('"""\nSilent\n======\n\nNo figure.\n"""\nprint("hello")\n')
    proc = run_example(silent, tmp_path)
    assert proc.returncode == 3 and "open figures: 0" in proc.stdout


def test_an_unreadable_figure_is_caught(tmp_path):
    """Small text, a figure wider than the page, a legend on the data, a label in two colours
    are each reported; the same figure in the shared style with its legend outside is not."""
    pytest.importorskip("matplotlib")
    script = tmp_path / "plot_unreadable.py"
    script.write_text(
        textwrap.dedent(
            '''
            """
            Unreadable
            ==========

            Two figures.
            """
            import matplotlib.pyplot as plt
            from stcgym.agents.benchmark import style

            fig, axes = plt.subplots(1, 2, figsize=(12, 3))
            for ax, color in zip(axes, ["C0", "C1"]):
                ax.plot([0, 1, 2], [0, 1, 0], color=color, label="stc")
                ax.set_title("panel", fontsize=7)
            axes[0].legend(loc="center")
            plt.rcParams.update(style.RC)
            fig, axes = plt.subplots(1, 2, figsize=(style.WIDTH, 3), layout="constrained")
            for ax in axes:
                ax.plot([0, 1, 2], [0, 1, 0], color=style.color("stc"), label="stc")
            fig.legend(*axes[0].get_legend_handles_labels(), loc="outside upper center")
            '''
        )
    )
    proc = run_example(script, tmp_path)
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("unreadable figure")]
    assert all(ln.startswith("unreadable figure 1: ") for ln in lines), lines
    problems = " ".join(lines)
    assert "'panel': 4.7 pt at 800 px" in problems  # 7 pt shrunk from 1200 to 800 px
    assert "legend ['stc'] lies on the plotting area" in problems
    assert "'stc' is drawn in #1f77b4 and in #ff7f0e" in problems
