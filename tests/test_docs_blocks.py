"""Every code block of README.md and the documentation runs as written.

Blocks are collected from the Markdown itself, so a page and its test cannot drift apart. Per
page, in one fresh working folder and in page order: ```python blocks run in one namespace,
```bash blocks line by line (a line that is one `vogjax` command runs in this process through
the CLI's entry point, the rest in bash with this environment's `vogjax` on PATH; a block that
sets shell state runs in one bash), ```toml blocks load as a
settings file. A block preceded by `<!-- skip: reason -->` is not run (install commands, runs of
hours); the reason is required. A page that starts from the survey the Getting started page
maps says so with `<!-- uses: the boxes survey -->`: its folder then starts with that page's
`boxes.h5` and `maps/boxes`, made once per test session by the same commands. Snippet lines
(`--8<-- "path"`) are replaced by the file they name, as MkDocs does, so a tutorial script
included in its page runs here.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"^(?P<indent> *)```(?P<lang>[\w-]*)[^\n]*\n(?P<body>.*?)^(?P=indent)```\s*$", re.S | re.M)
SKIP = re.compile(r"<!-- skip: (?P<reason>[^>]+?) -->\s*$")
SNIPPET = re.compile(r'^ *--8<-- "(?P<path>[^"]+)"$', re.M)
RUN = ("python", "bash", "toml")
USES_BOXES = "<!-- uses: the boxes survey -->"
# What docs/getting-started.md runs; pages marked USES_BOXES start from its results. The same
# commands in any page are run once per session and their outputs copied (the CLI is
# deterministic: same inputs, same files), which keeps the docs' share of the suite short.
SURVEY = {
    "vogjax simulate --scene boxes --scans 600 --out boxes.h5": ["boxes.h5"],
    "vogjax map boxes.h5 --out maps --quiet": ["maps/boxes"],
}
BOXES_SURVEY = "".join(f"{command}\n" for command in SURVEY)


@dataclass
class Block:
    page: Path
    line: int
    lang: str
    code: str
    skip: str | None


def blocks_of(page: Path) -> list[Block]:
    text = SNIPPET.sub(lambda m: (ROOT / m.group("path")).read_text(), page.read_text())
    found = []
    for match in FENCE.finditer(text):
        before = text[: match.start()].rstrip("\n").rsplit("\n", 1)[-1]
        skip = SKIP.search(before)
        indent = len(match.group("indent"))
        body = "\n".join(line[indent:] for line in match.group("body").split("\n"))
        found.append(
            Block(
                page,
                text.count("\n", 0, match.start()) + 1,
                match.group("lang"),
                body,
                skip.group("reason") if skip else None,
            )
        )
    return found


def where(block: Block) -> str:
    return f"{block.page.relative_to(ROOT)}:{block.line}"


def run_python(block: Block, namespace: dict) -> None:
    exec(compile(block.code, where(block), "exec"), namespace)


# A line that is one `vogjax` command (optionally `> file`) runs in this process, through the same
# entry point as the console script: each subprocess would pay the imports and the JIT again
# (seconds each on 2 cores). Anything else (pipes, `||`, heredocs, other programs) runs in bash.
IN_PROCESS = re.compile(r"^vogjax(?P<args>(?: [^|&;<>$`\\(){}]*)?)(?: > (?P<out>[\w./-]+))?$")


def run_vogjax(argv: list[str], out: str | None, where_: str) -> None:
    import contextlib
    import io

    from vogjax.cli import main

    stdout, stderr = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = main(argv)
    except SystemExit as done:
        code = done.code or 0
    assert code == 0, f"{where_}: vogjax {' '.join(argv)} exited {code}:\n{stdout.getvalue()}\n{stderr.getvalue()}"
    if out is not None:
        Path(out).write_text(stdout.getvalue())


def segments(code: str) -> list[tuple[str, str]]:
    """The block as ("vogjax", line) and ("bash", lines) pieces, in order; heredocs stay whole."""
    pieces: list[tuple[str, str]] = []
    lines = code.replace("\\\n", " ").split("\n")
    heredoc = None
    for line in lines:
        command = line.split(" #", 1)[0].strip()
        if heredoc is None and IN_PROCESS.match(command):
            pieces.append(("vogjax", command))
            continue
        if heredoc is None:
            opened = re.search(r"<<-?\s*'?(\w+)'?", command)
            heredoc = opened.group(1) if opened else None
        elif line.strip() == heredoc:
            heredoc = None
        if pieces and pieces[-1][0] == "bash":
            pieces[-1] = ("bash", pieces[-1][1] + "\n" + line)
        else:
            pieces.append(("bash", line))
    return [(kind, text.rstrip()) for kind, text in pieces if text.strip()]


# shell state that later lines would need: such a block runs in one bash, vogjax lines included
SHELL_STATE = re.compile(r"^\s*(cd|export|source|\.|set|alias)\s|^\s*\w+=", re.M)


def run_bash(block: Block, folder: Path, survey=None) -> None:
    """Run a bash block in `folder` (the working folder); with `survey` (a callable giving the
    session's survey folder), the survey's own commands copy their outputs from it instead."""
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    pieces = segments(block.code)
    if any(kind == "bash" and SHELL_STATE.search(text) for kind, text in pieces):
        pieces = [("bash", block.code)]
    for kind, text in pieces:
        if survey is not None and text in SURVEY:
            for output in SURVEY[text]:
                source = survey() / output
                copy = shutil.copytree if source.is_dir() else shutil.copy
                copy(source, folder / output)
        elif kind == "vogjax":
            match = IN_PROCESS.match(text)
            with _working_folder(folder):
                run_vogjax(shlex.split(match.group("args")), match.group("out"), where(block))
        else:
            done = subprocess.run(
                ["bash", "-euo", "pipefail", "-c", text],
                cwd=folder,
                env=env,
                capture_output=True,
                text=True,
                timeout=600,
            )
            assert done.returncode == 0, f"{where(block)} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"


@contextmanager
def _working_folder(folder: Path):
    before = Path.cwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(before)


def check_toml(block: Block) -> None:
    from vogjax.config import JobConfig
    from vogjax.config.planner import ExploreConfig

    document = tomllib.loads(block.code)
    errors = []
    for cls in (JobConfig, ExploreConfig):
        try:
            cls.from_document(document)
            return
        except ValueError as error:
            errors.append(f"{cls.__name__}: {error}")
    raise AssertionError(f"{where(block)} is not a settings file: {'; '.join(errors)}")


PAGES_WITH_BLOCKS = [p for p in PAGES if any(b.lang in RUN for b in blocks_of(p))]


@pytest.fixture(scope="session")
def boxes_survey(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("boxes_survey")
    run_bash(Block(ROOT / "docs" / "getting-started.md", 0, "bash", BOXES_SURVEY, None), folder)
    return folder


@pytest.mark.parametrize("page", PAGES_WITH_BLOCKS, ids=lambda p: str(p.relative_to(ROOT)))
def test_page_blocks_run_as_written(page, tmp_path, monkeypatch, request):
    monkeypatch.chdir(tmp_path)
    if USES_BOXES in page.read_text():
        survey = request.getfixturevalue("boxes_survey")
        shutil.copy(survey / "boxes.h5", tmp_path)
        shutil.copytree(survey / "maps", tmp_path / "maps")
    namespace = {"__name__": "__docs__"}
    for block in blocks_of(page):
        if block.lang not in RUN or block.skip:
            continue
        if block.lang == "python":
            run_python(block, namespace)
        elif block.lang == "bash":
            run_bash(block, tmp_path, survey=lambda: request.getfixturevalue("boxes_survey"))
        else:
            check_toml(block)


def test_every_block_is_run_or_says_why_not():
    unknown, skipped = [], []
    for page in PAGES:
        for block in blocks_of(page):
            if block.lang not in (*RUN, "text", "mermaid"):
                unknown.append(f"{where(block)} ({block.lang or 'no language'})")
            if block.skip:
                skipped.append(where(block))
    assert not unknown, f"blocks of a language the suite neither runs nor shows as output: {unknown}"
    # skips are for what cannot run here (installs, hours-long runs); keep them rare
    assert len(skipped) <= 20, skipped


def test_the_boxes_survey_is_what_getting_started_runs():
    page = (ROOT / "docs" / "getting-started.md").read_text()
    assert f"```bash\n{BOXES_SURVEY}```" in page


def test_the_collector_finds_what_it_should(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "text\n\n```python\nx = 1\n```\n\n<!-- skip: needs a GPU -->\n```bash\nnvidia-smi\n```\n\n"
        "- item\n\n  ```python\n  y = x + 1\n  ```\n"
    )
    found = blocks_of(page)
    assert [(b.lang, b.code.strip(), b.skip) for b in found] == [
        ("python", "x = 1", None),
        ("bash", "nvidia-smi", "needs a GPU"),
        ("python", "y = x + 1", None),
    ]


def test_a_block_splits_into_vogjax_commands_and_bash_in_order():
    code = (
        "vogjax --version   # which one\n"
        "cat > quick.toml <<'EOF'\n[pipeline]\nvogjax = 1\nEOF\n"
        "vogjax config --defaults > settings.toml\n"
        'vogjax map boxes.h5 --out maps || echo "exit status $?"\n'
        "ls maps\n"
    )
    assert not any(SHELL_STATE.search(text) for _, text in segments(code))
    assert SHELL_STATE.search("cd maps") and SHELL_STATE.search("RUN=boxes.h5")
    assert segments(code) == [
        ("vogjax", "vogjax --version"),
        ("bash", "cat > quick.toml <<'EOF'\n[pipeline]\nvogjax = 1\nEOF"),
        ("vogjax", "vogjax config --defaults > settings.toml"),
        ("bash", 'vogjax map boxes.h5 --out maps || echo "exit status $?"\nls maps'),
    ]
