"""The README and the guide stay honest: every code block in them is run here, and every `piest`
command they show is a valid one.

The guide pages (`docs/*.md`, in the order of the site's navigation) continue the README: their
blocks are run after its blocks, as one reader's session.

- Every ```python block is run, in order, as one script in a fresh interpreter inside a temporary
  folder (later blocks may use names from earlier ones, as a reader would in one session).
- Every ```bash block is run, in order, as one `bash -euo pipefail` script in another temporary
  folder, with this interpreter's `bin` folder first on PATH (so `piest` and `python` are the
  ones under test); tests/test_readme_shell.py runs it, so that the two sessions (each a minute
  of subprocesses) run on different test workers. Two blocks are special: the main command
  between the `main-command` markers creates a virtual environment and installs the package,
  which is what this test runs in already, so only its `piest` commands are run; the test command
  between the `test-command` markers is what CI runs (`.ci/run` runs the same command and refuses
  to start if they differ), so here it is only checked.
- ```bibtex blocks are checked for balanced braces and the paper's DOI. A block in any other
  language fails the test: nothing in the README goes unchecked.
- Every `piest ...` command in a shell block (and every `example:` line of a command's help) is
  also parsed by the real argument parser, so a renamed command or option fails with its name.
"""

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from piest_jax._cli import COMMANDS, build_parser, main

pytestmark = pytest.mark.long

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
# Pages whose blocks are excerpts of the package's code (with `...`), not a session to run.
EXCERPTS = {"architecture.md"}
GUIDE = [
    "cli.md",
    "tour.md",
    "paper.md",
    "excitation.md",
    "fitting.md",
    "diagnosis.md",
    "performance.md",
    "reliability.md",
    "data.md",
]
FENCE = re.compile(r"^```[ \t]*([\w+-]*)[^\n]*\n(.*?)^```[ \t]*$", re.M | re.S)
SHELL = {"bash", "sh", "shell", "console", "zsh"}
RUN = {"simulate"}  # help examples cheap enough to run for real here
BIBTEX = {"bibtex", "bib"}
PYTHON_LANGS = {"python", "py", "python3"}


def code_blocks(text: str) -> list[tuple[str, str]]:
    """(language, code) for every fenced block of a Markdown text, in order."""
    return [(m.group(1).lower(), m.group(2)) for m in FENCE.finditer(text)]


def piest_commands(shell: str) -> list[list[str]]:
    """The argument lists of every `piest ...` invocation in a shell snippet.

    Lines are joined at trailing backslashes; a line is split at `&&`, `||`, `;` and `|`, and
    a leading `$ ` prompt is dropped.
    """
    text = re.sub(r"\\\n", " ", shell)
    found = []
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("$ "):
            line = line[2:]
        if not line or line.startswith("#"):
            continue
        for part in re.split(r"&&|\|\||;|\|", line):
            if part.split()[:1] != ["piest"]:
                continue  # not a `piest` command (and perhaps a fragment of a quoted string)
            words = shlex.split(part, comments=True)
            if words and words[0] == "piest":
                found.append(words[1:])
    return found


def _readme() -> str:
    return README.read_text(encoding="utf-8")


def _documents() -> str:
    """The README followed by the guide pages."""
    return "\n".join([_readme(), *((ROOT / "docs" / page).read_text(encoding="utf-8") for page in GUIDE)])


BLOCKS = code_blocks(_documents())
PYTHON = [code for lang, code in BLOCKS if lang in PYTHON_LANGS]
COMMAND_LINES = [args for lang, code in BLOCKS if lang in SHELL for args in piest_commands(code)]
HELP_EXAMPLES = [
    piest_commands(line.split("example:", 1)[1])[0]
    for mod in COMMANDS
    for line in mod.DESCRIPTION.splitlines()
    if "example:" in line and "piest" in line
]


def _id(args) -> str:
    return " ".join(args)[:60] or "<none>"


