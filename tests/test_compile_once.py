"""A second call with inputs of the same shapes compiles nothing.

An eager `lax.scan` (or loop) over a closure made inside the call compiles a new XLA program on
every call, and JAX keeps it: a process that calls such an entry point in a loop spends the
compile time each time and collects executables (and their memory mappings) without bound. Every
public entry point here is called twice on the same shapes; the second call must hit the caches.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_count import Compiles

import piest_jax as pj


@pytest.fixture(scope="module")
def records():
    rec, _ = pj.hidden_effect_record(("creep",), key=jax.random.PRNGKey(0), n_samples=400)
    # Two runs of one device: the same sampling, the second run later in the same record.
    half = len(rec.t) // 2
    return rec.slice(0, half), rec.slice(half, len(rec.t))


def _u(n=300):
    t = np.arange(n) * 1e-2
    return jnp.asarray(3.0 * np.sin(2 * np.pi * t) + np.sin(2 * np.pi * 2.7 * t))


R = jnp.array([0.0, 0.5, 1.0])
W = jnp.array([1.0, 0.5, 0.2])

CASES = {
    "play scan": lambda recs: pj.play(_u(), R, method="scan"),
    "play associative": lambda recs: pj.play(_u(), R, method="associative"),
    "stop": lambda recs: pj.stop(_u(), R),
    "PIOperator": lambda recs: pj.PIOperator(R, W)(_u()),
    "PIOperator regressor": lambda recs: pj.PIOperator(R, W).regressor(_u()),
    "inverse": lambda recs: pj.inverse(pj.PIOperator(R, W))(_u()),
    "Creep": lambda recs: pj.Creep(jnp.array([0.1, 1.0]), jnp.array([0.2, 0.1]), 0.01)(_u()),
    "fit_pi": lambda recs: pj.fit_pi(recs[0].u, recs[0].y, 3, n_starts=2),
    "identify with validation": lambda recs: pj.identify(recs[0], recs[1], model="pi+creep", plays=3, lags=1, starts=2),
    "compare": lambda recs: pj.compare(pj.fit_pi(recs[0].u, recs[0].y, 3, n_starts=2), recs[1].u, recs[1].y),
    "prediction_band": lambda recs: pj.prediction_band(pj.fit_pi(recs[0].u, recs[0].y, 3, n_starts=2), recs[1].u),
    "feedforward": lambda recs: pj.feedforward(pj.PIOperator(R, W), _u()),
    "GeneralizedPI and its inverse": lambda recs: pj.feedforward(_gpi(), 0.5 * _gpi()(_u())),
    "Preisach and its inverse": lambda recs: pj.feedforward(_preisach(), 0.5 * _preisach()(_u())),
}


def _gpi():
    return pj.GeneralizedPI(pj.PIOperator(R, W), [1.0, 0.5], [0.0, 1.0], [1.0, 2.0], 0.2)


def _preisach():
    K, M = 3, 4
    return pj.Preisach(jnp.linspace(0.1, 1.5, K), jnp.linspace(-2.0, 2.0, M), jnp.full((K, M), 0.3), 0.1)


@pytest.mark.parametrize("name", list(CASES))
def test_second_call_compiles_nothing(name, records):
    call = CASES[name]
    jax.block_until_ready(jax.tree_util.tree_leaves(call(records)))
    with Compiles() as compiles:
        jax.block_until_ready(jax.tree_util.tree_leaves(call(records)))
    assert compiles.count == 0, f"{name}: {compiles.count} programs compiled again on a repeat call"


def test_the_counter_sees_a_compile():
    # The check above is only meaningful if a fresh program is counted.
    with Compiles() as compiles:
        jax.jit(lambda x: jnp.sin(x) * 3.0 + 1.25)(jnp.arange(7.0))
    assert compiles.count >= 1


def test_another_play_count_compiles_only_the_fit(records):
    # On a record length already seen, a new play count compiles the fit's own programs (start
    # grids, solve, the chosen start in the data's units, the covariance's Jacobian), not one
    # program per small operation of the glue around them.
    u, y = records[0].u, records[0].y
    pj.fit_pi(u, y, 2, n_starts=2)
    with Compiles() as c:
        pj.fit_pi(u, y, 4, n_starts=2)
    assert c.count <= 5
