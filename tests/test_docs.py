"""The documentation: every public name listed in the API reference, every environment id with
a card, every Python snippet of the README and of the pages runs as written and prints what the
``output`` block after it shows, the counts the pages state are the code's, code lines fit the
site's code box, Markdown tables keep their columns, and the site builds without a warning and
without raw markup or dead links in its HTML (the gallery's scripts run in
``tests/test_examples.py``)."""

from __future__ import annotations

import ast
import importlib
import logging
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import gymnasium as gym
import pytest
from sybil import Document, Example
from sybil.parsers.markdown import CodeBlockParser

import stcgym.envs  # noqa: F401  (registers the ids)

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PACKAGES = ("stcgym.envs", "stcgym.adaptive", "stcgym.agents", "stcgym.agents.sweeps")
PAGES = [ROOT / "README.md", *sorted(DOCS.glob("*.md")), *sorted((DOCS / "api").glob("*.md"))]
# Sybil finds a page's fenced ``python`` blocks and the ``output`` blocks after them (``output``
# is a Pygments lexer: the site shows the block as plain program output).
BLOCK_PARSERS = (CodeBlockParser("python"), CodeBlockParser("output"))
NUMBER = re.compile(r"-?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?")
FENCE = re.compile(r"^(`{3,})([^\n`]*)\n(.*?)^\1[ \t]*$", re.S | re.M)
# The code box of a page shows 90 characters at a 1400 px window (furo, measured in Chromium:
# a 708 px box, 7.8 px per character of its monospace font); API entries are indented and show
# 82-86. 84 leaves room for fonts slightly wider than the one measured.
CODE_WIDTH = 84
# Pages whose code blocks are shortened when those pages are next rewritten (with what they
# describe); every other page is held to CODE_WIDTH. Empty this set, do not grow it.
WIDE_CODE_PAGES: set[str] = set()


@dataclass
class Snippet:
    """A Python snippet, where the pages show it, and the output blocks shown after it."""

    code: str
    where: list[str]
    outputs: list[tuple[str, str]]


def _public_names() -> list[tuple[str, str, object]]:
    out = []
    for package in PACKAGES:
        module = importlib.import_module(package)
        for name in module.__all__:
            out.append((package, name, getattr(module, name)))
    return out


def test_the_api_pages_list_every_public_name():
    listed: dict[str, set[str]] = {}
    for page in sorted((DOCS / "api").glob("*.md")):
        text = page.read_text()
        for block in re.findall(r"```\{eval-rst\}\n(.*?)```", text, re.S):
            module = re.search(r"^\.\. currentmodule:: ([\w.]+)$", block, re.M).group(1)
            listed.setdefault(module, set()).update(re.findall(r"^   (\w+)$", block, re.M))
    absent = [f"{p}.{n}" for p, n, _ in _public_names() if n not in listed.get(p, set())]
    assert not absent, f"no page of docs/api/ lists {absent}"
    api = (DOCS / "api.md").read_text()
    unlinked = [p.stem for p in (DOCS / "api").glob("*.md") if f"api/{p.stem}\n" not in api]
    assert not unlinked, f"docs/api.md does not link {unlinked}"


def _cards() -> dict[str, str]:
    """The environment cards of docs/environments.md: heading id -> its text."""
    text = (DOCS / "environments.md").read_text()
    text = text[text.index("## Environment cards") :]
    parts = re.split(r"^### `([^`]+)`$", text, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2], strict=True))


@pytest.mark.parametrize("env_id", [k for k in gym.registry if k.startswith("stcgym/")])
def test_every_registered_environment_has_a_card(env_id):
    cards = _cards()
    assert env_id in cards, f"docs/environments.md has no card '### `{env_id}`'"
    card = cards[env_id]
    env = gym.make(env_id)
    for what, space in (("action", env.action_space), ("observation", env.observation_space)):
        assert f"| {what} space | `{space}`" in card, f"{env_id}: the {what} space is {space}"
    for section in ("Description", "Reward", "Episode end", "Arguments", "Version history"):
        assert f"**{section}" in card, f"{env_id}: the card has no {section}"
    version = env_id.rsplit("-", 1)[1]
    assert f"{version}:" in card.split("**Version history.**", 1)[1], f"{env_id}: no {version}"


