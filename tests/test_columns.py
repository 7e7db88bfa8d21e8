"""Columns as users name them: units in the header, names chosen with `columns=` / `--columns`,
quoted numbers; and what only looks like a number (`1_000`, digits of other scripts) refused."""

import json

import numpy as np
import pytest

import piest_jax as pj
from piest_jax._cli import main

T = 0.01 * np.arange(300)
U = 2 * np.sin(2 * np.pi * T)
Y = 0.5 * U + 0.1 * np.cos(2 * np.pi * T)


def _write(path, header, quote="", delim=","):
    rows = zip(T.tolist(), U.tolist(), Y.tolist())
    body = "".join(delim.join(f"{quote}{v!r}{quote}" for v in row) + "\n" for row in rows)
    path.write_text(header + "\n" + body)
    return path


def _run(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.mark.parametrize(
    "header, order",
    [
        ("Time [s],Voltage [V],Displacement [um]", (0, 1, 2)),
        ("time_s,input_V,output_um", (0, 1, 2)),
        ("Displacement (um);Time (s);Voltage (V)", (1, 2, 0)),
    ],
)
def test_headers_name_their_roles_by_leading_word(header, order, tmp_path):
    # `order`: the file's column of t, u and y.
    cols = [None] * 3
    for signal, i in zip((T, U, Y), order):
        cols[i] = signal
    delim = ";" if ";" in header else ","
    body = "".join(delim.join(repr(float(c[k])) for c in cols) + "\n" for k in range(T.size))
    path = tmp_path / "r.csv"
    path.write_text(header + "\n" + body)
    rec = pj.load_record(path)
    np.testing.assert_array_equal(rec.t, T)
    np.testing.assert_array_equal(rec.u, U)
    np.testing.assert_array_equal(rec.y, Y)
    assert rec.extras == {}


def test_two_columns_of_one_role_are_not_guessed(tmp_path):
    path = _write(tmp_path / "r.csv", "Time [s],Voltage [V],Voltage [mV]")
    with pytest.raises(pj.DataError, match="no header row naming the columns t, u and y"):
        pj.load_record(path)


@pytest.mark.parametrize("header", ["t [s],u [V],y [um]", '"T (s)";"U (V)";"Y [µm]"', "t,u ( V ),y[um]"])
def test_units_in_the_header_match_by_name(header, tmp_path):
    delim = ";" if ";" in header else ","
    rec = pj.load_record(_write(tmp_path / "r.csv", header, delim=delim))
    np.testing.assert_array_equal(rec.u, U)
    np.testing.assert_array_equal(rec.y, Y)


def test_quoted_numbers_are_read(tmp_path):
    rec = pj.load_record(_write(tmp_path / "q.csv", '"t","u","y"', quote='"'))
    np.testing.assert_array_equal(rec.t, T)
    np.testing.assert_array_equal(rec.u, U)


def test_columns_name_the_file_s_columns(tmp_path):
    path = _write(tmp_path / "n.csv", "time_s,voltage_V,displacement_um")
    for columns in (("time_s", "voltage_V", "displacement_um"), "TIME_S,voltage_v,displacement_um"):
        rec = pj.load_record(path, columns=columns)
        np.testing.assert_array_equal(rec.y, Y)
        assert rec.extras == {}
    # Their leading words name the roles: read without columns= too.
    np.testing.assert_array_equal(pj.load_record(path).y, Y)
    other = _write(tmp_path / "o.csv", "secs,volts,disp_um")
    with pytest.raises(ValueError, match=r"no header row naming the columns t, u and y .*columns="):
        pj.load_record(other)
    with pytest.raises(ValueError, match="columns= needs three distinct names"):
        pj.load_record(path, columns=("time_s", "time_s", "voltage_V"))
    with pytest.raises(ValueError, match=r"missing column\(s\) y_um"):
        pj.load_record(path, columns="time_s,voltage_V,y_um")


def test_columns_in_an_npz(tmp_path):
    path = tmp_path / "r.npz"
    np.savez(path, time=T, volts=U, um=Y, t=np.zeros_like(T))
    rec = pj.load_record(path, columns=("time", "volts", "um"))
    np.testing.assert_array_equal(rec.t, T)
    assert "t" not in rec.extras  # the chosen time column is `t`; the file's own `t` is not kept


@pytest.mark.parametrize("cell", ["1_000", "\u0661\u0662", "\uff11", "0x10", "1d5"])
def test_what_only_looks_like_a_number_is_refused(cell, tmp_path):
    lines = ["t,u,y"] + [f"{a!r},{b!r},{c!r}" for a, b, c in zip(T.tolist(), U.tolist(), Y.tolist())]
    lines[5] = f"{float(T[4])!r},{cell},1"
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(ValueError, match=rf"row 6: cell 2 is not a number: {cell!r}"):
        pj.load_record(path)


def test_piest_fit_with_columns_fits_the_record(tmp_path, capsys):
    named = _write(tmp_path / "n.csv", "time_s,voltage_V,displacement_um")
    units = _write(tmp_path / "u.csv", "t [s],u [V],y [um]")
    plain = _write(tmp_path / "p.csv", "t,u,y")
    reports = []
    for argv in ([str(named), "--columns", "time_s,voltage_V,displacement_um"], [str(units)], [str(plain)]):
        out = tmp_path / f"o{len(reports)}"
        code, _, err = _run(
            capsys,
            [
                "fit",
                *argv,
                "--model",
                "pi",
                "--plays",
                "2",
                "--starts",
                "2",
                "--max-steps",
                "40",
                "--quiet",
                "--out",
                str(out),
            ],
        )
        assert code == 0, err
        reports.append(json.loads((out / "fit.json").read_text()))
    # The same fit as of the file with the usual names.
    for rep in reports[:2]:
        assert (rep["thresholds"], rep["weights"], rep["rmse"]) == (
            reports[2]["thresholds"],
            reports[2]["weights"],
            reports[2]["rmse"],
        )


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["fit", "x.csv", "--columns", "a,b,c,d"], "argument --columns: expected 2 or 3 distinct column names"),
        (["fit", "x.csv", "--columns", "a,A,b"], "expected 2 or 3 distinct column names"),
        (["fit", "x.csv", "--columns", "a,A"], "expected 2 or 3 distinct column names"),
        (["compensate", "m.json", "d.csv", "--columns", "t,d,e"], "expected 2 distinct column names"),
        (["simulate", "--columns", "a,b,c"], "--columns is only used with --input csv"),
        (["simulate", "--resample"], "--resample is only used with --input csv"),
    ],
)
def test_bad_columns_give_one_line(argv, needle, tmp_path, capsys):
    code, out, err = _run(capsys, [*argv, "--out", str(tmp_path / "o")])
    assert (code, out) == (2, "") and err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "o").exists()


