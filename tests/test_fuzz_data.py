"""Hostile data files: every file either loads exactly or raises one `DataError` naming the file,
the row (the line number in the file, counting from 1) and the problem.

A few hundred corrupted files are generated from clean records (every kind of damage at many rows,
with several delimiters and preambles), hypothesis explores formats and magnitudes, and random text
and bytes must never escape as anything but a `DataError`.
"""

import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from piest_jax._data import record as _record
from piest_jax._data.record import MIN_SAMPLES, DataError, load_record

N_ROWS = 16


@pytest.fixture(autouse=True, scope="module", params=["lines", "stream"])
def reader(request):
    """Every test twice: small files as the line-by-line parser reads them, and as a large file is
    read (NumPy's parser straight from disk first, the line-by-line one for whatever it leaves)."""
    default = _record.STREAM_BYTES
    _record.STREAM_BYTES = 0 if request.param == "stream" else default
    yield request.param
    _record.STREAM_BYTES = default


def _clean(n=N_ROWS, scale_u=1.0, scale_y=1.0, dt=0.01, t0=0.0):
    k = np.arange(n)
    return t0 + dt * k, scale_u * np.sin(0.7 * k), scale_y * np.cos(0.3 * k) + 0.1 * k


def _render(t, u, y, *, delim=",", preamble=(), header="t,u,y", cells=None):
    """The file text and the line number (from 1) of each data row."""
    lines = list(preamble) + [header.replace(",", delim)]
    rows = []
    for k in range(len(t)):
        c = [repr(float(t[k])), repr(float(u[k])), repr(float(y[k]))] if cells is None else cells[k]
        lines.append(delim.join(c))
        rows.append(len(lines))
    return "\n".join(lines) + "\n", rows


