"""Every code block of the README and the docs pages (docs/**/*.md) is run here, so that none can drift.

- A ```python block runs as written, as a script in a temporary directory; where it is heavy (or needs what a test
  machine lacks), by the smaller stand-in declared in an HTML comment just above it (invisible on the site):

      <!-- test: smaller stand-in: why
      prepend: a line of code run before the block
      replace: OLD => NEW           (OLD must occur in the block; every occurrence is replaced)
      append: a line of code run after the block
      cwd: repository               (run in the repository root instead of a temporary directory)
      -->

  ``{repository}`` in a replacement is the repository's path.
- Every `pdestream ...` command in a ```bash block is parsed by the CLI's own parser (its flags and choices exist).
- A ```bash block with such a comment above it is run, after its replacements, by bash (``set -e``) in a temporary
  directory that the page's run blocks share, in order; the others are parsed only.

A snippet that fails as written (or as its stand-in) fails here. The runs are slow (each starts JAX and torch).
"""

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", re.S | re.M)


@dataclass
class Block:
    page: Path
    line: int
    lang: str
    code: str
    directive: str | None = None  # the comment's text, when there is one
    prepend: list[str] = field(default_factory=list)
    replace: list[tuple[str, str]] = field(default_factory=list)
    append: list[str] = field(default_factory=list)
    cwd: str = "temporary"

    @property
    def name(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"

    def stand_in(self) -> str:
        """The code to run: the block as written, or its declared stand-in."""
        code = self.code
        for old, new in self.replace:
            assert old in code, f"{self.name}: the stand-in replaces {old!r}, which the block no longer holds"
            code = code.replace(old, new.replace("{repository}", str(ROOT)))
        return "\n".join([*self.prepend, code, *self.append]) + "\n"


def parse_directive(block: Block, text: str) -> None:
    first, *lines = text.split("\n")
    assert first.startswith("smaller stand-in"), f"{block.name}: a test comment declares a 'smaller stand-in: ...'"
    block.directive = first
    for line in lines:
        if not line.strip():
            continue
        key, sep, value = line.partition(": ")
        assert sep, f"{block.name}: not a stand-in line: {line!r}"
        if key == "prepend":
            block.prepend.append(value)
        elif key == "append":
            block.append.append(value)
        elif key == "replace":
            old, arrow, new = value.partition(" => ") if " => " in value else value.rpartition(" =>")  # "OLD =>": drop
            assert arrow, f"{block.name}: a replacement is 'OLD => NEW': {line!r}"
            block.replace.append((old, new))
        elif key == "cwd":
            assert value in ("repository", "temporary"), f"{block.name}: cwd is 'repository' or 'temporary'"
            block.cwd = value
        else:
            raise AssertionError(f"{block.name}: unknown stand-in line {line!r}")


def blocks(page: Path) -> list[Block]:
    text = page.read_text()
    found = []
    for m in FENCE.finditer(text):
        block = Block(page, text.count("\n", 0, m.start()) + 1, m.group(1), m.group(2))
        start = text.rfind("<!-- test: ", 0, m.start())  # the comment just above the block, if any
        end = text.find("-->", start) if start >= 0 else -1
        if start >= 0 and not text[end + 3: m.start()].strip():
            parse_directive(block, text[start + len("<!-- test: "): end].rstrip())
        found.append(block)
    return found


ALL = [b for page in PAGES for b in blocks(page)]
PYTHON = [b for b in ALL if b.lang == "python"]
BASH = [b for b in ALL if b.lang == "bash"]
RUN_PAGES = sorted({b.page for b in BASH if b.directive}, key=PAGES.index)


REDIRECT = re.compile(r"\d?>>?(&\d|\S+)?")


def pdestream_commands(script: str) -> list[list[str]]:
    """The argv after `pdestream` of every command in a shell script (continuations joined, comments dropped)."""
    commands = []
    for line in script.replace("\\\n", " ").split("\n"):
        words = shlex.split(line, comments=True)
        command: list[str] = []
        target = False  # the word after a bare `>` / `2>>` is its file
        for word in [*words, "&&"]:
            if word in ("&&", "||", ";", "|"):
                if "pdestream" in command:
                    commands.append(command[command.index("pdestream") + 1:])
                command = []
            elif REDIRECT.fullmatch(word) or target:  # a redirection (2>&1, >log, > log) is the shell's
                target = not target and word.endswith(">")
            else:
                command.append(word)
    return commands


def test_the_pages_have_code_blocks_and_every_stand_in_still_fits_its_block():
    assert len(PYTHON) >= 9 and len(BASH) >= 20, (len(PYTHON), len(BASH))
    for block in ALL:
        block.stand_in()  # each replacement's OLD is still in its block
    readme = [b for b in ALL if b.page.name == "README.md"]
    assert [b.lang for b in readme] == ["bash", "bash", "python"]  # the two set-up commands and the example


@pytest.mark.parametrize("block", BASH, ids=lambda b: b.name)
def test_every_pdestream_command_parses(block):
    from pdestream import cli

    for argv in pdestream_commands(block.code):
        try:
            cli.build_parser().parse_args(argv)
        except SystemExit as exit:
            pytest.fail(f"{block.name}: `pdestream {shlex.join(argv)}` is refused by the CLI's parser ({exit})")


def run(args: list[str], cwd: Path, name: str, timeout: int = 600) -> None:
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""), MPLBACKEND="Agg")
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{name} failed (exit {done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"


@pytest.mark.slow
@pytest.mark.parametrize("block", PYTHON, ids=lambda b: b.name)
def test_python_block_runs(block, tmp_path):
    script = tmp_path / "snippet.py"
    script.write_text(block.stand_in())
    run([sys.executable, str(script)], ROOT if block.cwd == "repository" else tmp_path, block.name)


@pytest.mark.slow
@pytest.mark.parametrize("page", RUN_PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_bash_blocks_run(page, tmp_path):
    for block in blocks(page):
        if block.lang == "bash" and block.directive:
            run(["bash", "-e", "-c", block.stand_in()], ROOT if block.cwd == "repository" else tmp_path, block.name)
