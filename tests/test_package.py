"""Package manners: lazy imports, the version, `python -m piest_jax`, optional extras, and figure
helpers that leave matplotlib's backend and pyplot alone."""

import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numpy as np

import piest_jax as pj


def _python(code: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300)


def test_import_loads_neither_jax_nor_the_diagnosis_stack():
    code = """
import sys
import piest_jax as pj
print(sorted(m for m in ("jax", "scipy", "matplotlib", "tqdm") if m in sys.modules))
pj.fit_pi, pj.PIOperator, pj.load_record
print(sorted(m for m in ("jax", "scipy", "matplotlib") if m in sys.modules))
pj.diagnose
print(sorted(m for m in ("scipy", "matplotlib") if m in sys.modules))
"""
    proc = _python(code)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split("\n")[:3] == ["[]", "['jax']", "['scipy']"]


def test_help_and_version_do_not_load_jax():
    code = """
import contextlib, io, sys
from piest_jax._cli import main
for argv in (["--help"], ["--version"], ["nope"]):
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        try:
            main(argv)
        except SystemExit:
            pass
print("jax" in sys.modules)
"""
    proc = _python(code)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "False"


def test_version_comes_from_the_package_metadata():
    version = metadata.version("piest_jax")
    assert pj.__version__ == version
    for cmd in (["piest", "--version"], [sys.executable, "-m", "piest_jax", "--version"]):
        if cmd[0] == "piest":
            cmd[0] = str(__import__("pathlib").Path(sys.executable).with_name("piest"))
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0 and proc.stdout.strip() == f"piest {version}", proc