def test_readme_has_the_two_commands():
    text = _readme()
    for marker in ("main-command", "test-command"):
        blocks = code_blocks(_marked(text, marker).strip() + "\n")
        assert blocks and blocks[0][0] in SHELL and blocks[0][1].strip()
    assert "pytest" in _marked(text, "test-command")
    main_commands = piest_commands(code_blocks(_marked(text, "main-command").strip() + "\n")[0][1])
    assert main_commands, "the main command should run `piest`"


def _marked(text: str, marker: str) -> str:
    m = re.search(rf"<!-- {marker} -->(.*?)<!-- /{marker} -->", text, re.S)
    assert m, f"README.md has no block between the {marker} markers"
    return m.group(1)


def _env() -> dict:
    bin_dir = str(Path(sys.executable).parent)
    return dict(os.environ, MPLBACKEND="Agg", PATH=bin_dir + os.pathsep + os.environ.get("PATH", ""))


def _run(cmd, cwd, what) -> None:
    proc = subprocess.run(cmd, cwd=cwd, env=_env(), capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"README {what} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"


def test_every_page_with_code_is_checked():
    for page in sorted((ROOT / "docs").rglob("*.md")):
        runnable = [lang for lang, _ in code_blocks(page.read_text(encoding="utf-8")) if lang in SHELL | PYTHON_LANGS]
        assert not runnable or page.name in GUIDE or page.name in EXCERPTS, (
            f"{page} has code blocks that no test runs: add it to GUIDE"
        )


def test_every_block_is_run_or_checked():
    langs = {lang for lang, _ in BLOCKS}
    unchecked = langs - SHELL - PYTHON_LANGS - BIBTEX
    assert not unchecked, f"README.md has blocks no test runs: {sorted(unchecked)} (use bash or python)"
    assert PYTHON, "README.md should show the Python API"
    assert COMMAND_LINES, "README.md should show the command line"


def test_readme_python_runs(tmp_path):
    (tmp_path / "readme_blocks.py").write_text("\n\n".join(PYTHON), encoding="utf-8")
    _run([sys.executable, "readme_blocks.py"], tmp_path, "Python")


def test_readme_bibtex_is_well_formed():
    entries = [code for lang, code in BLOCKS if lang in BIBTEX]
    for code in entries:
        assert code.count("{") == code.count("}"), "unbalanced braces in a bibtex block"
        assert re.match(r"\s*@\w+\{[\w:-]+,", code), "a bibtex block should start with @type{key,"
    assert any("10.1115/1.4050189" in code for code in entries), "cite the paper by its DOI"


@pytest.mark.parametrize("args", COMMAND_LINES + HELP_EXAMPLES, ids=_id)
def test_piest_command_parses(args):
    assert args, "`piest` with no command"
    parser = build_parser()
    try:
        parsed = parser.parse_args(args)
    except SystemExit as e:
        if "--help" in args or "-h" in args:
            assert e.code == 0
            return
        pytest.fail(f"`piest {' '.join(args)}` does not parse (exit {e.code})")
    assert parsed.command in {m.NAME for m in COMMANDS}


@pytest.mark.parametrize("args", [a for a in HELP_EXAMPLES if a and a[0] in RUN], ids=_id)
def test_cheap_piest_command_runs(args, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code = main([*args, "--quiet"] if "--quiet" not in args else args)
    out = capsys.readouterr()
    assert code == 0, out.err
    written = [Path(line) for line in out.out.split()]
    assert written and all((tmp_path / p).exists() or p.exists() for p in written)


def test_extractors():
    text = (
        "intro\n```python\nx = 1\n```\n\n```bash\n$ piest simulate --out a && ls a\n"
        "piest reproduce fig5 \\\n  --P0 1e6  # comment\npip install .\n```\n"
    )
    blocks = code_blocks(text)
    assert [lang for lang, _ in blocks] == ["python", "bash"]
    assert blocks[0][1] == "x = 1\n"
    assert piest_commands(blocks[1][1]) == [
        ["simulate", "--out", "a"],
        ["reproduce", "fig5", "--P0", "1e6"],
    ]


def test_a_bad_command_is_caught(capsys):
    parser = build_parser()
    with pytest.raises(SystemExit) as e:
        parser.parse_args(["simulate", "--no-such-option"])
    assert e.value.code == 2
    capsys.readouterr()
