"""The README stays honest: its Python runs, and every `piest` command it shows is a valid one.

- Every ```python block is run, in order, as one script in a fresh interpreter inside a temporary
  folder (later blocks may use names from earlier ones, as a reader would in one session).
- Every `piest ...` command in a ```bash / ```sh / ```console block (and every `example:` line of
  a command's help) is parsed by the real argument parser, so a renamed command or option fails
  here. `piest simulate` commands are cheap, so they are also run, in a temporary folder.
- The test command that CI runs verbatim sits between the `test-command` markers.
"""

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from piest_jax._cli import COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
FENCE = re.compile(r"^```[ \t]*([\w+-]*)[^\n]*\n(.*?)^```[ \t]*$", re.M | re.S)
SHELL = {"bash", "sh", "shell", "console", "zsh"}
RUN = {"simulate"}  # commands fast enough to run for real here


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
            words = shlex.split(part, comments=True)
            if words and words[0] == "piest":
                found.append(words[1:])
    return found


def _readme() -> str:
    return README.read_text(encoding="utf-8")


BLOCKS = code_blocks(_readme())
PYTHON = [code for lang, code in BLOCKS if lang in ("python", "py", "python3")]
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
        m = re.search(rf"<!-- {marker} -->(.*?)<!-- /{marker} -->", text, re.S)
        assert m, f"README.md has no block between the {marker} markers"
        blocks = code_blocks(m.group(1).strip() + "\n")
        assert blocks and blocks[0][0] in SHELL and blocks[0][1].strip()
    test_cmd = re.search(r"<!-- test-command -->(.*?)<!-- /test-command -->", text, re.S).group(1)
    assert "pytest" in test_cmd


@pytest.mark.skipif(not PYTHON, reason="README.md has no Python blocks yet")
def test_readme_python_runs(tmp_path):
    script = "\n\n".join(PYTHON)
    (tmp_path / "readme_blocks.py").write_text(script, encoding="utf-8")
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    proc = subprocess.run(
        [sys.executable, "readme_blocks.py"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, f"README Python failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"


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


@pytest.mark.parametrize(
    "args", [a for a in COMMAND_LINES + HELP_EXAMPLES if a and a[0] in RUN], ids=_id
)
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
