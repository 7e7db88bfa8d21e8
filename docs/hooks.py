"""Build-time hooks of the documentation site (mkdocs `hooks:`).

Pages that would otherwise go stale are generated from their sources when the site is built:
the command-line help from the real argument parser, the experiments page from
`experiments/README.md` and the data sources page from `piest_jax/data/README.md`, with the
figures those pages show.
"""

import contextlib
import io
import os
import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]
HELP_MARKER = "<!-- piest-help -->"
GENERATED = {
    "experiments.md": ROOT / "experiments" / "README.md",
    "data_sources.md": ROOT / "piest_jax" / "data" / "README.md",
}
IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")


def _help(words) -> str:
    from piest_jax._cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        main([*words, "--help"])
    return out.getvalue()


def cli_help() -> str:
    """`piest --help` and every command's help, as Markdown sections."""
    from piest_jax._cli import HELP

    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal; the page is fixed-width
    parts = ["## piest\n\n```text\n" + _help([]) + "```\n"]
    parts += [f"## piest {name}\n\n```text\n" + _help([name]) + "```\n" for name in HELP]
    return "\n".join(parts)


def on_files(files, config):
    for name, src in GENERATED.items():
        text = src.read_text(encoding="utf-8")
        files.append(File.generated(config, name, content=text))
        # The figures the page shows, at the same paths relative to the page.
        for link in IMAGE.findall(text):
            path = (src.parent / link).resolve()
            if path.is_file() and not files.get_file_from_path(link):
                files.append(File.generated(config, link, abs_src_path=str(path)))
    for link in ("experiments/results/montecarlo/pe_map.png",):
        if not files.get_file_from_path(link):
            files.append(File.generated(config, link, abs_src_path=str(ROOT / link)))
    return files


def on_page_markdown(markdown, page, config, files):
    if HELP_MARKER in markdown:
        markdown = markdown.replace(HELP_MARKER, cli_help())
    return markdown
