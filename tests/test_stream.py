"""Records read in chunks (`open_record_stream`): the same numbers as `load_record`, the cases it
leaves to `load_record`, and `estimate_record` / `piest estimate` on a stream equal to the record
read whole."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import piest_jax as pj
import piest_jax._data.record as R
import piest_jax._data.stream as S
from piest_jax._cli import main


def _record(n=5000, dt=1e-3, seed=0):
    t = np.arange(n) * dt
    u = 2 * np.sin(2 * np.pi * 3 * t) * (1 + 0.3 * np.sin(2 * np.pi * 0.4 * t))
    y = np.asarray(pj.PIOperator(np.array([0.0, 0.5, 1.0]), np.array([1.0, 0.5, 0.3]))(u))
    return t, u, y + 0.01 * np.random.default_rng(seed).normal(size=n)


def _write(path, header, rows, fmt="%.12g"):
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt=fmt)
    return path


@settings(max_examples=20, deadline=None)
@given(n=st.integers(8, 700), chunk=st.integers(1, 300), size=st.integers(1, 400))
def test_chunks_are_the_record_in_any_chunking(tmp_path_factory, n, chunk, size):
    path = _write(tmp_path_factory.mktemp("s") / "r.csv", "t,u,y", np.column_stack(_record(n)))
    old = S.CHUNK_ROWS
    S.CHUNK_ROWS = chunk
    try:
        stream = pj.open_record_stream(path)
    finally:
        S.CHUNK_ROWS = old
    rec = pj.load_record(path)
    u, y = (np.concatenate(c) for c in zip(*stream.chunks(size)))
    np.testing.assert_array_equal(u, rec.u)
    np.testing.assert_array_equal(y, rec.y)
    assert stream.n_samples == rec.n_samples and stream.t0 == rec.t[0]
    assert stream.dt == pytest.approx(rec.dt, rel=1e-9)
    assert (stream.u_min, stream.u_max, stream.u_first) == (rec.u.min(), rec.u.max(), rec.u[0])
    assert stream.y_peak == np.abs(rec.y).max()


def test_columns_units_and_data_without_time(tmp_path):
    t, u, y = _record(300)
    path = _write(tmp_path / "named.csv", "time_s,extra,voltage_V,displacement_um", np.column_stack([t, 0 * t, u, y]))
    stream = pj.open_record_stream(path, columns="time_s,voltage_V,displacement_um")
    rec = pj.load_record(path, columns="time_s,voltage_V,displacement_um")
    np.testing.assert_array_equal(np.concatenate([c[0] for c in stream.chunks(64)]), rec.u)
    path = _write(tmp_path / "units.csv", "t [s],u [V],y [um]", np.column_stack([t, u, y]))
    assert pj.open_record_stream(path).n_samples == 300
    path = _write(tmp_path / "index.csv", "u,y", np.column_stack([u, y]))
    stream, rec = pj.open_record_stream(path), pj.load_record(path)
    assert stream.time_is_index and rec.time_is_index and (stream.t0, stream.dt) == (0.0, 1.0)
    np.testing.assert_array_equal(np.concatenate([c[1] for c in stream.chunks(50)]), rec.y)


@pytest.mark.parametrize("case", ["comment", "quoted", "nan", "gap", "backwards", "segment", "short"])
def test_what_load_record_decides_is_left_to_it(tmp_path, case):
    t, u, y = _record(400)
    rows = [f"{a:.12g},{b:.12g},{c:.12g}" for a, b, c in zip(t, u, y)]
    header = "t,u,y"
    if case == "comment":
        rows.insert(10, "# a note")
    elif case == "quoted":
        rows[5] = '"0.005","1","2"'
    elif case == "nan":
        rows[7] = "0.007,nan,1"
    elif case == "gap":
        rows = rows[:100] + rows[120:]
    elif case == "backwards":
        rows[50], rows[51] = rows[51], rows[50]
    elif case == "segment":
        header = "t,u,y,segment"
        rows = [r + ",1" for r in rows]
    else:
        rows = rows[:5]
    path = tmp_path / "r.csv"
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    assert pj.open_record_stream(path) is None


def test_a_missing_column_is_named_as_load_record_names_it(tmp_path):
    path = _write(tmp_path / "r.csv", "t,u,z", np.column_stack(_record(100)))
    with pytest.raises(pj.DataError) as streamed:
        pj.open_record_stream(path)
    with pytest.raises(pj.DataError) as whole:
        pj.load_record(path)
    assert str(streamed.value) == str(whole.value)


@pytest.mark.parametrize("start", [0, 777])
def test_estimate_on_a_stream_equals_the_record_read_whole(tmp_path, start):
    path = _write(tmp_path / "r.csv", "t,u,y", np.column_stack(_record(6000)))
    old = S.CHUNK_ROWS
    S.CHUNK_ROWS = 1000  # the stream's chunks cut across the estimator's blocks
    try:
        stream = pj.open_record_stream(path)
        r = np.array([0.0, 0.4, 0.8, 1.2])
        kw = dict(dt=stream.dt, window=600, chunk=1800, start=start)
        a = pj.estimate_record(pj.ContinuousRLS(1e6, stream.dt), stream, None, r, **kw)
    finally:
        S.CHUNK_ROWS = old
    rec = pj.load_record(path)
    b = pj.estimate_record(pj.ContinuousRLS(1e6, stream.dt), rec.u, rec.y, r, **kw)
    for field in ("weights", "offset", "weights_trajectory", "error_rms", "pe_levels", "gram_bound", "initial_states"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    assert a.final_rmse == b.final_rmse
    assert pj.settled_start(stream) == pj.settled_start(rec.u)
    with pytest.raises(ValueError, match="give `y` as None"):
        pj.estimate_record(pj.ContinuousRLS(1e6, stream.dt), stream, rec.y, r, dt=stream.dt)


def test_cli_estimate_streams_a_large_file_and_writes_what_the_whole_read_writes(tmp_path, monkeypatch, capsys):
    path = _write(tmp_path / "r.csv", "t,u,y", np.column_stack(_record(8000)))
    argv = ["estimate", str(path), "--plays", "4"]
    assert main([*argv, "--out", str(tmp_path / "whole")]) == 0
    monkeypatch.setattr(R, "STREAM_BYTES", 1000)
    read = []
    monkeypatch.setattr(
        S.RecordStream, "_rows", lambda self, size, f=S.RecordStream._rows: read.append(size) or f(self, size)
    )
    assert main([*argv, "--out", str(tmp_path / "stream")]) == 0
    assert len(read) >= 4  # the check, the settled start, the estimate, the final RMSE
    a, b = (json.loads((tmp_path / d / "estimate.json").read_text()) for d in ("whole", "stream"))
    # the stream's dt is the mean step, the whole read's the median: equal up to rounding here
    np.testing.assert_allclose(a["weights_final"], b["weights_final"], rtol=1e-9)
    assert a["final_rmse"] == pytest.approx(b["final_rmse"], rel=1e-9)
    assert a["start_sample"] == b["start_sample"]


@pytest.mark.parametrize("estimator", ["rls", "gradient"])
def test_windows_longer_than_a_chunk_are_summed_over_chunks(estimator):
    t, u, y = _record(9000)
    r = np.array([0.0, 0.4, 0.8, 1.2])
    est = pj.ContinuousRLS(1e6, 1e-3) if estimator == "rls" else pj.NormalisedGradient(1.0)
    kw = dict(dt=1e-3, window=700, start=123)
    a = pj.estimate_record(est, u, y, r, chunk=256, **kw)  # every window spans several chunks
    b = pj.estimate_record(est, u, y, r, chunk=1400, **kw)  # two whole windows per chunk
    np.testing.assert_array_equal(a.weights_trajectory, b.weights_trajectory)
    assert a.pe_levels.shape == b.pe_levels.shape == ((9000 - 123) // 700,)
    np.testing.assert_allclose(a.pe_levels, b.pe_levels, rtol=1e-9)
    np.testing.assert_allclose(a.gram_bound, b.gram_bound, rtol=1e-9)
    np.testing.assert_array_equal(a.exciting, b.exciting)