def test_compensate_with_columns(tmp_path, capsys):
    model = tmp_path / "m.json"
    model.write_text(json.dumps({"thresholds": [0, 0.5], "weights": [1, 0.5], "offset": 0.0}))
    desired = _write(tmp_path / "d.csv", "time [s],input,target [um]")
    out = tmp_path / "o"
    code, _, err = _run(
        capsys, ["compensate", str(model), str(desired), "--columns", "time,target", "--quiet", "--out", str(out)]
    )
    assert code == 0, err
    res = np.loadtxt(out / "compensate.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(res[:, 1], Y)
    np.testing.assert_allclose(res[:, 3], Y, atol=1e-9)


def test_one_segment_of_a_record_without_time(tmp_path, capsys):
    # B-H loops as the shipped files hold them: segment, H, B. One loop, chosen with --segment,
    # fits as the same loop written alone; its time counts samples, which the command says.
    k = np.arange(120)
    h = np.repeat([1.0, 2.0, 3.0], 40) * np.cos(2 * np.pi * k / 40)
    b = np.asarray(pj.PIOperator([0.0, 0.4], [1.0, 0.5])(h))
    loops = tmp_path / "loops.csv"
    loops.write_text(
        "segment,H [A/m],B [T]\n"
        + "".join(f"{k // 40},{a!r},{c!r}\n" for k, (a, c) in enumerate(zip(h.tolist(), b.tolist())))
    )
    alone = tmp_path / "alone.csv"
    alone.write_text("u,y\n" + "".join(f"{a!r},{c!r}\n" for a, c in zip(h[40:80].tolist(), b[40:80].tolist())))
    reps, errs = [], []
    # --segment picks from the data file; the --validate record (of one segment) is read whole.
    val = tmp_path / "val.csv"
    val.write_text("H,B\n" + alone.read_text().split("\n", 1)[1])
    first = [str(loops), "--columns", "H,B", "--segment", "1", "--validate", str(val)]
    for name, argv in (("a", first), ("b", [str(alone)])):
        code, _, err = _run(
            capsys,
            [
                "fit",
                *argv,
                "--model",
                "pi",
                "--plays",
                "2",
                "--starts",
                "2",
                "--max-steps",
                "30",
                "--quiet",
                "--out",
                str(tmp_path / name),
            ],
        )
        assert code == 0, err
        reps.append(json.loads((tmp_path / name / "fit.json").read_text()))
        errs.append(err)
    a, b_ = reps
    assert (a["thresholds"], a["weights"], a["rmse"]) == (b_["thresholds"], b_["weights"], b_["rmse"])
    assert a["n_samples"] == 40 and a["dt"] == 1.0 and a["validation_rmse"] == pytest.approx(a["rmse"], rel=1e-6)
    assert (a["time_unit"], a["segment"]) == ("sample", 1.0) and b_["time_unit"] == "sample" and "segment" not in b_
    for path in (loops, val):
        assert (
            f"piest fit: note: {path} has no time in seconds: t counts samples (step 1), so the times, time "
            "constants and rates in the results are in samples\n"
        ) in errs[0]


def test_every_command_reading_a_record_says_its_time_counts_samples(tmp_path, capsys):
    k = np.arange(600)
    u = np.sin(2 * np.pi * k / 100) * (1 + 0.5 * np.sin(2 * np.pi * k / 370))
    y = 0.5 * u + 0.1 * np.cos(2 * np.pi * k / 100)
    data = tmp_path / "uy.csv"
    data.write_text("u,y\n" + "".join(f"{a!r},{b!r}\n" for a, b in zip(u.tolist(), y.tolist())))
    runs = {
        "diagnose": (
            [str(data), "--max-effects", "1", "--candidates", "creep", "--solver", "none"],
            "report.json",
            lambda rep: rep["time_unit"],
        ),
        "estimate": ([str(data), "--plays", "3"], "estimate.json", lambda rep: rep["time_unit"]),
        "simulate": (["--input", "csv", "--csv", str(data)], "simulate.json", lambda rep: rep["input"]["time_unit"]),
    }
    for command, (argv, name, unit) in runs.items():
        out = tmp_path / command
        code, _, err = _run(capsys, [command, *argv, "--quiet", "--out", str(out)])
        assert code == 0, err
        assert unit(json.loads((out / name).read_text())) == "sample"
        assert f"piest {command}: note: {data} has no time in seconds: t counts samples (step 1)" in err


def test_segments_are_joined_in_the_files_order(tmp_path, capsys):
    # Loops of growing amplitude, each a segment: without --segment the data file and the
    # --validate file are taken one segment after another, as the same rows written as one run.
    k = np.arange(120)
    h = np.repeat([1.0, 2.0, 3.0], 40) * np.cos(2 * np.pi * k / 40)
    b = np.asarray(pj.PIOperator([0.0, 0.4], [1.0, 0.5])(h)) + 0.01 * np.sin(0.37 * k)
    loops, run = tmp_path / "loops.csv", tmp_path / "run.csv"
    loops.write_text(
        "segment,H,B\n" + "".join(f"{i // 40},{a!r},{c!r}\n" for i, a, c in zip(k, h.tolist(), b.tolist()))
    )
    run.write_text("H,B\n" + "".join(f"{a!r},{c!r}\n" for a, c in zip(h.tolist(), b.tolist())))
    fits, errs = [], []
    for name, path in (("a", loops), ("b", run)):
        argv = ["fit", str(path), "--columns", "H,B", "--validate", str(loops), "--model", "pi", "--plays", "2"]
        code, _, err = _run(capsys, [*argv, "--starts", "2", "--max-steps", "30", "--out", str(tmp_path / name)])
        assert code == 0, err
        fits.append(json.loads((tmp_path / name / "fit.json").read_text()))
        errs.append(err)
    a, b_ = fits
    for key in ("thresholds", "weights", "rmse", "validation_rmse", "validation_rmse_ic"):
        np.testing.assert_allclose(a[key], b_[key], rtol=1e-12, atol=0)
    assert a["segments_joined"] == 3 and "segments_joined" not in b_ and a["n_samples"] == 120
    note = f"{loops} holds 3 segments, taken one after another in the file's order: the plays' memory runs on"
    assert note in errs[0] and "; --segment LABEL takes one of them" in errs[0]
    assert note in errs[1] and "--segment LABEL" not in errs[1].split(note)[1].split("\n")[0]
