"""The covariance of a generalized PI fit's parameters: the PI fit's estimate (`covariance.py`) on
the generalized model's own parameters.

The parameters, in the data's units: thresholds r_2..r_n, weights, the output function's
amplitudes, centres and scales s_2..s_K (s_1 = 1 fixes the model's scale, see `fit_gpi`), the
offset, and the plays' initial states when fitted (but the first's, which the input sets at the
first sample). J is taken at the solution by forward-mode differentiation through the fits' play
scan (`fit.run`) and the output function, on the fitted samples; the estimate (Newey-West or
Gauss-Newton), the rank test and the relative limit are the PI fit's. Each parameter's scale for
that limit: as for the PI fit for thresholds, the offset and initial states; half the output range
for an amplitude; half the range the PI output covers on the record for a centre; the PI
output's half range over the input's for a weight (the model's slope before the output
function); its own size for a scale.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._models.gpi import GeneralizedPI, output_function
from . import covariance as _cov
from .fit import run


def names(n: int, k: int, states: bool) -> tuple:
    """The parameters' names, in the order of [`flatten`][]."""
    out = [f"thresholds[{j}]" for j in range(1, n)] + [f"weights[{j}]" for j in range(n)]
    out += [f"output.amplitudes[{j}]" for j in range(k)] + [f"output.centres[{j}]" for j in range(k)]
    out += [f"output.scales[{j}]" for j in range(1, k)] + ["offset"]
    if states:
        out += [f"initial_states[{j}]" for j in range(1, n)]
    return tuple(out)


def flatten(model: GeneralizedPI, states: bool):
    """The parameter vector of `model` (see the module notes)."""
    pi = model.pi
    parts = [
        pi.thresholds[1:],
        pi.weights,
        jnp.exp(model.log_amplitudes),
        model.centres,
        jnp.exp(model.log_scales[1:]),
        jnp.atleast_1d(model.offset),
    ]
    if states:
        parts.append(pi.initial_states[1:])
    return jnp.concatenate([jnp.asarray(p, pi.weights.dtype).reshape(-1) for p in parts])


def _predict(theta, u, x0, n: int, k: int, states: bool):
    sizes = np.cumsum([n - 1, n, k, k, k - 1, 1])
    r, w, a, c, s, off, x = jnp.split(theta, sizes)
    r = jnp.concatenate([jnp.zeros(1, theta.dtype), r])
    if states:
        x0 = x0.at[1:].set(x)
    log_s = jnp.concatenate([jnp.zeros(1, theta.dtype), jnp.log(s)])
    v = run(u, r, w, 0.0, x0)
    return output_function(v, jnp.log(a), c, log_s, off[0])


# Compiled once per shape: an eager `jacfwd` through the scan would compile on every call.
@eqx.filter_jit
def jacobian(theta, u, x0, n: int, k: int, states: bool):
    """The model's output (T,) and its Jacobian (T, p) with respect to `theta` ([`flatten`][]).

    **Arguments:** `theta` (p,); `u` (T,); `x0` (n,), the plays' states before the first sample
    (those of plays 2..n are replaced by `theta`'s when `states`); `n` plays, `k` output terms.
    """

    def f(th):
        return _predict(th, u, x0, n, k, states)

    return f(theta), jax.jacfwd(f)(theta)


def _padded(model: GeneralizedPI, pad_plays: int) -> GeneralizedPI:
    """`model` with plays added at its top threshold, weight 0: the same output, and the same
    derivatives with respect to the parameters it shares with `model`."""
    extra = pad_plays - model.n_plays
    r, w, x0 = (np.asarray(a) for a in (model.pi.thresholds, model.pi.weights, model.pi.initial_states))
    # In NumPy (eager JAX would compile for every play count), and set directly: the operator's
    # constructor refuses thresholds that repeat.
    parts = tuple(
        jnp.asarray(np.concatenate([a, np.full(extra, fill, a.dtype)]))
        for a, fill in ((r, r[-1]), (w, 0.0), (x0, x0[-1]))
    )
    return eqx.tree_at(lambda m: (m.pi.thresholds, m.pi.weights, m.pi.initial_states), model, parts)


def fields(method: str, model: GeneralizedPI, u, y, mask, states: bool, pad_plays: int | None = None) -> dict:
    """The covariance fields of a `GPIFit` (as [`PIFit`][]'s) for `model` fitted to `u`, `y`
    (T,) with sample weights `mask` (T,). With `pad_plays`, J is taken on the model padded to
    that many plays (`_padded`) and the padding's columns dropped, so that models with different
    play counts share one compilation."""
    n, k = model.n_plays, model.n_terms
    dtype = model.pi.weights.dtype
    u, y = jnp.asarray(u, dtype), np.asarray(y, np.float64)
    theta = flatten(model, states)
    parameter_names = names(n, k, states)
    N = n if pad_plays is None else pad_plays
    padded = model if N == n else _padded(model, N)
    x0 = jnp.broadcast_to(padded.pi.initial_states, (N,)).astype(dtype)
    pred, J = jacobian(theta if N == n else flatten(padded, states), u, x0, N, k, states)
    J = np.asarray(J)
    if N != n:
        at = {name: i for i, name in enumerate(names(N, k, states))}
        J = J[:, [at[name] for name in parameter_names]]
    m = np.asarray(mask, np.float64)
    used = m > 0
    Ju = J[used] * m[used, None]
    e = (y - np.asarray(pred))[used] * m[used]
    cov, se, deficient, info = _cov.estimate(Ju, e, method=method, eps=np.finfo(np.asarray(u).dtype).eps)
    values = np.asarray(theta)
    u_np = np.asarray(u)[used]
    u_half, y_half = 0.5 * float(np.ptp(u_np)), 0.5 * float(np.ptp(y[used]))
    v = np.asarray(model.pi(u))[used]
    v_half = 0.5 * float(np.ptp(v))
    scale = _cov.scales(parameter_names, values, u_half, y_half)
    for i, name in enumerate(parameter_names):
        if name.startswith("weights["):
            scale[i] = v_half / u_half
        elif name.startswith("output.amplitudes["):
            scale[i] = y_half
        elif name.startswith("output.centres["):
            scale[i] = v_half
    undetermined = deficient | ~(se < _cov.RELATIVE_LIMIT * scale)
    return dict(
        parameter_names=parameter_names,
        parameter_values=jnp.asarray(values),
        covariance=jnp.asarray(cov),
        std_errors=jnp.asarray(se),
        undetermined=jnp.asarray(undetermined),
        covariance_method=method,
        residual_std=jnp.asarray(info["sigma"], dtype),
    )
