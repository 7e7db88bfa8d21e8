"""Determinism: every command run twice with the same arguments (and seed, where it takes one)
writes byte-identical JSON, timing fields aside; the CSVs and figures are compared too, and the
input files are unchanged."""

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
import reference as ref

from piest_jax._cli import main

pytestmark = pytest.mark.long

# Keys that report how long something took on this machine, not a result.
_TIMING = re.compile(r"^(wall|elapsed|timing|runtime)|_(wall|elapsed|seconds)(_s)?$|^(seconds|time_s|wall_s)$")


def _timing_keys(obj, path=""):
    if isinstance(obj, dict):
        for k, v in obj.items():
            if _TIMING.search(str(k)):
                yield f"{path}/{k}"
            else:
                yield from _timing_keys(v, f"{path}/{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _timing_keys(v, f"{path}/{i}")


def _nulls(obj, path=""):
    if obj is None:
        yield path
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _nulls(v, f"{path}/{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _nulls(v, f"{path}/{i}")


def _without_timing(obj):
    if isinstance(obj, dict):
        return {k: _without_timing(v) for k, v in obj.items() if not _TIMING.search(str(k))}
    if isinstance(obj, list):
        return [_without_timing(v) for v in obj]
    return obj


def _twice(tmp_path, capsys, argv):
    # The input files are read, never written: their bytes are the same after both runs.
    inputs = {a: Path(a).read_bytes() for a in argv if os.path.isfile(a)}
    dirs = []
    for i in range(2):
        out = tmp_path / f"run{i}"
        code = main([*argv, "--out", str(out), "--quiet"])
        err = capsys.readouterr().err
        assert code == 0, err
        dirs.append(out)
    assert {a: Path(a).read_bytes() for a in inputs} == inputs
    return dirs


def _assert_identical(a, b):
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    assert any(n.endswith(".json") for n in names)
    for n in names:
        x, y = (a / n).read_bytes(), (b / n).read_bytes()
        if n.endswith(".json"):
            # Strict JSON: NaN or inf would break other readers (the writer maps them to null).
            jx, jy = (json.loads(z, parse_constant=lambda c: pytest.fail(f"{n} holds {c}")) for z in (x, y))
            # NaN or inf is written as null and flagged under "non_finite". Only a time that was
            # never reached (reproduce's P0 sweep, where a small gain does not converge within
            # the record) may be null; any other null would be a result that silently failed.
            nulls = list(_nulls(jx))
            assert not [p for p in nulls if "/time_to_" not in p], (n, nulls)
            flagged = jx.get("non_finite", {})
            assert len(flagged) == len(nulls) and set(flagged.values()) <= {"inf"}, (n, flagged)
            if not list(_timing_keys(jx)):
                assert x == y, n
            else:
                assert _without_timing(jx) == _without_timing(jy), n
        else:
            assert x == y, n


@pytest.fixture
def record(tmp_path):
    rng = np.random.default_rng(7)
    t = 0.01 * np.arange(400)
    u = 3 * np.sin(2 * np.pi * 0.5 * t) + np.sin(2 * np.pi * 1.3 * t)
    y = ref.pi(u, [0.0, 0.5, 1.0, 2.0], [1.0, 0.5, 0.3, 0.2]) + 0.01 * rng.normal(size=t.size)
    p = tmp_path / "rec.csv"
    p.write_text("t,u,y\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(t.tolist(), u.tolist(), y.tolist())))
    return p


def test_timing_keys_are_recognised():
    rep = {"wall_s": 1.2, "fit": {"elapsed_seconds": 3}, "time_to_1pct": 0.03, "duration": 1.0}
    assert sorted(_timing_keys(rep)) == ["/fit/elapsed_seconds", "/wall_s"]
    assert _without_timing(rep) == {"fit": {}, "time_to_1pct": 0.03, "duration": 1.0}


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "--input", "chirp", "--duration", "0.5", "--plays", "5", "--r-max", "8"],
        ["simulate", "--input", "multisine", "--amplitude", "3,1", "--frequency", "2,7", "--duration", "0.3"],
    ],
)
def test_simulate_twice(argv, tmp_path, capsys):
    _assert_identical(*_twice(tmp_path, capsys, argv))


