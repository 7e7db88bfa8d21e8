"""Loading measured records: formats that must load, and each rejection with its message."""

import types

import numpy as np
import pytest

import piest_jax as pj
from piest_jax import DataError, Record, dataset_path, datasets, load_dataset, load_record


def _rows(n=10, dt=0.5):
    t = dt * np.arange(n)
    return t, np.sin(t), np.cos(t)


def _csv(tmp_path, text, name="d.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _table(t, u, y, *, delim=",", header="t,u,y", extra=None):
    lines = [header.replace(",", delim)]
    for k in range(len(t)):
        cells = [t[k], u[k], y[k]] + ([extra[k]] if extra is not None else [])
        lines.append(delim.join(repr(float(c)) for c in cells))
    return "\n".join(lines) + "\n"


def test_csv_with_extra_column_kept(tmp_path):
    t, u, y = _rows()
    d = 2 * u
    rec = load_record(_csv(tmp_path, _table(t, u, y, header="t,u,y,desired", extra=d)))
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.u, u)
    np.testing.assert_array_equal(rec.y, y)
    assert list(rec.extras) == ["desired"]
    np.testing.assert_array_equal(rec.extras["desired"], d)
    assert rec.n_samples == 10 and rec.dt == pytest.approx(0.5)
    assert rec.source.endswith("d.csv")


def test_column_order_and_case_do_not_matter(tmp_path):
    t, u, y = _rows()
    text = "Y,T,U\n" + "".join(f"{y[k]:.17g},{t[k]:.17g},{u[k]:.17g}\n" for k in range(10))
    rec = load_record(_csv(tmp_path, text))
    np.testing.assert_array_equal(rec.u, u)
    np.testing.assert_array_equal(rec.y, y)


@pytest.mark.parametrize("delim", [";", "\t"])
def test_other_delimiters(tmp_path, delim):
    t, u, y = _rows()
    rec = load_record(_csv(tmp_path, _table(t, u, y, delim=delim)))
    np.testing.assert_array_equal(rec.y, y)


def test_preamble_and_comments_skipped(tmp_path):
    t, u, y = _rows()
    body = _table(t, u, y).splitlines()
    text = "Instrument: XY-500\nDate: 2024-01-01\n\n" + "\n".join(body[:4] + ["# a comment", ""] + body[4:])
    rec = load_record(_csv(tmp_path, text))
    np.testing.assert_array_equal(rec.t, t)


def test_npz_with_extra_arrays(tmp_path):
    t, u, y = _rows()
    p = tmp_path / "d.npz"
    np.savez(p, t=t, u=u, y=y, desired=3 * u, image=np.zeros((2, 2)))
    rec = load_record(p)
    np.testing.assert_array_equal(rec.u, u)
    assert list(rec.extras) == ["desired"]  # two-dimensional extras are not time series


def test_resample_onto_uniform_grid(tmp_path):
    t = np.r_[0.0, 1.0, 2.0, 3.5, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]
    u = 2.0 * t + 1.0
    rec = load_record(_csv(tmp_path, _table(t, u, -u)), resample=True)
    np.testing.assert_allclose(rec.t, np.arange(10.0))
    np.testing.assert_allclose(rec.u, 2.0 * np.arange(10.0) + 1.0, atol=1e-12)
    np.testing.assert_allclose(rec.y, -rec.u, atol=1e-12)


def test_slice_keeps_extras():
    t, u, y = _rows()
    rec = Record(t, u, y, {"d": u + 1}).slice(2, 5)
    assert rec.n_samples == 3
    np.testing.assert_array_equal(rec.extras["d"], u[2:5] + 1)


def _fails(tmp_path, text, match, **kw):
    with pytest.raises(DataError, match=match):
        load_record(_csv(tmp_path, text), **kw)


def test_missing_column(tmp_path):
    t, u, y = _rows()
    text = "t,u\n" + "".join(f"{t[k]},{u[k]}\n" for k in range(10))
    _fails(tmp_path, text, r"d\.csv, row 1: missing column\(s\) y: the header has t, u")


