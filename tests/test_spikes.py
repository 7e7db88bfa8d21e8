"""Isolated spikes in a measured output (sensor glitches): found where they are, nowhere else."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from piest_jax._cli import main
from piest_jax._data.spikes import isolated_spikes, without_spikes


def smooth(seed, T=800, noise=0.01):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 8, T)
    y = 3 * np.sin(2 * np.pi * 0.5 * t) + np.where(t > 4, 1.5, 0.0)  # a loop and a step that stays
    return y + noise * rng.standard_normal(T)


def brute_force(y, sigmas=20.0, share=0.01):
    """The definition, sample by sample."""
    d2 = np.diff(y, 2)
    moving = d2[d2 != 0]
    sigma = 1.4826 * np.median(np.abs(moving - np.median(moving)))
    lo, hi = np.percentile(y, [1, 99])
    floor = max(sigmas * sigma, share * (hi - lo))
    found = []
    for i in range(1, len(y) - 1):
        a, b = y[i] - y[i - 1], y[i + 1] - y[i]
        small = min(abs(a), abs(b))
        left = abs(y[i - 1] - y[i - 2]) if i >= 2 else 0.0
        right = abs(y[i + 2] - y[i + 1]) if i + 2 < len(y) else 0.0
        if np.sign(a) == -np.sign(b) and small > floor and abs(y[i + 1] - y[i - 1]) < 0.5 * small:
            if max(left, right) < 0.25 * small:
                found.append(i)
    return found


@settings(max_examples=40, deadline=None)
@given(
    st.integers(0, 2**31 - 1),
    st.integers(2, 797).filter(lambda r: abs(r - 400) > 3),  # not on the step itself
    st.floats(1.5, 1e3),
    st.sampled_from([-1.0, 1.0]),
)
def test_a_glitch_is_found_where_it_is(seed, row, size, sign):
    y = smooth(seed)
    assert isolated_spikes(y).tolist() == []
    y[row] += sign * size
    assert isolated_spikes(y).tolist() == [row] == brute_force(y)
    np.testing.assert_allclose(without_spikes(y, [row])[row], 0.5 * (y[row - 1] + y[row + 1]))


def test_steps_and_ringing_are_not_spikes():
    y = smooth(1)
    t = np.arange(y.size)
    # Ringing after a step, near the sampling rate: every increment large, but none isolated.
    ring = np.where(t > 300, 2.0 * (-1.0) ** t * np.exp(-(t - 300) / 6.0), 0.0)
    assert isolated_spikes(y + ring).tolist() == [] == brute_force(y + ring)
    assert isolated_spikes(np.zeros(50)).tolist() == [] and isolated_spikes([1.0, 5.0]).tolist() == []


def test_fit_refuses_a_glitch_unless_told(tmp_path, capsys):
    y = smooth(2, T=600)
    t = np.linspace(0, 8, 600)
    u = 3 * np.sin(2 * np.pi * 0.5 * t)
    y[123] *= 1000
    path = tmp_path / "d.csv"
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
    out = tmp_path / "o"
    assert main(["fit", str(path), "--plays", "2", "--model", "pi", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"1 isolated spike in the output at t = {t[123]:.6g} (sample 123" in err
    assert "--spikes drop" in err and not out.exists()
    argv = ["fit", str(path), "--plays", "2", "--model", "pi", "--spikes", "drop", "--out", str(out)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "each replaced by its neighbours' mean (--spikes drop)" in err


def test_a_kept_glitch_is_noted(tmp_path, capsys):
    y = smooth(3, T=600)
    t = np.linspace(0, 8, 600)
    y[300] -= 50
    path = tmp_path / "d.csv"
    np.savetxt(path, np.column_stack([t, 3 * np.sin(t), y]), delimiter=",", header="t,u,y", comments="")
    argv = ["fit", str(path), "--plays", "2", "--model", "pi", "--spikes", "keep", "--out", str(tmp_path / "o")]
    assert main(argv) == 0
    assert "fitted as measured (--spikes keep)" in capsys.readouterr().err