def _write(tmp_path, text, name="d.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _expect(path, pattern):
    with pytest.raises(DataError) as exc:
        load_record(path)
    msg = str(exc.value)
    assert msg.startswith(str(path)), msg
    assert "\n" not in msg
    assert re.search(pattern, msg), msg
    return msg


# ---------------------------------------------------------------- damage that must be named


def _damage(kind, k, t, u, y):
    """Cells with one kind of damage at data row k; returns (cells, message pattern, bad row)."""
    cells = [[repr(float(a)), repr(float(b)), repr(float(c))] for a, b, c in zip(t, u, y)]
    if kind == "text":
        cells[k][1] = "abc"
        return cells, r"cell 2 is not a number: 'abc' \(column `u`\)", k
    if kind == "empty_cell":
        cells[k][2] = ""
        return cells, r"cell 3 is not a number: '' \(column `y`\)", k
    if kind == "missing_cell":
        cells[k] = cells[k][:2]
        return cells, r"expected 3 cells as in the header, found 2", k
    if kind == "extra_cell":
        cells[k] = cells[k] + ["1.0"]
        return cells, r"expected 3 cells as in the header, found 4", k
    if kind in ("nan_u", "inf_y", "-inf_t"):
        col = {"t": 0, "u": 1, "y": 2}[kind[-1]]
        cells[k][col] = kind.split("_")[0]
        return cells, rf"column `{kind[-1]}` holds {kind.split('_')[0]} \(NaN or inf are not data\)", k
    if kind == "overflow":
        cells[k][1] = "1e999"
        return cells, r"column `u` holds inf", k
    if kind == "repeat_t":
        cells[k][0] = cells[k - 1][0]
        return cells, r"time is not strictly increasing: t = .* repeats", k
    if kind == "backwards_t":
        cells[k][0] = repr(float(t[k - 1] - 0.5 * (t[1] - t[0])))
        return cells, r"time is not strictly increasing: t = .* goes backwards", k
    if kind == "gap":
        for j in range(k, len(t)):
            cells[j][0] = repr(float(t[j] + 3 * (t[1] - t[0])))
        return cells, r"non-uniform sampling: step .* against the median", k
    raise AssertionError(kind)


KINDS = [
    "text",
    "empty_cell",
    "missing_cell",
    "extra_cell",
    "nan_u",
    "inf_y",
    "-inf_t",
    "overflow",
    "repeat_t",
    "backwards_t",
    "gap",
]
PREAMBLES = [(), ("Instrument: scope 3", "Channel 1; 10 V", ""), ("# exported", "# by hand")]


def _corpus():
    """The generated bad files: every kind of damage at several rows, delimiters and preambles."""
    out = []
    for kind in KINDS:
        for k in (1, 2, 7, N_ROWS // 2, N_ROWS - 1):
            for delim in (",", ";", "\t"):
                for pre in range(len(PREAMBLES)):
                    out.append((kind, k, delim, pre))
    return out


CORPUS = _corpus()


def test_corpus_is_a_few_hundred_files():
    assert len(CORPUS) >= 400


def test_every_damaged_file_names_file_row_and_problem(tmp_path):
    t, u, y = _clean()
    for i, (kind, k, delim, pre) in enumerate(CORPUS):
        cells, pattern, bad = _damage(kind, k, t, u, y)
        text, rows = _render(t, u, y, delim=delim, preamble=PREAMBLES[pre], cells=cells)
        path = _write(tmp_path, text, f"bad{i}.csv")
        _expect(path, rf"^{re.escape(str(path))}, row {rows[bad]}: {pattern}")


@pytest.mark.parametrize(
    "text, pattern",
    [
        ("", r": the file is empty$"),
        ("\n   \n\t\n", r": the file is empty$"),
        ("t,u,y\n", r": the header is there but no data rows follow"),
        ("# comment\nt,u,y\n# nothing else\n\n", r": the header is there but no data rows follow"),
        ("secs,volts,disp\n0,1,2\n", r": no header row naming the columns t, u and y"),
        ("1,2,3\n4,5,6\n", r": no header row naming the columns t, u and y .*first line: '1,2,3'"),
        ("t,u,x\n0,1,2\n", r", row 1: missing column\(s\) y: the header has t, u, x"),
        ("t,u,y,u\n0,1,2,3\n", r", row 1: duplicated column name\(s\) in the header: u"),
        ("t,u,y\n0,1,2\n", r": only 1 sample; at least 8 are needed"),
        (
            "t,u,y,note\n" + "".join(f"{k},1,2,ok\n" for k in range(9)),
            r", row 2: cell 4 is not a number: 'ok' \(column `note`\)",
        ),
    ],
)
def test_structural_problems(tmp_path, text, pattern):
    _expect(_write(tmp_path, text), pattern)


def test_missing_folder_and_device(tmp_path):
    for path, pattern in [
        (tmp_path / "absent.csv", "no such file"),
        (tmp_path, "is a folder, not a data file"),
        ("/dev/null", "is not a regular file"),
    ]:
        with pytest.raises(DataError, match=f"^{re.escape(str(path))}: {pattern}$"):
            load_record(path)


def test_binary_and_wrong_encoding(tmp_path):
    p = tmp_path / "scope.csv"
    p.write_bytes(bytes(range(256)) * 4)
    _expect(p, r"is not a text \(UTF-8\) CSV file")
    p.write_bytes("t,u,y\n# réglage\n0,1,2\n".encode("latin-1"))
    _expect(p, r"is not a text \(UTF-8\) CSV file")


def test_npz_damage(tmp_path):
    t, u, y = _clean()
    p = tmp_path / "d.npz"
    cases = [
        (dict(t=t, u=u + 1j, y=y), r"array `u` is complex"),
        (dict(t=t, u=u > 0, y=y), r"array `u` is not numeric \(dtype bool\)"),
        (dict(t=t[:1].reshape(()), u=u, y=y), r"array `t` must be one-dimensional, got shape \(\)"),
        (dict(t=t, u=u, y=np.where(np.arange(N_ROWS) == 3, np.inf, y)), r"column `y` holds inf"),
        (dict(t=t[::-1], u=u, y=y), r"time is not strictly increasing"),
        (dict(), r"missing array\(s\) t, u, y"),
    ]
    for arrays, pattern in cases:
        np.savez(p, **arrays)
        _expect(p, pattern)
    np.savez(p, t=t, u=u, y=y)
    p.write_bytes(p.read_bytes()[:200])
    _expect(p, r"cannot be read as NPZ")


def test_resampling_refuses_to_invent_a_record(tmp_path):
    t, u, y = _clean()
    t = t.copy()
    t[9:] += 1000.0
    text, rows = _render(t, u, y)
    p = _write(tmp_path, text)
    with pytest.raises(DataError, match=rf"row {rows[9]}: a gap of .* is too long to resample"):
        load_record(p, resample=True)
    # A short gap is interpolated: the grid is uniform and the data points are kept.
    t2 = _clean()[0].copy()
    t2[9:] += 0.02
    rec = load_record(_write(tmp_path, _render(t2, u, y)[0], "g.csv"), resample=True)
    np.testing.assert_allclose(np.diff(rec.t), 0.01, rtol=1e-9)
    assert rec.n_samples == N_ROWS + 2 and rec.u[0] == u[0]
    assert rec.u[-1] == pytest.approx(u[-1], rel=1e-9)


# ---------------------------------------------------------------- files that must load exactly


@given(
    n=st.integers(MIN_SAMPLES, 40),
    su=st.sampled_from([1e-9, 1e-6, 1e-3, 1.0, 1e3, 1e6, 1e9]),
    sy=st.sampled_from([1e-9, 1e-6, 1.0, 1e6, 1e9]),
    dt=st.sampled_from([1e-6, 1e-3, 0.25, 10.0]),
    t0=st.sampled_from([0.0, -5.0, 1e6]),
    delim=st.sampled_from([",", ";", "\t"]),
    pre=st.integers(0, len(PREAMBLES) - 1),
    header=st.sampled_from(["t,u,y", "T,U,Y", "y,t,u", '"t","u","y"', "t,u,y,desired", "t,u,y,"]),
    crlf=st.booleans(),
    constant=st.sampled_from([None, "u", "y"]),
)
def test_clean_files_load_exactly(tmp_path_factory, n, su, sy, dt, t0, delim, pre, header, crlf, constant):
    t, u, y = _clean(n, su, sy, dt, t0)
    if constant:  # constant channels are data: the loader keeps them, commands decide
        (u if constant == "u" else y)[:] = 0.5 * (su if constant == "u" else sy)
    names = [c.strip('"').lower() for c in header.split(",")]
    cols = {"t": t, "u": u, "y": y, "desired": 2 * u, "": None}
    cells = [[repr(float(cols[c][k])) if c else "" for c in names] for k in range(n)]
    text, _ = _render(t, u, y, delim=delim, preamble=PREAMBLES[pre], header=header, cells=cells)
    if crlf:
        text = text.replace("\n", "\r\n")
    p = tmp_path_factory.mktemp("ok") / "rec.csv"
    p.write_bytes(text.encode())
    rec = load_record(p)
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.u, u)
    np.testing.assert_array_equal(rec.y, y)
    assert list(rec.extras) == (["desired"] if "desired" in names else [])


@given(
    kind=st.sampled_from(KINDS),
    k=st.integers(1, N_ROWS - 1),
    su=st.sampled_from([1e-9, 1.0, 1e9]),
    pre=st.integers(0, len(PREAMBLES) - 1),
)
def test_damage_anywhere_is_found(tmp_path_factory, kind, k, su, pre):
    t, u, y = _clean(scale_u=su)
    cells, pattern, bad = _damage(kind, k, t, u, y)
    text, rows = _render(t, u, y, preamble=PREAMBLES[pre], cells=cells)
    p = tmp_path_factory.mktemp("bad") / "rec.csv"
    p.write_text(text)
    _expect(p, rf", row {rows[bad]}: {pattern}")


_CELL = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["", " ", "nan", "-", "1e", "0x10", '"1"', "1,5", "#", "t", "u", "y"]),
    st.text(max_size=6),
)