def test_module_runs_the_command_line(tmp_path):
    args = [
        "simulate",
        "--input",
        "triangle",
        "--thresholds",
        "0,1",
        "--weights",
        "1,0.5",
        "--duration",
        "0.2",
        "--quiet",
    ]
    a = subprocess.run(
        [sys.executable, "-m", "piest_jax", *args, "--out", str(tmp_path / "a")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert a.returncode == 0, a.stderr
    assert pj.run_cli([*args, "--out", str(tmp_path / "b")]) == 0
    assert (tmp_path / "a" / "simulate.csv").read_bytes() == (tmp_path / "b" / "simulate.csv").read_bytes()


def test_commands_without_matplotlib_say_which_extra_to_install(tmp_path):
    code = """
import sys
sys.modules["matplotlib"] = None  # as if it were not installed
from piest_jax._cli import main
sys.exit(main(sys.argv[1:]))
"""
    out = tmp_path / "o"
    proc = _python(code, "simulate", "--out", str(out))
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "piest simulate: error: matplotlib is needed to draw the figures; install the command "
        "line's extras with pip install 'piest_jax[cli]'"
    ]
    assert not out.exists()


def test_progress_without_tqdm_yields_the_items():
    code = """
import sys
sys.modules["tqdm"] = None
from piest_jax._progress import progress
print(list(progress(range(4), desc="x")))
"""
    proc = _python(code)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[0, 1, 2, 3]"


def _fake_report():
    t = np.linspace(0, 1, 50)
    w = np.outer(1 - np.exp(-20 * t), [1.0, 3.0, 5.0])
    p0 = [1e4, 1e6, 1e8]
    return {
        "_arrays": {"t": t, "weights": w, "bound": np.exp(-t)},
        "weights_true": [1.0, 3.0, 5.0],
        "figure": "fig5",
        "input": "u",
        "P0": 1e8,
        "sweep": {"P0": p0, "time_to_1pct": {"paper": [None, 0.1, 0.03], "standard": [0.2, 0.05, 0.03]}},
        "time_input_exceeds_r_max": 0.02,
    }


def test_figure_helpers_leave_the_backend_and_pyplot_alone(tmp_path):
    import matplotlib
    import matplotlib.pyplot as plt

    backend, figures = matplotlib.get_backend(), plt.get_fignums()
    fig = pj.paper.figure(_fake_report())
    assert isinstance(fig, matplotlib.figure.Figure) and len(fig.axes) >= 2
    assert matplotlib.get_backend() == backend and plt.get_fignums() == figures
    a = pj.save_figure(fig, tmp_path / "a.png", dpi=50)
    b = pj.save_figure(fig, tmp_path / "b.png", dpi=50)
    assert a.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and a.read_bytes() == b.read_bytes()
    assert plt.get_fignums() == figures


def test_library_write_json_reads_as_the_cli_writes(tmp_path):
    from piest_jax._cli import output

    obj = {"a": np.arange(3.0), "b": np.float32(0.5), "c": float("inf"), "p": tmp_path}
    lib = pj.write_json(tmp_path / "lib.json", obj)
    cli = output.write_json(tmp_path / "cli.json", obj)
    assert lib.read_text() == cli.read_text()
    assert '"non_finite": {\n    "c": "inf"\n  }' in lib.read_text()


def test_readme_notebooks_and_experiments_use_only_the_public_api():
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    files = [
        root / "README.md",
        *(root / "notebooks").rglob("*.py"),
        *(root / "notebooks").glob("*.ipynb"),
        *(root / "experiments").rglob("*.py"),
    ]
    private = [
        f"{p.relative_to(root)}:{i}"
        for p in files
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if re.search(r"piest_jax\._", line)
    ]
    assert len(files) > 15 and private == []


def test_lazy_exports_and_the_type_checking_imports_agree():
    # The lazy table serves users; the TYPE_CHECKING block serves type checkers and editors.
    # A name in one and not the other, or mapped to another object, is a silent API split.
    import ast
    import importlib
    from pathlib import Path

    src = Path(pj.__file__).read_text()
    tree = ast.parse(src)
    block = next(n for n in tree.body if isinstance(n, ast.If) and getattr(n.test, "id", "") == "TYPE_CHECKING")
    checked = {}
    for node in block.body:
        assert isinstance(node, ast.ImportFrom), ast.dump(node)
        for alias in node.names:
            checked[alias.asname or alias.name] = ("." * node.level + (node.module or ""), alias.name)
    assert checked == {**pj._EXPORTS, **{m: (".", m) for m in pj._SUBMODULES}}
    for public, (module, attr) in pj._EXPORTS.items():
        assert getattr(importlib.import_module(module, "piest_jax"), attr) is getattr(pj, public)


def _figure_calls():
    """Every figure function of the public API, called on small inputs."""
    t = np.linspace(0.0, 1.0, 60)
    u = np.sin(2 * np.pi * 2 * t)
    y = u + 0.1 * np.cos(2 * np.pi * 2 * t)
    rec = pj.Record(t, u, y)
    mask = (t >= 0.2).astype(float)
    val = pj.DiagnosisValidation(
        rec, 0.2, 0.02, 0.1, 0.01, 50.0, 95.0, 60.0, 96.0, {}, 0.01, 0.2, 0.02, ["delay"], 0.0, {}, 0.9 * y, y
    )
    diagnosis = pj.Diagnosis(
        rec, ["delay"], 0.1, 0.01, 0.01, {}, {}, [], [], 0.1, 0.01, 1, [], 0.9 * y, y, validation=val
    )
    k = np.arange(4.0)
    online = pj.OnlineEstimate(
        thresholds=k[:2],
        initial_states=k[:2],
        weights=k[:2],
        offset=np.float64(0.0),
        t=k,
        weights_trajectory=np.ones((4, 2)),
        offset_trajectory=k,
        error_rms=np.exp(-k),
        final_rmse=0.1,
        window_t=k[:2],
        pe_levels=np.array([1e-3, 1e-2]),
        exciting=np.array([True, True]),
        bound_t=k[:2],
        gram_bound=np.array([1.0, 0.1]),
    )
    settings = pj.make_settings(n_samples=100, families=["sine", "triangle"], dtype="float64")
    rng = np.random.default_rng(0)
    draws = {
        "rho": rng.uniform(0.1, 3, 20),
        "c1_normalised": rng.uniform(1e-12, 1e-3, 20),
        "pe": rng.uniform(size=20) > 0.4,
        "family": np.repeat(list(settings.families), 10),
        "exact": rng.uniform(size=20) > 0.3,
        "sharper": rng.uniform(size=20) > 0.5,
        "weight_error": rng.uniform(1e-9, 1, 20),
        "margin": rng.uniform(1e-9, 1e-4, 20),
        "c1": rng.uniform(1e-9, 1e-3, 20),
        "worst_error": rng.uniform(1e-6, 1, 20),
        "guaranteed_error": rng.uniform(1e-4, 1, 20),
        "samples_to_1pct": rng.integers(-1, 100, 20),
        "guaranteed_samples_to_1pct": rng.integers(-1, 100, 20),
        "worst_samples_to_1pct": rng.integers(-1, 100, 20),
        "gram_scale": rng.uniform(1, 10, 20),
        "excited": rng.uniform(size=(20, 3, 4)) > 0.5,
        "min_excited": rng.integers(0, 5, 20),
        "redundant": rng.integers(0, 3, 20),
        "zero_frozen": rng.uniform(size=20) > 0.9,
        "twin_triple": rng.uniform(size=20) > 0.9,
        "exact_level": rng.uniform(1e-12, 1e-3, 20),
        "thresholds": np.sort(rng.uniform(0, 1, (20, 4)), axis=1),
    }
    pe_map = pj.PEMap(settings=settings, start=0, devices=("cpu",), settled=None, seconds=1.0, **draws)
    return {
        "fit_figure": lambda: pj.fit_figure(rec, 0.9 * y, title="fit", mask=mask),
        "compensation_figure": lambda: pj.compensation_figure(t, y, u),
        "loop_figure": lambda: pj.loop_figure(t, u, y, np.column_stack([u, 0.5 * u]), [0.0, 0.5]),
        "diagnosis_figure": lambda: pj.diagnosis_figure(diagnosis),
        "online_estimate_figure": lambda: pj.online_estimate_figure(online, title="rls", t0=1.0),
        "pe_map_figure": lambda: pj.pe_map_figure(pe_map),
        "paper.figure": lambda: pj.paper.figure(_fake_report()),
    }


def test_every_figure_function_leaves_the_backend_and_pyplot_alone(tmp_path):
    import matplotlib
    import matplotlib.pyplot as plt

    backend = matplotlib.get_backend()
    for name, draw in _figure_calls().items():
        fig = draw()
        assert isinstance(fig, matplotlib.figure.Figure) and len(fig.axes) >= 2, name
        assert matplotlib.get_backend() == backend and plt.get_fignums() == [], name
        pj.save_figure(fig, tmp_path / f"{name}.png", dpi=40)
        assert (tmp_path / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    assert plt.get_fignums() == []


def test_the_commands_draw_without_pyplot():
    # The figures are library functions built on `Figure()`; no command imports pyplot or
    # switches the backend.
    from pathlib import Path

    root = Path(pj.__file__).parent
    offending = [
        str(p.relative_to(root))
        for p in root.rglob("*.py")
        if "matplotlib.use(" in p.read_text() or "import matplotlib.pyplot" in p.read_text()
    ]
    assert offending == ["_cli/output.py"]  # save_figure closes a pyplot figure it is given


def test_the_command_line_in_process_leaves_the_backend_alone(tmp_path):
    code = """
import sys
import matplotlib
matplotlib.use("pdf")
import matplotlib.pyplot as plt
from piest_jax._cli import main
code = main(["simulate", "--duration", "0.1", "--quiet", "--out", sys.argv[1]])
print(code, matplotlib.get_backend(), plt.get_fignums())
"""
    proc = _python(code, str(tmp_path / "o"))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split("\n")[-2] == "0 pdf []"
    assert (tmp_path / "o" / "loop.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_lowest_versions_job_pins_the_floors():
    # .ci/run's second job installs .ci/lowest.txt: each dependency of the library and of the
    # `cli` extra at exactly the floor pyproject.toml declares, so a floor the code outgrows fails.
    import re
    import tomllib

    root = Path(__file__).resolve().parents[1]
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    floors = {}
    for spec in [*project["dependencies"], *project["optional-dependencies"]["cli"]]:
        m = re.fullmatch(r"([A-Za-z0-9_.-]+)>=([0-9.]+)", spec)
        assert m, f"{spec!r} has no plain floor"
        floors[m[1].lower()] = m[2]
    pins = dict(
        line.split("==")
        for line in (root / ".ci" / "lowest.txt").read_text().splitlines()
        if "==" in line and not line.startswith("#")
    )
    assert {k: pins.get(k) for k in floors} == floors
    assert pins["jaxlib"] == floors["jax"]
