"""The documentation site builds in strict mode: every page, every API entry, every cross-reference."""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_site_builds_strictly(tmp_path):
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "mkdocs",
            "build",
            "--strict",
            "-f",
            str(ROOT / "mkdocs.yml"),
            "-d",
            str(tmp_path / "site"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    site = tmp_path / "site"
    # The generated pages are there, with their generated content.
    cli = (site / "cli" / "index.html").read_text(encoding="utf-8")
    assert "piest fit" in cli and "--validate" in cli
    assert (site / "experiments" / "index.html").exists()
    api = (site / "api" / "identification" / "index.html").read_text(encoding="utf-8")
    assert "fit_pi" in api and "Arguments:" in api


def test_every_public_name_has_one_api_entry():
    import piest_jax as pj

    entries = []
    for page in (ROOT / "docs" / "api").glob("*.md"):
        entries += [
            line.split("piest_jax.", 1)[1].strip()
            for line in page.read_text().splitlines()
            if line.startswith("::: piest_jax.")
        ]
    assert sorted(entries) == sorted(pj._EXPORTS)
