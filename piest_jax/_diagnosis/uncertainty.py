"""Standard errors of a diagnosis model's effect parameters, as `fit_pi` reports its own.

The final model is the joint model of `refine` at its parameters θ (normalised units; times as
logarithms, positive coefficients through a softplus). Its residuals' Jacobian J = ∂r/∂θ comes
from forward-mode differentiation through the model, and the covariance of θ from the same
estimate `fit_pi` uses (`covariance.estimate`: Newey-West by default, so coloured residuals do
not make the errors look smaller than they are). The numbers the report gives for each effect
(its `describe`: a delay in seconds, time constants, an envelope coefficient, ...) are functions
of θ; their covariance follows by the delta method, G Cov(θ) Gᵀ with G their derivatives with
respect to θ (central differences: `describe` is plain Python). The offset's standard error is
in the output's units.

A number is *undetermined* when it depends on a direction of θ the Jacobian leaves free (its
numerical rank), or when its standard error exceeds `covariance.RELATIVE_LIMIT` times its own
size: then the record does not pin it down, and the value is a guess.

The Jacobian is taken on the samples the refinement ran on (every k-th sample of a long record,
at most `diagnose.REFINE_SAMPLES`): fewer samples than the record, so the errors, if anything,
are the larger.
"""

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from .._identification import covariance as _cov
from .effects import EFFECT
from .refine import Refined, data_of, initial_params, model, structure
from .scaling import Scaling


def _numbers(d: dict, prefix: str) -> dict:
    """The parameters in a `describe` dict, by dotted name (lists indexed); words and whole
    numbers (a form, a filter's order) are structure, not estimates."""
    out = {}
    for k, v in d.items():
        if isinstance(v, (bool, str, int)):
            continue
        if isinstance(v, (list, tuple)):
            out.update({f"{prefix}.{k}[{i}]": float(x) for i, x in enumerate(v)})
        else:
            out[f"{prefix}.{k}"] = float(v)
    return out


def _described(cfg, theta: dict, sc: Scaling) -> dict:
    """Every named effect's numbers and the offset (data units) at the parameters `theta`."""
    t = {k: np.asarray(v, float) for k, v in theta.items()}
    out = {}
    for name, q in cfg.items():
        q_new, _ = EFFECT[name].from_theta(q, t)
        out.update(_numbers(EFFECT[name].describe(q_new), name))
    out["offset"] = float(t["offset"]) * sc.y_half + sc.y_mid
    return out


@eqx.filter_jit
def _jacobian(flat, unravel, st, data, y):
    def residuals(v):
        return model(unravel(v), st, data) - y

    return jax.jacfwd(residuals)(flat), residuals(flat)


def parameters(model_entry: dict, signed: bool = False):
    """The joint model's parameters, structure and configuration for a search's model entry.

    `signed`: the play weights are signed (a clockwise loop, `Prepared.signed`).

    **Returns:** `(theta, structure, cfg)`: the refined ones when the refinement was kept, else
    those of the kept variable-projection fit.
    """
    refined = model_entry.get("refined")
    if isinstance(refined, Refined):
        return refined.theta, refined.structure, refined.cfg
    cfg = model_entry["cfg"]
    return initial_params(cfg, model_entry["coef"], signed), structure(cfg), cfg


def parameter_uncertainty(p, model_entry: dict, sc: Scaling, *, method: str = "newey-west") -> dict:
    """Standard errors of a diagnosis model's effect parameters and offset.

    **Arguments:**

    - `p`: the prepared record the model was refined on (normalised units).
    - `model_entry`: `search(...)["model_final"]` (configuration, coefficients, normalisation
      and, when the refinement was kept, its `Refined`).
    - `sc`: the record's `Scaling` (to report the offset in data units).
    - `method`: `"newey-west"` (default) or `"gauss-newton"`, as for `fit_pi`.

    **Returns:** a dict with `method`, `std_errors` and `values` (by parameter name: `delay.delay_s`,
    `creep.time_constants_s[0]`, ..., `offset`), `undetermined` (names) and `samples` (the number
    of samples the Jacobian was taken on).
    """
    theta, st, cfg = parameters(model_entry, p.signed)
    data, y, _ = data_of(p, model_entry["norm"], pad=False)
    flat, unravel = jax.flatten_util.ravel_pytree({k: jnp.asarray(v) for k, v in theta.items()})
    J, e = (np.asarray(a) for a in _jacobian(flat, unravel, st, data, y))
    cov, _, deficient, _ = _cov.estimate(J, e, method=method, eps=np.finfo(J.dtype).eps)

    base = _described(cfg, unravel(flat), sc)
    names = list(base)
    G = np.zeros((len(names), flat.shape[0]))
    flat_np = np.asarray(flat, float)
    for i in range(flat_np.shape[0]):
        h = 1e-6 * max(1.0, abs(flat_np[i]))
        up, down = flat_np.copy(), flat_np.copy()
        up[i] += h
        down[i] -= h
        hi = _described(cfg, unravel(jnp.asarray(up)), sc)
        lo = _described(cfg, unravel(jnp.asarray(down)), sc)
        G[:, i] = [(hi[n] - lo[n]) / (2 * h) for n in names]
    var = np.einsum("ij,jk,ik->i", G, cov, G)
    se = np.sqrt(np.maximum(var, 0.0))
    free = (np.abs(G[:, np.asarray(deficient, bool)]) > 0).any(axis=1)
    values = np.array([base[n] for n in names])
    # An effect's number is judged against its own size; the offset against the output's half
    # range (an offset near zero, known to a small error, is determined).
    scale = np.where(np.array(names) == "offset", sc.y_half, np.abs(values))
    undetermined = free | (se > _cov.RELATIVE_LIMIT * scale)
    se = np.where(free, np.inf, se)
    return {
        "method": method,
        "values": dict(zip(names, values.tolist())),
        "std_errors": {n: (float(s) if np.isfinite(s) else None) for n, s in zip(names, se)},
        "undetermined": [n for n, bad in zip(names, undetermined) if bad],
        "samples": int(e.shape[0]),
    }
