"""Progress bars: drawn on a terminal, silent when stderr is not one or when asked to be quiet."""

import io
import sys

import pytest

from piest_jax._progress import progress


class _Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.mark.parametrize("tty, quiet, shown", [(True, False, True), (True, True, False), (False, False, False)])
def test_bar_only_on_a_terminal(monkeypatch, tty, quiet, shown):
    err = _Terminal() if tty else io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    items = list(progress(range(7), desc="chunks", quiet=quiet))
    assert items == list(range(7))
    text = err.getvalue()
    # The bar is cleared when done (leave=False); what was drawn names the label and the total.
    assert ("chunks" in text and "/7" in text) == shown, text
    if not shown:
        assert text == ""


def test_diagnose_search_reports_progress_per_round(monkeypatch):
    import jax

    from piest_jax._diagnosis import diagnose as _diagnose
    from piest_jax._diagnosis import hidden as _hidden

    rec, _ = _hidden.generate(("delay",), key=jax.random.PRNGKey(3), n_samples=300)
    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    _diagnose.search(rec, max_effects=1, candidates=("delay", "creep"), solver=None, quiet=False)
    assert "diagnose, round 1" in err.getvalue()
    err.truncate(0)
    _diagnose.search(rec, max_effects=1, candidates=("delay", "creep"), solver=None, quiet=True)
    assert err.getvalue() == ""
