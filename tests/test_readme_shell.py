"""The README's and the guide's shell blocks run as one session (the rules are in the docstring of
tests/test_readme.py; this file holds only the shell session, so that it and the Python session,
each a minute of subprocess work, run on different test workers)."""

import shlex

import pytest
from test_readme import SHELL, _documents, _marked, _run, code_blocks, piest_commands

pytestmark = pytest.mark.long


def shell_script(text: str) -> str:
    """The README's shell blocks as one script, as this test runs them (see the module docstring)."""
    main_block = code_blocks(_marked(text, "main-command").strip() + "\n")[0][1]
    test_block = code_blocks(_marked(text, "test-command").strip() + "\n")[0][1]
    parts = []
    for lang, code in code_blocks(text):
        if lang not in SHELL or code == test_block:
            continue
        if code == main_block:
            code = "\n".join(shlex.join(["piest", *args]) for args in piest_commands(code)) + "\n"
        parts.append(code)
    return "set -euo pipefail\n" + "\n".join(parts)


def test_readme_shell_runs(tmp_path):
    script = shell_script(_documents())
    assert "piest" in script
    (tmp_path / "readme_blocks.sh").write_text(script, encoding="utf-8")
    _run(["bash", "readme_blocks.sh"], tmp_path, "shell blocks")