def test_no_header(tmp_path):
    t, u, y = _rows()
    text = _table(t, u, y).split("\n", 1)[1]
    _fails(tmp_path, text, r"no header row naming the columns t, u and y .*first line: '0\.0,")


def test_empty_file(tmp_path):
    _fails(tmp_path, "\n\n", "the file is empty")


def test_header_without_data(tmp_path):
    _fails(tmp_path, "t,u,y\n", "the header is there but no data rows follow")


def test_non_numeric_cell(tmp_path):
    t, u, y = _rows()
    lines = _table(t, u, y).splitlines()
    lines[4] = "1.5,abc,0.2"
    _fails(tmp_path, "\n".join(lines), r"row 5: cell 2 is not a number: 'abc' \(column `u`\)")


def test_wrong_cell_count(tmp_path):
    t, u, y = _rows()
    lines = _table(t, u, y).splitlines()
    lines[3] = "1.0,2.0"
    _fails(tmp_path, "\n".join(lines), r"row 4: expected 3 cells as in the header, found 2")


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_nan_or_inf(tmp_path, bad):
    t, u, y = _rows()
    lines = _table(t, u, y).splitlines()
    lines[6] = f"{t[5]},{u[5]},{bad}"
    message = rf"row 7: column `y` holds {bad} \(NaN or inf are not data\)"
    _fails(tmp_path, "\n".join(lines), message)


def test_too_few_samples(tmp_path):
    t, u, y = _rows(n=5)
    _fails(tmp_path, _table(t, u, y), r"only 5 samples; at least 8 are needed")
    assert load_record(_csv(tmp_path, _table(t, u, y)), min_samples=5).n_samples == 5


@pytest.mark.parametrize("t5, what", [(1.5, "repeats"), (1.25, "goes backwards")])
def test_time_not_strictly_increasing(tmp_path, t5, what):
    t, u, y = _rows()
    t = t.copy()
    t[4] = t5
    _fails(tmp_path, _table(t, u, y), rf"row 6: time is not strictly increasing: t = {t5} {what}")


def test_non_uniform_sampling(tmp_path):
    t, u, y = _rows()
    t = t.copy()
    t[6:] += 0.2
    _fails(
        tmp_path,
        _table(t, u, y),
        r"row 8: non-uniform sampling: step 0\.7 against the median 0\.5 .*resample=True",
    )
    # Within the tolerance it loads as is.
    t2 = 0.5 * np.arange(10.0)
    t2[6] += 1e-5
    assert load_record(_csv(tmp_path, _table(t2, u, y))).n_samples == 10


def test_duplicated_column(tmp_path):
    text = "t,u,y,u\n" + "0,1,2,3\n" * 3
    _fails(tmp_path, text, r"row 1: duplicated column name\(s\) in the header: u")


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        load_record(tmp_path / "absent.csv")
    with pytest.raises(DataError, match="is a folder, not a data file"):
        load_record(tmp_path)


def test_binary_file(tmp_path):
    p = tmp_path / "bin.csv"
    p.write_bytes(b"\xff\xfe\x00\x81" * 8)
    with pytest.raises(DataError, match=r"is not a text \(UTF-8\) CSV file"):
        load_record(p)


def test_npz_rejections(tmp_path):
    t, u, y = _rows()
    p = tmp_path / "d.npz"
    np.savez(p, t=t, u=u)
    with pytest.raises(DataError, match=r"missing array\(s\) y; found \['t', 'u'\]"):
        load_record(p)
    np.savez(p, t=t, u=u, y=y[:7])
    with pytest.raises(DataError, match=r"array `y` has 7 samples but `t` has 10"):
        load_record(p)
    np.savez(p, t=t, u=np.stack([u, u]), y=y)
    with pytest.raises(DataError, match=r"array `u` must be one-dimensional, got shape \(2, 10\)"):
        load_record(p)
    np.savez(p, t=t, u=u, y=np.array(["a"] * 10))
    with pytest.raises(DataError, match=r"array `y` is not numeric"):
        load_record(p)
    y_bad = y.copy()
    y_bad[3] = np.nan
    np.savez(p, t=t, u=u, y=y_bad)
    with pytest.raises(DataError, match=r"d\.npz: column `y` holds nan"):
        load_record(p)
    p.write_bytes(b"not a zip archive")
    with pytest.raises(DataError, match="cannot be read as NPZ"):
        load_record(p)