NUMBER_WORDS = {"four": 4, "five": 5, "six": 6, "seven": 7, "eight": 8, "nine": 9, "ten": 10}


def _stated_counts() -> list[tuple[str, str, int]]:
    """``(page, pattern, count in the code)``: each pattern's group is a count a page states."""
    from stcgym.adaptive import ALGORITHMS
    from stcgym.envs import get_family

    ids = [k for k in gym.registry if k.startswith("stcgym/")]
    family = get_family("siso2-v1")
    splits = {name: len(family.split_indices(name)) for name in family.split_names}
    variant_sizes = {splits[v] for v in family.variant_names}
    assert len(variant_sizes) == 1, variant_sizes  # the page states one size for all
    return [
        ("docs/environments.md", r"registers (\w+) Gymnasium environment ids", len(ids)),
        ("README.md", r"all (\d+) names", len(ALGORITHMS)),
        ("docs/index.md", r"all (\d+) of the paper", len(ALGORITHMS)),
        ("docs/glossary.md", r"the paper's (\d+) names", len(ALGORITHMS)),
        ("docs/estimators.md", r"all (\d+) algorithms", len(ALGORITHMS)),
        ("docs/environments.md", r"has\s+(\d+) second-order plants", family.count),
        ("docs/environments.md", r"`train` \((\d+)\)", splits["train"]),
        ("docs/environments.md", r"`validation` \((\d+)\)", splits["validation"]),
        ("docs/environments.md", r"`test` \((\d+)\)", splits["test"]),
        ("docs/environments.md", r"Its (\w+) variants of \d+ plants", len(family.variant_names)),
        ("docs/environments.md", r"variants of (\d+) plants each", variant_sizes.pop()),
    ]


def test_the_counts_the_pages_state_are_the_codes():
    wrong = []
    for page, pattern, count in _stated_counts():
        stated = re.findall(pattern, (ROOT / page).read_text())
        assert stated, f"{page} no longer states /{pattern}/: update this test"
        for word in stated:
            if NUMBER_WORDS.get(word, word) not in (count, str(count)):
                wrong.append(f"{page}: '{word}' in /{pattern}/, the code has {count}")
    assert not wrong, wrong


def test_the_environments_table_lists_every_registered_id():
    text = (DOCS / "environments.md").read_text()
    table = re.findall(r"^\| \[`(stcgym/[\w-]+)`\]", text[: text.index("\n## ")], re.M)
    assert table == [k for k in gym.registry if k.startswith("stcgym/")]


#: The README's agreed length: the set-up steps and three examples; the rest lives on the site.
README_LINES = 170


def test_the_readme_stays_short():
    lines = len((ROOT / "README.md").read_text().splitlines())
    assert lines <= README_LINES, f"README.md has {lines} lines, over {README_LINES}"


def _blocks(page: Path) -> list[Example]:
    """The ``python`` and ``output`` code blocks of a page, in order (Sybil's Markdown lexer)."""
    return list(Document.parse(str(page), *BLOCK_PARSERS).examples())


def _language(block: Example) -> str:
    return block.region.lexemes["arguments"]


def _snippets() -> list[Snippet]:
    """Every Python snippet of the pages, each distinct one once (the README repeats the
    landing page's), with the output blocks that follow it on each page."""
    by_code: dict[str, Snippet] = {}
    for page in PAGES:
        previous = None
        for block in _blocks(page):
            where = f"{page.relative_to(ROOT)}:{block.line}"
            if _language(block) == "python":
                previous = by_code.setdefault(block.parsed, Snippet(block.parsed, [], []))
                previous.where.append(where)
            elif previous is None:
                raise AssertionError(f"{where}: an output block that follows no python block")
            else:
                previous.outputs.append((where, str(block.parsed)))
                previous = None
    return list(by_code.values())