def test_simulate_from_a_file_twice(record, tmp_path, capsys):
    _assert_identical(*_twice(tmp_path, capsys, ["simulate", "--input", "csv", "--csv", str(record)]))


def test_reproduce_twice(tmp_path, capsys):
    a, b = _twice(tmp_path, capsys, ["reproduce", "fig5"])
    _assert_identical(a, b)
    # The small gains of the P0 sweep never reach 1 % within the record: that time is infinite,
    # written as null and flagged as such.
    rep = json.loads((a / "fig5.json").read_text())
    flagged = rep["non_finite"]
    assert flagged and all(k.startswith("sweep.time_to_1pct.") for k in flagged)
    for k in flagged:
        norm, i = k.removeprefix("sweep.time_to_1pct.").rstrip("]").split("[")
        assert rep["sweep"]["time_to_1pct"][norm][int(i)] is None


def test_diagnose_twice(record, tmp_path, capsys):
    # The whole command (baseline fit, search, evaluation, location, report, figure) runs for
    # real; one round with one candidate effect keeps the test short.
    a, b = _twice(tmp_path, capsys, ["diagnose", str(record), "--max-effects", "1", "--candidates", "offset_drift"])
    _assert_identical(a, b)
    rep = json.loads((a / "report.json").read_text())
    assert set(rep["candidates"]) == {"offset_drift"}


def test_fit_twice(record, tmp_path, capsys):
    # Random starts drawn from --seed: the same seed gives the same fit, byte for byte.
    argv = ["fit", str(record), "--plays", "3", "--starts", "3", "--max-steps", "20", "--seed", "5"]
    a, b = _twice(tmp_path, capsys, [*argv, "--validate", str(record)])
    _assert_identical(a, b)
    assert json.loads((a / "fit.json").read_text())["n_plays"] == 3


def test_compensate_twice(record, tmp_path, capsys):
    model = tmp_path / "model.json"
    model.write_text(json.dumps({"thresholds": [0.0, 0.5, 1.0], "weights": [1.0, 0.5, 0.3], "offset": 0.1}))
    _assert_identical(*_twice(tmp_path, capsys, ["compensate", str(model), str(record)]))


def test_estimate_twice(record, tmp_path, capsys):
    a, b = _twice(tmp_path, capsys, ["estimate", str(record), "--plays", "4", "--start", "0"])
    _assert_identical(a, b)
    rep = json.loads((a / "estimate.json").read_text())
    assert len(rep["weights_final"]) == 4 and rep["start_sample"] == 0


def test_montecarlo_twice(tmp_path, capsys):
    argv = ["montecarlo", "--inputs", "6", "--samples", "300", "--plays", "3", "--chunk", "3", "--seed", "11"]
    a, b = _twice(tmp_path, capsys, argv)
    _assert_identical(a, b)
    rep = json.loads((a / "pe_map.json").read_text())
    assert rep["seed"] == 11 and len(rep["draws"]["rho"]) == 6


def test_excite_twice(tmp_path, capsys):
    argv = ["excite", "--thresholds", "0,1,2", "--samples", "600", "--amplitude", "3"]
    a, b = _twice(tmp_path, capsys, argv)
    _assert_identical(a, b)
    rep = json.loads((a / "excite.json").read_text())
    assert rep["samples"] == 600 and rep["design"]["margin"] > 0


def test_every_command_is_run_twice():
    from piest_jax._cli import COMMANDS

    tested = {name.split("_")[1] for name in globals() if name.startswith("test_") and name.endswith("_twice")}
    assert {m.NAME for m in COMMANDS} <= tested