@given(
    header=st.lists(st.sampled_from(["t", "u", "y", "x", "", "T", "time"]), min_size=0, max_size=5),
    body=st.lists(st.lists(_CELL, min_size=0, max_size=5), min_size=0, max_size=12),
    delim=st.sampled_from([",", ";", "\t"]),
)
def test_random_text_loads_or_raises_data_error(tmp_path_factory, header, body, delim):
    text = delim.join(header) + "\n" + "\n".join(delim.join(r) for r in body)
    p = tmp_path_factory.mktemp("rnd") / "r.csv"
    p.write_text(text, encoding="utf-8", errors="replace")
    try:
        rec = load_record(p)
    except DataError as e:
        assert str(e).startswith(str(p)) and "\n" not in str(e)
        return
    assert rec.n_samples >= MIN_SAMPLES
    assert np.all(np.isfinite(rec.t)) and np.all(np.isfinite(rec.u)) and np.all(np.isfinite(rec.y))
    assert np.all(np.diff(rec.t) > 0)


@given(data=st.binary(max_size=300))
def test_random_bytes_load_or_raise_data_error(tmp_path_factory, data):
    d = tmp_path_factory.mktemp("bytes")
    for name in ("b.csv", "b.npz"):
        p = d / name
        p.write_bytes(data)
        with pytest.raises(DataError, match=re.escape(str(p))):
            load_record(p)


# ---------------------------------------------------------------- one deliberately long file


@pytest.fixture(scope="module")
def long_file(tmp_path_factory):
    n = 200_000
    t, u, y = _clean(n, 1e-3, 1e4, 1e-5)
    p = tmp_path_factory.mktemp("long") / "long.csv"
    with open(p, "w") as f:
        f.write("# long record\nt,u,y\n")
        np.savetxt(f, np.column_stack([t, u, y]), delimiter=",", fmt="%.17g")
    return p, (t, u, y)


def test_long_file_loads_exactly_and_damage_near_its_end_is_located(long_file, tmp_path):
    path, (t, u, y) = long_file
    rec = load_record(path)
    assert rec.n_samples == len(t)
    np.testing.assert_array_equal(rec.u, u)
    np.testing.assert_array_equal(rec.y, y)
    lines = path.read_text().splitlines()
    lines[-3] = lines[-3].rsplit(",", 1)[0] + ",12.5 V"
    bad = _write(tmp_path, "\n".join(lines) + "\n", "long_bad.csv")
    _expect(bad, rf"row {len(lines) - 2}: cell 3 is not a number: '12.5 V' \(column `y`\)")
    assert load_record(path).n_samples == len(t)  # the input file is untouched