def output_mismatch(shown: str, printed: str) -> str | None:
    """Why ``printed`` is not what an output block ``shown`` says, or None if it is.

    The text must match with whitespace runs equal and ``...`` standing for any text (the
    doctest conventions); each number must equal the printed one to a unit in the last
    place either writes (a rounding that another BLAS or compiler may flip), integers exactly.
    """
    pattern, numbers = "", []
    for token in re.split(rf"(\.\.\.|{NUMBER.pattern}|\s+)", shown.strip()):
        if token == "...":
            pattern += ".*?"
        elif NUMBER.fullmatch(token or "x"):
            pattern += f"({NUMBER.pattern})"
            numbers.append(token)
        elif token.isspace():
            pattern += r"\s+"
        else:
            pattern += re.escape(token)
    match = re.fullmatch(pattern, printed.strip(), re.S)
    if match is None:
        return f"the page shows\n{shown}\nthe snippet printed\n{printed}"
    for want, got in zip(numbers, match.groups(), strict=True):
        decimals = max(len(n.partition(".")[2].partition("e")[0]) for n in (want, got))
        unit = 10.0**-decimals if "." in want + got else 0.0  # integers: exactly
        if abs(float(want) - float(got)) > unit + 1e-12:
            return f"the page shows {want}, the snippet printed {got}:\n{printed}"
    return None


@pytest.mark.parametrize("snippet", _snippets(), ids=lambda s: s.where[0])
def test_every_python_snippet_runs_as_written_and_prints_what_the_page_shows(snippet, tmp_path):
    if "stcgym.agents" in snippet.code and importlib.util.find_spec("stable_baselines3") is None:
        pytest.skip("needs the rl extra")
    script = tmp_path / "snippet.py"
    script.write_text(snippet.code)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    done = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, f"{snippet.where} failed:\n{done.stderr[-3000:]}"
    wrong = [(w, output_mismatch(shown, done.stdout)) for w, shown in snippet.outputs]
    wrong = [f"{w}: {why}" for w, why in wrong if why]
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize(
    ("shown", "printed", "ok"),
    [
        ("stc: 0.172\nppo: ...\noracle: 0.131", "stc: 0.172\nppo: 0.945\noracle: 0.131\n", True),
        ("stc: 0.172\nppo: 1.558\noracle: 0.131", "stc: 0.172\nppo: 0.945\noracle: 0.131\n", False),
        ("[-1.498  0.698  1.     0.507]", "[-1.498  0.698  1.     0.507]\n", True),
        ("[-1.498  0.698  1.     0.507]", "[-1.497  0.698  0.999  0.507]\n", True),  # a rounding
        ("[-1.498  0.698  1.     0.507]", "[-1.496  0.698  1.     0.507]\n", False),
        ("15", "16\n", False),
        ("range(1100, 1300)", "range(1100, 1300)\n", True),
        ("a 1.0", "b 1.0", False),
        ("1.0", "1.0\n2.0\n", False),
    ],
)
def test_the_output_check_allows_a_rounding_and_nothing_else(shown, printed, ok):
    assert (output_mismatch(shown, printed) is None) == ok


def test_a_printed_value_is_shown_in_an_output_block_not_a_comment():
    """A value written in a comment after ``print`` is not checked: it goes in an ``output``
    block after the snippet, which is."""
    unchecked = []
    for snippet in _snippets():
        for line in snippet.code.splitlines():
            code, _, comment = line.partition("  # ")
            if "print(" in code and re.search(r"\d*\.\d|\[\s*-?\d", comment):
                unchecked.append(f"{snippet.where[0]}: {line.strip()}")
    assert not unchecked, f"values in comments after print: {unchecked}"


def test_code_lines_fit_the_code_box():
    wide = []
    for page in PAGES:
        if page.name in WIDE_CODE_PAGES:
            continue
        text = page.read_text()
        for match in FENCE.finditer(text):
            if match.group(2).startswith("{"):  # a directive, not a code block
                continue
            first = text[: match.start(3)].count("\n") + 1
            for i, line in enumerate(match.group(3).splitlines()):
                if len(line) > CODE_WIDTH:
                    wide.append(f"{page.relative_to(ROOT)}:{first + i} ({len(line)})")
    wide += _wide_gallery_code()
    assert not wide, f"code lines wider than {CODE_WIDTH} characters: {wide}"