def test_record_shape_mismatch():
    t, u, y = _rows()
    with pytest.raises(DataError, match=r"column `y` has shape \(4,\), expected \(10,\)"):
        Record(t, u, y[:4])


def test_data_error_is_a_value_error():
    assert issubclass(DataError, ValueError)


def test_shipped_data_sets_all_load():
    names = datasets()
    assert len(names) >= 6 and "piezo_aye2018_identification" in names
    for name in names:
        path = dataset_path(name)
        assert path.name == f"{name}.csv" and path.is_file()
        if name.startswith("bh_"):
            # B-H loops: columns segment, H, B (no time axis): one segment a loop, t the sample.
            data = np.loadtxt(path, delimiter=",", skiprows=1)
            assert path.read_text().splitlines()[0] == "segment,H,B"
            rec = load_dataset(name, columns="H,B")
            assert rec.time_is_index and rec.dt == 1.0
            np.testing.assert_array_equal(rec.t, np.arange(len(data)))
            np.testing.assert_array_equal(np.c_[rec.segment, rec.u, rec.y], data)
            assert rec.n_segments == len(np.unique(data[:, 0])) >= 3
            with pytest.raises(DataError, match="no header row naming the columns t, u and y"):
                load_dataset(name)
        else:
            rec = load_dataset(name)
            assert rec.n_samples > 1000
            assert np.all(np.diff(rec.t) > 0)
            assert rec.source == str(path)
            np.testing.assert_array_equal(rec.y, load_record(path).y)
    val = load_dataset("piezo_aye2018_validation")
    assert "desired" in val.extras
    # The file name is accepted as well as the data set's name.
    assert dataset_path("piezo_aye2018_validation.csv") == dataset_path("piezo_aye2018_validation")


def test_dataset_path_unknown_name():
    with pytest.raises(ValueError, match=r"no shipped data set 'nope\.csv'; available: .*piezo"):
        dataset_path("nope.csv")


def test_public_names_are_the_loaders():
    assert pj.Record is Record and pj.load_record is load_record and issubclass(pj.DataError, ValueError)


def test_from_arrays_equals_the_file(tmp_path):
    t, u, y = _rows(20)
    d = 3 * u
    from_file = load_record(_csv(tmp_path, _table(t, u, y, header="t,u,y,desired", extra=d)))
    rec = Record.from_arrays(list(t), u, y.astype(np.float32), extras={"desired": d})
    for name in ("t", "u"):
        np.testing.assert_array_equal(getattr(rec, name), getattr(from_file, name))
    # A float32 column is widened, not kept in float32.
    assert rec.y.dtype == np.float64
    np.testing.assert_array_equal(rec.y, y.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(rec.extras["desired"], from_file.extras["desired"])
    assert rec.source == "<arrays>"


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda t, u, y: (t, u[:-1], y), r"<arrays>: column `u` has 19 samples but `t` has 20"),
        (lambda t, u, y: (t, u.reshape(4, 5), y), r"column `u` must be one-dimensional, got shape \(4, 5\)"),
        (lambda t, u, y: (t, u + 1j, y), r"column `u` is not real numbers \(dtype complex128\)"),
        (lambda t, u, y: (t, u, np.where(t > 3, np.nan, y)), r"column `y` holds nan"),
        (lambda t, u, y: (t[::-1], u, y), r"time is not strictly increasing"),
        (lambda t, u, y: (t[:3], u[:3], y[:3]), r"only 3 samples; at least 8 are needed"),
        (lambda t, u, y: (t**1.5, u, y), r"non-uniform sampling"),
    ],
)
def test_from_arrays_rejects_bad_columns(change, message):
    t, u, y = _rows(20)
    with pytest.raises(DataError, match=message):
        Record.from_arrays(*change(t, u, y))


