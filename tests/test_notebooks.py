"""The notebooks: every one runs top to bottom with small sizes, and the committed copies are current.

Each notebook's source is `notebooks/src/NN_name.py` (percent format); `notebooks/build.py` turns
it into `notebooks/NN_name.ipynb` and executes it. Here each source is executed in a fresh kernel
with `PIEST_NOTEBOOK_SMALL=1` (so none can rot), and the committed `.ipynb` must have the same
cells as its source and carry the outputs of a full-size run.
"""

import importlib.util
import sys
from pathlib import Path

import pytest
from conftest import shared_compile_cache

pytestmark = pytest.mark.long

nbformat = pytest.importorskip("nbformat")
pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ROOT / "notebooks"


def _load_build():
    spec = importlib.util.spec_from_file_location("piest_notebook_build", NOTEBOOKS / "build.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


build = _load_build()
SOURCES = build.sources()
IDS = [p.stem for p in SOURCES]


def _errors(nb) -> list[str]:
    found = []
    for i, cell in enumerate(nb.cells):
        for out in cell.get("outputs", []):
            if out.get("output_type") == "error":
                found.append(f"cell {i}: {out.get('ename')}: {out.get('evalue')}")
            elif out.get("name") == "stderr" and "Traceback" in out.get("text", ""):
                found.append(f"cell {i}: traceback on stderr")
    return found


def _missing_figures(nb) -> list[int]:
    """Code cells that draw a figure but show no image (e.g. after a backend switch)."""
    return [
        i
        for i, cell in enumerate(nb.cells)
        if cell.cell_type == "code"
        and "plt.subplots(" in cell.source
        and not any("image/png" in out.get("data", {}) for out in cell.get("outputs", []))
    ]


def test_there_are_notebooks():
    assert len(SOURCES) >= 2, f"expected notebook sources in {build.SRC}"
    numbers = [p.name[:2] for p in SOURCES]
    assert len(set(numbers)) == len(numbers), f"two notebooks share a number: {numbers}"


@pytest.mark.parametrize("src", SOURCES, ids=IDS)
def test_opens_with_the_maths(src):
    nb = build.load_source(src)
    first = nb.cells[0]
    assert first.cell_type == "markdown"
    assert first.source.startswith("# "), "the first cell should be a title"
    assert "$" in first.source, "the opening cell should state the maths the notebook explores"
    assert any(c.cell_type == "code" for c in nb.cells)


@pytest.mark.parametrize("src", SOURCES, ids=IDS)
def test_committed_notebook_is_current(src):
    target = NOTEBOOKS / f"{src.stem}.ipynb"
    assert target.exists(), f"{target.name} is missing: run `python notebooks/build.py {src.stem[:2]}`"
    committed = nbformat.read(target, as_version=4)
    nbformat.validate(committed)
    assert build.same_cells(build.load_source(src), committed), (
        f"{target.name} is out of date with {src.name}: run `python notebooks/build.py {src.stem[:2]}`"
    )
    code = [c for c in committed.cells if c.cell_type == "code"]
    assert all(c.get("execution_count") for c in code), f"{target.name} was not executed"
    assert any(c.get("outputs") for c in code), f"{target.name} has no outputs"
    assert _errors(committed) == []
    assert _missing_figures(committed) == [], "cells that draw a figure but show none"
    assert committed.metadata.get("piest", {}).get("small") is False, (
        f"{target.name} should be committed from a full-size run (build.py without --small)"
    )


@pytest.mark.parametrize("src", SOURCES, ids=IDS)
def test_notebook_runs_with_small_sizes(src, monkeypatch):
    # The kernel loads what the test session already compiled (tests/conftest.py).
    folder = shared_compile_cache()
    if folder is not None:
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", folder)
        monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
    nb = build.execute(build.load_source(src), small=True, timeout=300)
    assert nb.metadata["piest"]["small"] is True
    assert _errors(nb) == []
    assert _missing_figures(nb) == [], "cells that draw a figure but show none"
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(c.get("execution_count") for c in code)


def test_parse_percent_format():
    text = "# %% [markdown]\n# # Title\n#\n# $x$\n\n# %%\nx = 1\n\n\n# %%\nprint(x)\n"
    nb = build.parse(text)
    assert [c.cell_type for c in nb.cells] == ["markdown", "code", "code"]
    assert nb.cells[0].source == "# Title\n\n$x$"
    assert nb.cells[1].source == "x = 1"
    assert [c["id"] for c in nb.cells] == ["cell-00", "cell-01", "cell-02"]


def test_parse_rejects_malformed_sources():
    with pytest.raises(ValueError, match="before the first"):
        build.parse("x = 1\n# %%\ny = 2\n")
    with pytest.raises(ValueError, match="does not start with '# '"):
        build.parse("# %% [markdown]\nnot a comment\n")
