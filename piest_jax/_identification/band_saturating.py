"""Prediction bands of the models that saturate: the generalized PI and the Preisach model.

As for the PI fit ([`prediction_band`][]): linearised at the fitted parameters, the prediction's
variance on an input is J_t Σ J_tᵀ, Σ the fit's covariance, and a new measurement adds σ². For the
generalized PI, J is `gpi_covariance.jacobian` on the input (the fit's play scan and output
function, forward mode; it holds T x p numbers). The Preisach model is linear in its density and
offset, so J's rows are its relays (and a 1): they are formed chunk by chunk as the plays run, so
memory does not grow with the input's length.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._models.gpi import GeneralizedPI
from .._models.preisach import Preisach, relay_chunk
from .._operators.play import Method
from . import covariance as _cov
from . import gpi_covariance
from .fit_gpi import GPIFit
from .fit_preisach import PreisachFit, triangle_columns


def band_parts(fit: GPIFit | PreisachFit, u, initial_states=None, chunk: int = _cov.CHUNK):
    """The prediction (T,), its variance diag(J Σ Jᵀ) (T,) and σ for a saturating fit on `u`.

    **Arguments:** `fit`, with a covariance; `u` (T,), finite; `initial_states`, the plays' states before the first
    sample (scalar or (n,)), taken as known; default the model's; `chunk`, samples per chunk
    (the Preisach model's relays).
    """
    model = fit.model if initial_states is None else fit.model.with_initial_states(initial_states)
    dtype = jnp.result_type(u, model.offset)
    u = jnp.asarray(u, dtype)
    cov = np.asarray(fit.covariance, np.float64)
    if isinstance(fit, GPIFit):
        assert isinstance(model, GeneralizedPI)  # a GPIFit's model, as is its copy with other states
        n, k = model.n_plays, model.n_terms
        states = any(name.startswith("initial_states") for name in fit.parameter_names)
        if states and initial_states is not None:
            # Given states are known: their parameters add no variance.
            known = np.asarray([name.startswith("initial_states") for name in fit.parameter_names])
            cov = np.where(known[:, None] | known[None, :], 0.0, cov)
        theta = gpi_covariance.flatten(model, states)
        x0 = jnp.broadcast_to(model.pi.initial_states, (n,)).astype(dtype)
        pred, J = gpi_covariance.jacobian(theta.astype(dtype), u, x0, n, k, states)
        var = jnp.sum((J @ jnp.asarray(cov, dtype)) * J, axis=1)
    else:
        assert isinstance(model, Preisach)  # a PreisachFit's model, as is its copy with other states
        keep = triangle_columns(*model.shape)
        x0 = model._start(u).astype(dtype)
        pred = model(u)
        var = _preisach_variance(
            u,
            model.half_widths.astype(dtype),
            model.centres.astype(dtype),
            model.blur.astype(dtype),
            x0,
            jnp.asarray(keep),
            jnp.asarray(cov, dtype),
            min(int(chunk), u.shape[0]),
            model.method,
        )
    return pred, var, jnp.asarray(fit.residual_std, dtype)


@eqx.filter_jit
def _preisach_variance(u, half_widths, centres, blur, x0, keep, cov, chunk: int, method: Method):
    T = u.shape[0]

    def body(x, uu):
        S, x = relay_chunk(uu, x, half_widths, centres, blur, method)
        S = S[:, keep]
        return x, jnp.sum((S @ cov) * S, axis=1)

    _, var = lax.scan(body, x0, _cov.chunked(u, u[-1], chunk))
    return var.reshape(-1)[:T]