def test_from_arrays_resamples_when_asked():
    t = np.array([0.0, 1.0, 2.0, 3.5, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
    rec = Record.from_arrays(t, 2 * t, -t, resample=True)
    np.testing.assert_allclose(rec.t, np.arange(10.0))
    np.testing.assert_allclose(rec.u, 2 * rec.t)


def test_from_dataframe_matches_from_arrays():
    pd = pytest.importorskip("pandas")
    t, u, y = _rows(12)
    df = pd.DataFrame({"T": t, "u": u, "Y": y, "desired": 2 * u})
    rec = Record.from_dataframe(df)
    ref = Record.from_arrays(t, u, y, extras={"desired": 2 * u})
    for name in ("t", "u", "y"):
        np.testing.assert_array_equal(getattr(rec, name), getattr(ref, name))
    np.testing.assert_array_equal(rec.extras["desired"], ref.extras["desired"])
    with pytest.raises(DataError, match=r"<DataFrame>: missing column\(s\) y: the frame has t, u"):
        Record.from_dataframe(df[["T", "u"]])


# Data without time and records made of segments (docs/data.md).


def _uy(n=20):
    k = np.arange(n)
    return np.sin(k / 3).tolist(), np.cos(k / 3).tolist()


@pytest.mark.parametrize("header, index", [("u,y", None), ("n,u,y", "n"), ("sample [#],y,u", "sample")])
def test_data_without_time_count_samples(tmp_path, header, index):
    u, y = _uy()
    names = [c.split(" ")[0] for c in header.split(",")]
    cols = {"u": u, "y": y, index: 1 + np.arange(20.0)}
    text = header + "\n" + "".join(",".join(repr(float(cols[c][k])) for c in names) + "\n" for k in range(20))
    rec = load_record(_csv(tmp_path, text))
    assert rec.time_is_index and rec.dt == 1.0 and rec.extras == {}
    np.testing.assert_array_equal(rec.t, cols[index] if index else np.arange(20.0))
    np.testing.assert_array_equal(rec.u, u)
    np.testing.assert_array_equal(rec.y, y)


def test_a_sample_index_with_a_missing_row_is_caught(tmp_path):
    u, y = _uy()
    text = "n,u,y\n" + "".join(f"{k},{u[k]!r},{y[k]!r}\n" for k in range(20) if k != 7)
    _fails(tmp_path, text, r"row 9: non-uniform sampling: step 2 against the median 1")


def test_a_time_column_by_another_name_is_not_taken_for_an_index(tmp_path):
    u, y = _uy()
    text = "time,u,y\n" + "".join(f"{0.1 * k!r},{u[k]!r},{y[k]!r}\n" for k in range(20))
    _fails(
        tmp_path,
        text,
        r"row 1: no time column `t`: the header has time, u, y; name its time, input and "
        r"output with columns=",
    )
    rec = load_record(_csv(tmp_path, text), columns="time,u,y")
    assert not rec.time_is_index and rec.dt == pytest.approx(0.1)


def test_two_columns_name_input_and_output(tmp_path):
    u, y = _uy()
    text = "H [A/m],B [T],t\n" + "".join(f"{u[k]!r},{y[k]!r},{9.0 - k}\n" for k in range(20))
    rec = load_record(_csv(tmp_path, text), columns=("H", "B"))
    assert rec.time_is_index
    np.testing.assert_array_equal(rec.t, np.arange(20.0))
    np.testing.assert_array_equal(rec.u, u)
    np.testing.assert_array_equal(rec.y, y)
    # The same from arrays, an NPZ without `t`, and a frame.
    same = [Record.from_arrays(None, u, y), load_record(_npz(tmp_path, u=u, y=y))]
    same.append(Record.from_dataframe(_Frame({"H [A/m]": u, "B": y, "t": 9.0 - np.arange(20)}), columns="H,B"))
    for r in same:
        assert r.time_is_index
        for name in ("t", "u", "y"):
            np.testing.assert_array_equal(getattr(r, name), getattr(rec, name))
    with pytest.raises(ValueError, match="columns= needs three distinct names, .* or two"):
        load_record(_csv(tmp_path, text), columns=("H",))


def _npz(tmp_path, **arrays):
    p = tmp_path / "d.npz"
    np.savez(p, **arrays)
    return p


class _Frame:
    """As much of a pandas DataFrame as `Record.from_dataframe` uses."""

    def __init__(self, cols):
        self._cols = cols
        self.columns = list(cols)

    def __getitem__(self, name):
        return types.SimpleNamespace(to_numpy=lambda: np.asarray(self._cols[name]))


def test_from_dataframe_takes_columns_as_load_record_does(tmp_path):
    t, u, y = _rows(12)
    frame = _Frame({"time_s": t, "voltage [V]": u, "displacement_um": y, "desired": 2 * u})
    rec = Record.from_dataframe(frame, columns=("time_s", "voltage", "displacement_um"))
    path = _csv(tmp_path, _table(t, u, y, header="time_s,voltage [V],displacement_um,desired", extra=2 * u))
    ref = load_record(path, columns="time_s,voltage,displacement_um")
    for name in ("t", "u", "y"):
        np.testing.assert_array_equal(getattr(rec, name), getattr(ref, name))
    np.testing.assert_array_equal(rec.extras["desired"], ref.extras["desired"])
    with pytest.raises(DataError, match=r"<DataFrame>: missing column\(s\) volts: the frame has time_s"):
        Record.from_dataframe(frame, columns="time_s,volts,displacement_um")


def _segmented(tmp_path, labels, t_of=lambda k, j: 0.5 * j, n=10, name="s.csv"):
    lines = ["segment,t,u,y"]
    for i, label in enumerate(labels):
        for j in range(n):
            k = i * n + j
            lines.append(f"{label},{t_of(i, j)!r},{float(np.sin(k / 3))!r},{float(np.cos(k / 3))!r}")
    return _csv(tmp_path, "\n".join(lines) + "\n", name)


def test_segments_restart_time_and_split_into_records(tmp_path):
    rec = load_record(_segmented(tmp_path, [3, 1, 2]))
    assert rec.n_segments == 3 and not rec.time_is_index and rec.extras == {}
    np.testing.assert_array_equal(rec.segment, np.repeat([3.0, 1.0, 2.0], 10))
    parts = rec.segments()
    assert [p.segment[0] for p in parts] == [3, 1, 2]
    for i, p in enumerate(parts):
        assert p.n_segments == 1 and p.n_samples == 10
        np.testing.assert_array_equal(p.t, 0.5 * np.arange(10))
        np.testing.assert_array_equal(p.u, np.sin((10 * i + np.arange(10)) / 3))
    np.testing.assert_array_equal(rec.select_segment(1).y, parts[1].y)
    with pytest.raises(DataError, match=r"no segment labelled 7; the labels are 3, 1, 2"):
        rec.select_segment(7)
    assert Record.from_arrays(*_rows(10)).segments()[0].n_samples == 10


def test_each_segment_is_checked_on_its_own(tmp_path):
    # Time restarting at a boundary is fine; inside a segment it must increase uniformly.
    with pytest.raises(DataError, match=r"row 22: segment 0 starts again after other segments \(it began at row 2\)"):
        load_record(_segmented(tmp_path, [0, 1, 0]))
    backwards = _segmented(tmp_path, [0, 1], t_of=lambda i, j: 0.5 * j if (i, j) != (1, 4) else 0.1)
    with pytest.raises(DataError, match=r"row 16: time is not strictly increasing"):
        load_record(backwards)
    slow = _segmented(tmp_path, [0, 1, 2], t_of=lambda i, j: (1.0 if i == 1 else 0.5) * j)
    with pytest.raises(DataError, match=r"row 13: non-uniform sampling: step 1 against the median 0.5"):
        load_record(slow)
    rec = load_record(slow, resample=True)
    assert [p.n_samples for p in rec.segments()] == [10, 19, 10]
    np.testing.assert_allclose(np.diff(rec.segments()[1].t), 0.5)
    # A short segment (a reversal curve that starts near saturation) is data; one of them taken
    # alone, and a whole record, must hold the minimum.
    short = "\n".join(
        ["segment,t,u,y"] + [f"0,{j},{np.sin(j)},{j}" for j in range(10)] + [f"1,{j},{np.sin(j)},{j}" for j in range(3)]
    )
    rec = load_record(_csv(tmp_path, short + "\n2,0,0.5,0.5\n"))
    assert [p.n_samples for p in rec.segments()] == [10, 3, 1]
    with pytest.raises(DataError, match=r"segment 1 has only 3 samples; at least 8 are needed"):
        rec.select_segment(1)
    with pytest.raises(DataError, match=r"only 6 samples; at least 8 are needed"):
        load_record(_csv(tmp_path, "segment,t,u,y\n" + "".join(f"{k // 3},{k % 3},{k},{k}\n" for k in range(6))))


def test_joined_segments_follow_one_another(tmp_path):
    rec = load_record(_segmented(tmp_path, [3, 1, 2]))
    j = rec.joined()
    # One uniform time through all segments, from the first sample; samples, order and labels kept.
    np.testing.assert_allclose(j.t, 0.5 * np.arange(30), rtol=0, atol=1e-12)
    for name in ("u", "y", "segment"):
        np.testing.assert_array_equal(getattr(j, name), getattr(rec, name))
    assert j.n_segments == 3 and [p.n_samples for p in j.segments()] == [10, 10, 10]
    one = load_record(_csv(tmp_path, "t,u,y\n" + "".join(f"{k},{k % 3},{k}\n" for k in range(9)), "one.csv"))
    assert one.joined() is one
    index = load_record(_csv(tmp_path, "segment,u,y\n" + "".join(f"{k // 4},{k},{k}\n" for k in range(12)), "i.csv"))
    np.testing.assert_array_equal(index.joined().t, np.arange(12.0))
    singles = Record.from_arrays(
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], np.arange(8.0), np.arange(8.0), segment=np.arange(8)
    )
    with pytest.raises(DataError, match="no segment has two samples"):
        singles.joined()


def test_a_segment_column_of_an_index_record(tmp_path):
    text = "segment,u,y\n" + "".join(f"{k // 12},{float(np.sin(k))!r},{float(np.cos(k))!r}\n" for k in range(36))
    rec = load_record(_csv(tmp_path, text))
    assert rec.time_is_index and rec.n_segments == 3
    np.testing.assert_array_equal(rec.t, np.arange(36.0))
    seg = Record.from_arrays(None, rec.u, rec.y, segment=rec.segment)
    np.testing.assert_array_equal(seg.segment, rec.segment)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_joined_reversal_curves_keep_the_history_they_were_measured_after(seed):
    # First-order reversal curves: the input comes down from saturation to a reversal field
    # (not recorded), then goes up to saturation (recorded, one segment per curve). The plays
    # run on the joined record equal the plays run on the whole history, at the recorded
    # samples: a monotone descent leaves the state the direct jump leaves.
    rng = np.random.default_rng(seed)
    sat, whole, at, labels = 1.0, [1.0], [0], [0]
    for i, hr in enumerate(np.sort(rng.uniform(-sat, sat, 12))):
        whole += list(np.linspace(sat, hr, int(rng.integers(3, 30)))[1:-1])
        up = np.linspace(hr, sat, int(rng.integers(2, 25)))
        at += range(len(whole), len(whole) + len(up))
        whole += list(up)
        labels += [i + 1] * len(up)
    history = np.asarray(whole)
    op = pj.PIOperator(np.linspace(0.0, 0.8, 6), rng.uniform(0.2, 1.0, 6))
    rec = Record.from_arrays(None, history[at], history[at], segment=labels).joined()
    assert rec.n_segments == 13
    np.testing.assert_allclose(np.asarray(op(rec.u)), np.asarray(op(history))[at], rtol=0, atol=1e-12)
