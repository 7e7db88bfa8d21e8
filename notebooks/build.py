"""Build the notebooks from their plain-text sources and execute them.

Each notebook is written as a Python file in `notebooks/src/` in the percent-cell format: a line
`# %%` starts a code cell, `# %% [markdown]` starts a markdown cell whose lines are comments
(`# ` is stripped). The sources are what gets reviewed; the `.ipynb` files next to this script are
built from them and committed with their outputs, so they read well on GitHub without running.

    python notebooks/build.py                 # build and execute every notebook (full sizes)
    python notebooks/build.py 01 02           # only the notebooks whose names start with these
    python notebooks/build.py --no-execute    # rebuild the cells without running them
    python notebooks/build.py --check         # fail if a committed notebook differs from its source

Execution uses the "python3" kernel, which jupyter_client resolves to the interpreter running this
script (so run it with the project's virtual environment's python). Set PIEST_NOTEBOOK_SMALL=1 to
run with the small sizes the tests use.
"""

import argparse
import os
import sys
import time
from pathlib import Path

import nbformat

HERE = Path(__file__).resolve().parent
SRC = HERE / "src"
KERNEL = "python3"
TIMEOUT_S = 600
SMALL_ENV = "PIEST_NOTEBOOK_SMALL"


def sources() -> list[Path]:
    """The notebook sources, in order."""
    return sorted(SRC.glob("[0-9][0-9]_*.py"))


def _flush(cells: list, kind: str | None, lines: list[str]) -> None:
    if kind is None:
        if any(line.strip() for line in lines):
            raise ValueError("text before the first `# %%` cell marker")
        return
    while lines and not lines[-1].strip():
        lines.pop()
    while lines and not lines[0].strip():
        lines.pop(0)
    if kind == "markdown":
        text = []
        for line in lines:
            if line.startswith("# "):
                text.append(line[2:])
            elif line.rstrip() == "#":
                text.append("")
            else:
                raise ValueError(f"markdown cell line does not start with '# ': {line!r}")
        cell = nbformat.v4.new_markdown_cell("\n".join(text))
    else:
        cell = nbformat.v4.new_code_cell("\n".join(lines))
    # Stable ids keep the committed notebooks' diffs small.
    cell["id"] = f"cell-{len(cells):02d}"
    cells.append(cell)


def parse(text: str) -> nbformat.NotebookNode:
    """A notebook (without outputs) from percent-format source text.

    **Arguments:** `text`, the source.

    **Returns:** an nbformat v4 notebook.
    """
    cells: list = []
    kind, lines = None, []
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("# %%"):
            _flush(cells, kind, lines)
            kind = "markdown" if "[markdown]" in stripped else "code"
            lines = []
        else:
            lines.append(line)
    _flush(cells, kind, lines)
    nb = nbformat.v4.new_notebook(cells=cells)
    nb.metadata["kernelspec"] = {"name": KERNEL, "display_name": "Python 3", "language": "python"}
    nb.metadata["language_info"] = {"name": "python"}
    return nb


def load_source(path: Path) -> nbformat.NotebookNode:
    """Parse one source file into a notebook without outputs."""
    return parse(path.read_text(encoding="utf-8"))


def execute(nb: nbformat.NotebookNode, *, small: bool, timeout: int = TIMEOUT_S):
    """Run a notebook top to bottom in a fresh kernel, in the notebooks folder.

    **Arguments:** `nb`, the notebook (modified in place); `small`, run with the test sizes;
    `timeout`, seconds allowed per cell.

    **Returns:** the executed notebook. Raises `nbclient.exceptions.CellExecutionError` on the
    first cell that fails.
    """
    from nbclient import NotebookClient

    env_before = os.environ.get(SMALL_ENV)
    os.environ[SMALL_ENV] = "1" if small else "0"
    try:
        client = NotebookClient(
            nb,
            kernel_name=KERNEL,
            timeout=timeout,
            resources={"metadata": {"path": str(HERE)}},
        )
        client.execute()
        # Recorded so a test can tell committed full-size runs from small test runs.
        nb.metadata["piest"] = {"small": bool(small)}
    finally:
        if env_before is None:
            os.environ.pop(SMALL_ENV, None)
        else:
            os.environ[SMALL_ENV] = env_before
    return nb


def _clean(nb: nbformat.NotebookNode) -> nbformat.NotebookNode:
    # Timestamps change on every run and say nothing to a reader.
    for cell in nb.cells:
        cell.metadata.pop("execution", None)
    return nb


def same_cells(a: nbformat.NotebookNode, b: nbformat.NotebookNode) -> bool:
    """Whether two notebooks have the same cell kinds and sources (outputs are ignored)."""
    pa = [(c.cell_type, c.source) for c in a.cells]
    pb = [(c.cell_type, c.source) for c in b.cells]
    return pa == pb


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="notebook name prefixes (default: all)")
    parser.add_argument("--no-execute", action="store_true", help="build without running")
    parser.add_argument("--check", action="store_true", help="compare committed notebooks")
    parser.add_argument("--small", action="store_true", help="run with the test sizes")
    args = parser.parse_args(argv)

    chosen = [p for p in sources() if not args.names or any(p.stem.startswith(n) for n in args.names)]
    if not chosen:
        print("no notebook source matches", args.names, file=sys.stderr)
        return 2
    status = 0
    for src in chosen:
        target = HERE / f"{src.stem}.ipynb"
        nb = load_source(src)
        if args.check:
            if not target.exists():
                print(f"{target.name}: missing", file=sys.stderr)
                status = 1
            elif not same_cells(nb, nbformat.read(target, as_version=4)):
                print(f"{target.name}: out of date with {src.name}", file=sys.stderr)
                status = 1
            continue
        if not args.no_execute:
            start = time.perf_counter()
            execute(nb, small=args.small)
            print(f"{target.name}: executed in {time.perf_counter() - start:.1f} s")
        nbformat.validate(nb)
        nbformat.write(_clean(nb), target)
        print(target)
    return status


if __name__ == "__main__":
    sys.exit(main())