def _wide_gallery_code() -> list[str]:
    """The code lines of the gallery's scripts wider than the code box. sphinx-gallery shows
    the module docstring and each comment block that follows a ``# %%`` line as text, every
    other line (comments within code included) in a code box."""
    wide = []
    for script in sorted((ROOT / "examples").glob("plot_*.py")):
        source = script.read_text()
        body = ast.parse(source).body
        docstring_end = body[0].end_lineno if isinstance(body[0], ast.Expr) else 0
        in_text = False
        for number, line in enumerate(source.splitlines(), start=1):
            if line.startswith("# %%"):
                in_text = True
            elif not (in_text and line.startswith("#")):
                in_text = False
                if number > docstring_end and len(line) > CODE_WIDTH:
                    wide.append(f"{script.relative_to(ROOT)}:{number} ({len(line)})")
    return wide


def _cells(row: str) -> int:
    """Cells of a Markdown table row: split on '|' not escaped by a backslash (GFM splits
    inside code spans too)."""
    return len(re.split(r"(?<!\\)\|", row.strip().strip("|")))


def test_markdown_tables_keep_their_columns():
    broken = []
    for page in PAGES:
        lines = page.read_text().splitlines()
        in_fence = False
        for i, line in enumerate(lines):
            if line.startswith("```"):
                in_fence = not in_fence
            if in_fence or not re.fullmatch(r"\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?", line):
                continue
            width = _cells(lines[i - 1])
            j = i + 1
            while j < len(lines) and lines[j].startswith("|"):
                if _cells(lines[j]) != width:
                    broken.append(f"{page.relative_to(ROOT)}:{j + 1}")
                j += 1
    assert not broken, f"table rows whose cell count differs from the header's: {broken}"


# ----------------------------------------------------------------------------- the built site

RAW_MARKUP = re.compile(r":(?:class|func|meth|mod|data|attr|obj|exc|ref|doc|term):`|``|\\\|")
ABBREVIATION_END = ("eq.", "eqs.", " e.g.", " i.e.", " cf.", " vs.")


