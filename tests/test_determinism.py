"""Determinism: every command run twice with the same arguments (and seed, where it takes one)
writes byte-identical JSON, timing fields aside; the CSVs and figures are compared too."""

import functools
import json
import re

import numpy as np
import pytest

from piest_jax import _effects
from piest_jax._cli import main

import reference as ref

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


def _without_timing(obj):
    if isinstance(obj, dict):
        return {k: _without_timing(v) for k, v in obj.items() if not _TIMING.search(str(k))}
    if isinstance(obj, list):
        return [_without_timing(v) for v in obj]
    return obj


def _twice(tmp_path, capsys, argv):
    dirs = []
    for i in range(2):
        out = tmp_path / f"run{i}"
        code = main([*argv, "--out", str(out), "--quiet"])
        err = capsys.readouterr().err
        assert code == 0, err
        dirs.append(out)
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
    _assert_identical(*_twice(tmp_path, capsys, ["reproduce", "fig5"]))


def test_diagnose_twice(record, tmp_path, capsys, monkeypatch):
    # The whole command (search over every candidate effect, evaluation, location, report, figure)
    # runs for real; only the optimiser is held to two steps per fit so that the test stays short.
    # Determinism does not depend on how many steps the optimiser takes.
    monkeypatch.setattr(_effects, "fit", functools.partial(_effects.fit, max_steps=2))
    a, b = _twice(tmp_path, capsys, ["diagnose", str(record), "--max-effects", "1"])
    _assert_identical(a, b)
    rep = json.loads((a / "report.json").read_text())
    assert len(rep["rounds"]) == 1 and set(rep["candidates"]) == set(_effects.EFFECTS)