class _Page(HTMLParser):
    """The text of a built page outside code blocks, its ids, its links, its paragraphs and the
    summary cells of its API tables."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.text: list[str] = []
        self.ids: set[str] = set()
        self.links: list[str] = []
        self.paragraphs: list[str] = []
        self.summaries: list[str] = []
        self._skip = 0
        self._p: list[str] | None = None
        self._autosummary = 0
        self._cell = 0
        self._td: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if "id" in attrs:
            self.ids.add(attrs["id"])
        if tag == "a" and attrs.get("href"):
            self.links.append(attrs["href"])
        if tag in ("pre", "script", "style"):
            self._skip += 1
        if tag == "p":
            self._p = []
        if tag == "table" and "autosummary" in (attrs.get("class") or ""):
            self._autosummary += 1
        if tag == "tr":
            self._cell = 0
        if tag == "td" and self._autosummary:
            self._cell += 1
            if self._cell == 2:
                self._td = []

    def handle_endtag(self, tag):
        if tag in ("pre", "script", "style"):
            self._skip -= 1
        if tag == "p" and self._p is not None:
            self.paragraphs.append("".join(self._p))
            self._p = None
        if tag == "table" and self._autosummary:
            self._autosummary -= 1
        if tag == "td" and self._td is not None:
            self.summaries.append("".join(self._td).strip())
            self._td = None

    def handle_data(self, data):
        if self._skip:
            return
        self.text.append(data)
        if self._p is not None:
            self._p.append(data)
        if self._td is not None:
            self._td.append(data)


def _site_problems(html: Path) -> list[str]:
    pages = {}
    for path in sorted(html.rglob("*.html")):
        rel = path.relative_to(html)
        if rel.parts[0] in ("_modules", "_static", "_sources"):
            continue
        page = _Page()
        page.feed(path.read_text())
        pages[rel.as_posix()] = page
    problems = []
    for name, page in pages.items():
        text = "".join(page.text)
        for m in RAW_MARKUP.finditer(text):
            problems.append(f"{name}: raw markup {text[max(0, m.start() - 50) : m.end() + 30]!r}")
        for p in page.paragraphs:
            if re.search(r"\|\s*-{3,}\s*\|", p) or re.match(r"\s*\|.*\|\s*$", p, re.S):
                problems.append(f"{name}: a table that did not parse: {p[:80]!r}")
        for s in page.summaries:
            # every public name has a summary on the topic pages; a member of a class may
            # have none (an attribute without a doc comment), but none is cut short
            missing = not s and name.startswith("api/")
            if missing or s.endswith(ABBREVIATION_END) or s.startswith("Built-in"):
                problems.append(f"{name}: an API summary cut short or missing: {s!r}")
        for href in page.links:
            parts = urlsplit(href)
            if parts.scheme or parts.netloc or href.startswith("mailto:"):
                continue
            target = (Path(name).parent / unquote(parts.path)).as_posix() if parts.path else name
            target = os.path.normpath(target)
            if target not in pages:
                if not (html / target).exists():
                    problems.append(f"{name}: a link to a missing file {href!r}")
                continue
            if parts.fragment and parts.fragment not in pages[target].ids:
                problems.append(f"{name}: a link to a missing anchor {href!r}")
    return problems


def test_the_site_builds_cleanly(tmp_path):
    pytest.importorskip("sphinx")
    pytest.importorskip("sphinx_gallery")
    done = subprocess.run(
        [
            sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
            "-D", "plot_gallery=0", "-d", str(tmp_path / "doctrees"),
            str(DOCS), str(tmp_path / "html"),
        ],
        cwd=DOCS, capture_output=True, text=True, timeout=900,
        env={**os.environ, "MPLBACKEND": "Agg"},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-5000:]
    problems = _site_problems(tmp_path / "html")
    assert not problems, "\n".join(problems[:40])


def test_the_docs_build_logs_the_compile_notice_as_information(caplog):
    """conf.py hands the ``stcgym`` logger's warning (the first-run compile notice) to
    Sphinx's log at INFO level: the gallery's first script compiles the kernels."""
    pytest.importorskip("sphinx")
    stcgym_log = logging.getLogger("stcgym")
    handlers, propagate = list(stcgym_log.handlers), stcgym_log.propagate
    path = list(sys.path)
    spec = importlib.util.spec_from_file_location("docs_conf", DOCS / "conf.py")
    try:
        spec.loader.exec_module(importlib.util.module_from_spec(spec))
        with caplog.at_level(logging.INFO):
            stcgym_log.warning("stcgym is compiling its kernels")
    finally:
        stcgym_log.handlers[:], stcgym_log.propagate = handlers, propagate
        sys.path[:] = path
    seen = [(r.name, r.levelno) for r in caplog.records if "compiling" in r.getMessage()]
    assert seen == [("sphinx.stcgym", logging.INFO)], seen


def test_the_site_check_finds_raw_markup_broken_tables_and_dead_links(tmp_path):
    (tmp_path / "api").mkdir()
    (tmp_path / "api" / "a.html").write_text(
        '<p>A <strong>``reset(options=...)`` accepts :class:`Foo`</strong></p>'
        "<p>| piece | equations |\n|---|---|</p>"
        '<table class="autosummary"><tr><td>x</td><td><p>Vector version (eq.</p></td></tr>'
        '<tr><td>y</td><td></td></tr></table>'
        '<a href="../b.html#nowhere">b</a><a href="c.html">c</a><a href="#here">here</a>'
        '<pre>``fine in code``</pre><p id="here">x_hat(t\\|t)</p>'
    )  # fmt: skip
    (tmp_path / "b.html").write_text('<p id="somewhere">b</p>')
    problems = _site_problems(tmp_path)
    raw = [p for p in problems if "raw markup" in p]
    assert len(raw) == 4, problems  # two double backticks, a role, an escaped pipe
    assert any(":class:`Foo" in p for p in raw) and any("t\\\\|t" in p for p in raw), raw
    assert sum("did not parse" in p for p in problems) == 1, problems
    assert any("cut short or missing: 'Vector version (eq.'" in p for p in problems), problems
    assert any("cut short or missing: ''" in p for p in problems), problems
    assert any("missing anchor '../b.html#nowhere'" in p for p in problems), problems
    assert any("missing file 'c.html'" in p for p in problems), problems
    assert len(problems) == 9, problems  # nothing from the code block or the link to #here
