"""The covariance of a fit's parameters, and which of them the record does not determine.

The parameters are the fitted model's own, in the data's units: thresholds r_2..r_n (r_1 = 0 is
fixed), weights, the offset, the plays' initial states when fitted (but the first's: the r = 0
play takes the input's value at the first sample, whatever its state before), and the creep's time
constants, weights and initial states. The Jacobian J (N x p) of the model's output with respect
to them is taken at the solution by forward-mode differentiation through the same scan the fit
minimises (`fit.run`), on the fitted samples (their `mask` weights included).

Two estimates, both on the identifiable subspace (below):

- **Gauss-Newton**: σ² (JᵀJ)⁻¹ with σ² = Σe²/(N - p). Right when the residuals are white.
- **Newey-West** (the default): the sandwich (JᵀJ)⁻¹ Ω (JᵀJ)⁻¹ · N/(N - p), Ω the long-run
  covariance of the scores g_t = J_t e_t by overlapping block sums (Bartlett weights) of length
  b, b from Andrews' AR(1) plug-in rule b = ⌈1.1447 (α N)^{1/3}⌉, α = 4ρ²/((1-ρ)²(1+ρ)²), ρ the
  residuals' lag-1 autocorrelation, and b at most N/5. A measured record's residuals are mostly
  model error, smooth over many samples; there σ²(JᵀJ)⁻¹ can be several times too small, while on
  white residuals ρ ≈ 0, b ≤ 2 and the two estimates agree (the calibration tests check both).

**Identifiability.** J's columns are scaled to unit norm and its singular values below
max(N, p)·eps·s_max (NumPy's `matrix_rank` rule) are dropped; a parameter with a component of
more than `NULL_SHARE` in the dropped directions is undetermined, its standard error infinite, and
the covariance is the pseudo-inverse's, i.e. that of the determined combinations. A parameter is
also undetermined when its standard error exceeds `RELATIVE_LIMIT` (0.5: its 95 % interval
reaches past its scale) of its scale: |value| for time constants; the model's overall slope
y_half/u_half for play weights (a weight estimated near zero with a small error is
determined to be small), and the larger of that slope and |value| for creep weights (a lag
slower than the record acts as a slow drift whose weight may well exceed the slope); for a threshold the
room it has, the distance to its lower neighbour or to the top of the input's half range,
whichever is smaller (a play whose threshold may lie beyond the input's reach is not known to
move); half the output range for the offset, half the input range for initial states.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array

from .. import _checks
from .. import _parameter_table as _table
from .._bounded_jit import bounded_jit
from .fit_data import Scales
from .time_constants import LAG_RATIO, lag_log_tau

METHODS = ("newey-west", "gauss-newton")
# Records longer than this (fitted samples) accumulate what the covariance needs chunk by chunk
# (`moments`) instead of holding J (T, p): the same estimate in bounded memory.
LONG_RECORD = 2**16
CHUNK = 4096
RELATIVE_LIMIT = 0.5
NULL_SHARE = 1e-4
# A creep lag whose squared free parameter (its log time constant's gap above its bound) is
# below this sits on the bound (`on_bounds`).
HOLD = 2e-3


class Layout(eqx.Module):
    """Where each parameter sits in the flat (padded) parameter vector."""

    n: int = eqx.field(static=True)
    k: int = eqx.field(static=True)
    states: bool = eqx.field(static=True)

    def sizes(self):
        sizes = [("thresholds", self.n - 1), ("weights", self.n), ("offset", 1)]
        if self.states:
            sizes.append(("initial_states", self.n))
        if self.k:
            sizes += [("creep.time_constants", self.k), ("creep.weights", self.k)]
            if self.states:
                sizes.append(("creep.initial_states", self.k))
        return sizes

    def split(self, theta):
        out, i = {}, 0
        for name, m in self.sizes():
            out[name] = theta[i : i + m]
            i += m
        return out

    def names(self, n_used: int, k_used: int):
        """Names and positions of the parameters of the first `n_used` plays and `k_used` lags."""
        names, index, i = [], [], 0
        for name, m in self.sizes():
            used = {"thresholds": n_used - 1, "offset": 1}.get(name, k_used if "creep" in name else n_used)
            first = 1 if name == "thresholds" else 0
            for j in range(m):
                # The r = 0 play's state is forgotten at the first sample: no parameter.
                if j < used and name != "initial_states" or 0 < j < used:
                    names.append(name if name == "offset" else f"{name}[{j + first}]")
                    index.append(i + j)
            i += m
        return tuple(names), np.asarray(index, int)


def flatten(layout: Layout, thresholds, weights, offset, states=None, taus=None, lag_weights=None, lag_states=None):
    """The flat parameter vector in the data's units, in the order of `layout`."""
    parts = [thresholds[1:], weights, jnp.atleast_1d(offset)]
    if layout.states:
        parts.append(states)
    if layout.k:
        parts += [taus, lag_weights]
        if layout.states:
            parts.append(lag_states)
    return jnp.concatenate([jnp.asarray(p, weights.dtype).reshape(-1) for p in parts])


@eqx.filter_jit
def _natural(layout: Layout, theta, s: Scales, x0, z0, dt):
    """`fit.run`'s arguments after the input, in normalised units, from the parameters `theta`."""
    p = layout.split(theta)
    w = p["weights"] * s.u_half / s.y_half
    r = jnp.concatenate([jnp.zeros(1, theta.dtype), p["thresholds"]]) / s.u_half
    x = (p["initial_states"] - s.u_mid) / s.u_half if layout.states else x0
    total = jnp.sum(p["weights"])
    lags: tuple[Array, ...] = ()
    if layout.k:
        c = p["creep.weights"] * s.u_half / s.y_half
        z = (p["creep.initial_states"] - s.u_mid) / s.u_half if layout.states else z0
        total = total + jnp.sum(p["creep.weights"])
        lags = (jnp.log(p["creep.time_constants"] / dt), c, z)
    # offset = y_mid + y_half c' - u_mid Σ (weights), the inverse of the fit's map to units
    c0 = (p["offset"][0] - s.y_mid + s.u_mid * total) / s.y_half
    return (r, w, c0, x, *lags)


def prediction(run, layout: Layout, theta, u, s: Scales, x0, z0, dt):
    """The model's output (T,) in the data's units at `theta`.

    `run(u, r, w, offset, x0, log_tau, c, z0)` is the fit's model in normalised units; `x0`, `z0`
    are the normalised states used when they are not parameters.
    """
    return s.y_mid + s.y_half * run(u, *_natural(layout, theta, s, x0, z0, dt))


# Compiled once per shape: run eagerly, `jacfwd` through the scan would compile it on every call.
@eqx.filter_jit
def jacobian(run, layout: Layout, theta, u, s: Scales, x0, z0, dt):
    """The model's output (T,) in the data's units ([`prediction`][]) and its Jacobian (T, p) at
    `theta`."""

    def predict(theta):
        return prediction(run, layout, theta, u, s, x0, z0, dt)

    return predict(theta), jax.jacfwd(predict)(theta)


def chunked(a, fill, chunk):
    """`a` (T,) padded with `fill` to a multiple of `chunk` and shaped (chunks, chunk)."""
    pad = -a.shape[0] % chunk
    if pad:
        a = jnp.concatenate([a, jnp.full(pad, fill, a.dtype)])
    return a.reshape(-1, chunk)


def chunk_rows(run, layout: Layout, theta, s: Scales, x0, z0, dt):
    """The model run chunk by chunk with its forward-mode sensitivities to `theta`.

    **Returns:** `(states, dstates, rows)`: the plays' (and lags') states before the first
    sample, their sensitivities (one per parameter, leading axis), and `rows(states, dstates,
    uu) -> (prediction, states_after, J, dstates_after)` for a chunk `uu` (m,): the output in the
    data's units, the states after it, J (p, m) (the Jacobian's rows, transposed) and the
    sensitivities after it. Chaining `rows` over consecutive chunks gives the exact Jacobian of
    the whole run with only one chunk's rows in memory.
    """

    def start(th):
        nat = _natural(layout, th, s, x0, z0, dt)
        return nat[3], (nat[6] if layout.k else None)

    def chunk_model(th, states, uu):
        r, w, c0, _, *lags = _natural(layout, th, s, x0, z0, dt)
        x, z = states
        args = (lags[0], lags[1], z) if layout.k else ()
        pred, after = run(uu, r, w, c0, x, *args, final=True)
        return s.y_mid + s.y_half * pred, after

    eye = jnp.eye(theta.shape[0], dtype=theta.dtype)

    def rows(states, dstates, uu):
        def tangent(t, d):
            return jax.jvp(lambda th, sv: chunk_model(th, sv, uu), (theta, states), (t, d))

        (pred, after), (J, dafter) = jax.vmap(tangent, out_axes=(None, 0))(eye, dstates)
        return pred, after, J, dafter

    s0 = start(theta)
    ds0 = jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0), jax.jacfwd(start)(theta))
    return s0, ds0, rows


# Each parameter layout and record length compiles a large program (a scan of forward-mode
# sensitivities and QR updates); a structure search meets many once each (`_bounded_jit.py`).
@bounded_jit(2)
def moments(
    run, layout: Layout, theta, u, y, mask, s: Scales, x0, z0, dt, window: int, chunk: int, blocks: bool = True
):
    """What the covariance needs from J, accumulated chunk by chunk in bounded memory.

    A `lax.scan` over chunks of the record carries the plays' (and lags') states and their
    sensitivities to `theta` (forward mode, one tangent per parameter), so each chunk's rows of
    J are exact while only `chunk` of them exist at a time.

    **Arguments:** as [`jacobian`][], plus `y` (T,) in the data's units, `mask` (T,) the samples'
    weights (0 leaves a sample out), `window` the Newey-West block length, `chunk` the chunk
    length and `blocks` whether to accumulate the block sums' factor (Newey-West's; Gauss-Newton
    needs none, and `Rw` then stays zero).

    **Returns:** `(R (p, p), Rw (p, p), eTe)`: the triangular factor of the weighted rows'
    J = QR, by a QR of the factor so far stacked on each chunk's rows (so RᵀR = JᵀJ, with J's
    singular values to the accuracy of a QR of J, where JᵀJ itself would square its condition
    number); a triangular factor, likewise, of the overlapping block sums W_t = Σ of
    g_i = J_i e_i over the `window` samples ending at t (every t >= window - 1), so
    RwᵀRw = Σ_t W_t W_tᵀ, for the same reason (`estimate_moments` turns them by S⁻¹, where
    Σ W Wᵀ would have lost cond² eps); and eᵀe.
    """
    p = theta.shape[0]
    T = u.shape[0]
    data = (chunked(u, u[-1], chunk), chunked(y, 0.0, chunk), chunked(mask, 0.0, chunk))
    # The samples' indices come from the chunk's number: a (T,) index array would be one more
    # copy of the record's length (80 MB at 10^7 samples).
    numbers = jnp.arange(data[0].shape[0])
    s0, ds0, rows = chunk_rows(run, layout, theta, s, x0, z0, dt)

    def body(carry, ch):
        states, dstates, tail, R, Rw, ete = carry
        (uu, yy, mm), k = ch
        ii = k * chunk + jnp.arange(chunk)
        pred, after, J, dafter = rows(states, dstates, uu)
        J = J * mm[None, :]
        e = (yy - pred) * mm
        R = jnp.linalg.qr(jnp.concatenate([R, J.T]), mode="r")
        if blocks:
            W, tail = block_sums(tail, (J * e[None, :]).T, ii, T)
            Rw = jnp.linalg.qr(jnp.concatenate([Rw, W]), mode="r")
        return (after, dafter, tail, R, Rw, ete + e @ e), None

    zero = jnp.zeros((p, p), theta.dtype)
    init = (s0, ds0, jnp.zeros((window, p), theta.dtype), zero, zero, jnp.zeros((), theta.dtype))
    (_, _, _, R, Rw, ete), _ = lax.scan(body, init, (data, numbers))
    return R, Rw, ete


def block_sums(tail, g, ii, T: int):
    """The overlapping block sums W_t (m, p) of the scores `g` (m, p) of one chunk.

    `tail` (b, p) holds the running sum of the scores at the chunk's last b samples before it (b
    the block length, zeros before the record); `ii` (m,) are the chunk's sample indices. W_t, the
    sum of the b scores ending at t, is 0 for t < b - 1 and for padding (t >= T).

    **Returns:** `(W, tail)`, the tail to carry into the next chunk.
    """
    b, m = tail.shape[0], g.shape[0]
    cum = jnp.concatenate([tail, tail[-1] + jnp.cumsum(g, axis=0)])
    W = (cum[b:] - cum[:m]) * ((ii >= b - 1) & (ii < T))[:, None]
    return W, cum[m:]


def bandwidth(e) -> int:
    """Andrews' AR(1) plug-in block length for the Bartlett kernel, 1 <= b <= N/5."""
    e = np.asarray(e, np.float64)
    return bandwidth_of(float(e @ e), float(e[1:] @ e[:-1]), e.shape[0])


def bandwidth_of(den: float, cross: float, N: int) -> int:
    """[`bandwidth`][] from the residuals' sums Σ e_t², Σ e_t e_(t-1) and their number `N`."""
    rho = cross / den if den > 0 else 0.0
    rho = min(max(rho, -0.999), 0.999)
    alpha = 4 * rho**2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    b = int(np.ceil(1.1447 * (alpha * N) ** (1 / 3)))
    return max(1, min(b, N // 5))


def estimate(J, e, *, method: str = "newey-west", eps=None):
    """Covariance of least-squares estimates from the Jacobian `J` (N, p) and residuals `e` (N,).

    **Arguments:** `J`, `e` on the fitted samples; `method`, one of `METHODS`; `eps`, the machine
    epsilon of the arithmetic J was computed in (default float64's).

    **Returns:** `(covariance (p, p), std_errors (p,), rank_deficient (p,) bool, info)` with
    `info` a dict (sigma, dof, rank, bandwidth). Standard errors of rank-deficient parameters are
    inf; the covariance is finite (the pseudo-inverse's).
    """
    if method not in METHODS:
        raise ValueError(f"unknown covariance method {method!r}; choose one of {METHODS}")
    J = np.asarray(J, np.float64)
    e = np.asarray(e, np.float64)
    N, p = J.shape
    norms = np.linalg.norm(J, axis=0)
    d = np.where(norms > 0, norms, 1.0)
    U, S, Vt = np.linalg.svd(J / d, full_matrices=False)
    b = bandwidth(e) if method == "newey-west" and N > p else None
    blocks = None
    if b is not None:
        # The block sums of J's left singular vectors (J / d = U S Vᵀ) times the residuals, in
        # the coordinates where the sandwich divides by S once, as a factor (see `_sandwich`).
        cs = np.concatenate([np.zeros((1, U.shape[1])), np.cumsum(U * e[:, None], axis=0)])
        blocks = np.linalg.qr(cs[b:] - cs[:-b], mode="r")
    return _sandwich(S, Vt, norms, N, p, float(e @ e), method, b, blocks, _floor(N, p, eps))


def estimate_moments(factor, blocks, ete, N: int, *, method: str, window, eps=None):
    """`estimate` from J's triangular factor, a factor of the block sums' Σ W Wᵀ and eᵀe
    ([`moments`][]), for records too long to hold J.

    The singular values of the column-scaled J are those of the column-scaled factor. The rank
    test's floor is max(√N, p)·eps·s_max here, where `estimate`'s is max(N, p)·eps·s_max: the
    factor is accumulated chunk by chunk, so its rounding grows like that of a sum of N terms,
    and N·eps would call every parameter of a float32 fit on 10⁶ samples free (0.12 s_max).

    **Arguments:** `factor` (k, p), any matrix with factorᵀ factor = JᵀJ (the `R` of `moments`,
    its columns selected and mapped); `blocks` (k', p), any matrix with blocksᵀ blocks = Σ W Wᵀ
    (the `Rw` of `moments`, mapped alike); `ete`; `N` the fitted samples; `method`; `window` the
    block length the block sums were taken over; `eps` as in `estimate`.

    **Returns:** as `estimate`.
    """
    if method not in METHODS:
        raise ValueError(f"unknown covariance method {method!r}; choose one of {METHODS}")
    factor = np.asarray(factor, np.float64)
    p = factor.shape[1]
    norms = np.linalg.norm(factor, axis=0)
    d = np.where(norms > 0, norms, 1.0)
    _, S, Vt = np.linalg.svd(factor / d, full_matrices=True)
    S = np.pad(S, (0, p - S.shape[0]))  # a factor of fewer rows than columns: the rest are zero
    b = int(window) if method == "newey-west" else None
    blocks_u = None
    if b is not None:
        # The block sums in the coordinates of J's left singular vectors, U = J V S⁻¹ / d, as
        # `_sandwich` takes them (where S is 0 the direction is beyond the rank and unused):
        # turned as a factor, F = blocks (S⁻¹ Vᵀ / d)ᵀ, whose cancellation costs cond·eps, not
        # the cond²·eps of turning Σ W Wᵀ itself.
        inv = np.divide(1.0, S, out=np.zeros_like(S), where=S > 0)
        blocks_u = np.asarray(blocks, np.float64) @ (inv[:, None] * Vt / d).T
    return _sandwich(S, Vt, norms, N, p, float(ete), method, b, blocks_u, _floor(np.sqrt(N), p, eps))


def _gram_svd(G):
    """The singular values (decreasing) and right vectors of the column-scaled J whose Gram
    matrix is `G` (p, p), and J's column norms."""
    G = np.asarray(G, np.float64)
    norms = np.sqrt(np.maximum(np.diag(G), 0.0))
    d = np.where(norms > 0, norms, 1.0)
    lam, V = np.linalg.eigh(G / np.outer(d, d))
    order = np.argsort(lam)[::-1]
    return np.sqrt(np.maximum(lam[order], 0.0)), V[:, order].T, norms


def _floor(rows, p, eps):
    """The rank test's floor relative to the largest singular value: max(rows, p)·eps, eps
    float64's by default (NumPy's `matrix_rank` rule for a J of `rows` rows)."""
    return max(rows, p) * (np.finfo(np.float64).eps if eps is None else float(eps))


def _identifiable(S, Vt, norms, p, rel):
    """J's numerical rank and the parameters it leaves free (rule 1 of the module notes): the
    singular values below `rel` times the largest are dropped."""
    tol = (S[0] if S.size and S[0] > 0 else 1.0) * rel
    rank = int(np.sum(S > tol))
    null = Vt[rank:].T
    deficient = np.linalg.norm(null, axis=1) > NULL_SHARE if rank < p else np.zeros(p, bool)
    return rank, deficient | (norms == 0)


def gram_deficient(G, N: int, eps=None):
    """The parameters a Gram matrix `G` = JᵀJ (p, p) of `N` rows leaves free, judged from its
    eigenvalues, which resolve J's scaled singular values down to about √eps of the largest.

    **Returns:** (p,) booleans.
    """
    S, Vt, norms = _gram_svd(G)
    p = norms.shape[0]
    eps = np.finfo(np.float64).eps if eps is None else float(eps)
    return _identifiable(S, Vt, norms, p, max(_floor(N, p, eps), np.sqrt(eps)))[1]


def _sandwich(S, Vt, norms, N, p, ete, method, b, blocks, rel):
    """The covariance from the scaled J's singular values `S` and right vectors `Vt` of `N`
    samples, dropping those below `rel` times the largest; for Newey-West, `blocks` (k, p) is a
    factor, blocksᵀ blocks = Σ W Wᵀ, of the block sums W of the residuals times J's left singular
    vectors U (J / d = U S Vᵀ).

    With A = V S⁻¹ / d over the `rank` kept directions (J's truncated pseudo-inverse without
    its Uᵀ), the Gauss-Newton covariance is σ² A Aᵀ and the sandwich A (Uᵀ Ω U) Aᵀ: from
    `estimate`'s block sums S enters once, where the product of (JᵀJ)⁺, Jᵀ Ω J and (JᵀJ)⁺ formed
    in the parameters' coordinates enters it four times. Near the rank floor (S of 1e-8 and
    below) that product's terms reach 1e30 and cancel: its variances came out negative, the
    offset's too, and a negative variance read as zero called a parameter the record barely
    resolves known exactly. `estimate_moments` turns a factor of the parameter-coordinate block
    sums by S⁻¹, which costs cond eps as `estimate`'s U does. With the meat as a factor the
    covariance is a Gram matrix (F Fᵀ), so no variance rounds below zero.
    """
    d = np.where(norms > 0, norms, 1.0)
    rank, deficient = _identifiable(S, Vt, norms, p, rel)
    A = Vt[:rank].T / S[:rank] / d[:, None]
    dof = N - p
    info = {"method": method, "dof": dof, "rank": rank, "bandwidth": None}
    if dof < 1:
        info["sigma"] = float("nan")
        return np.zeros((p, p)), np.full(p, np.inf), np.ones(p, bool), info
    sigma2 = ete / dof
    info["sigma"] = float(np.sqrt(sigma2))
    if method == "gauss-newton":
        cov = sigma2 * (A @ A.T)
    else:
        F = A @ blocks[:, :rank].T
        cov = F @ F.T * (N / (b * (N - b + 1)) * N / dof)
        info["bandwidth"] = b
    cov = 0.5 * (cov + cov.T)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    se[deficient] = np.inf
    return cov, se, deficient, info


def scales(names, values, u_half, y_half):
    """Each parameter's scale for the relative-error limit (see the module's docstring)."""
    values = np.asarray(values, np.float64)
    r = {n: v for n, v in zip(names, values) if n.startswith("thresholds[")}
    out = np.empty(len(names))
    for i, (n, v) in enumerate(zip(names, values)):
        if n.startswith("thresholds["):
            j = int(n[len("thresholds[") : -1])
            below = v - r.get(f"thresholds[{j - 1}]", 0.0)
            out[i] = min(below, u_half - v)
        elif n == "offset":
            out[i] = y_half
        elif "initial_states" in n:
            out[i] = u_half
        elif n.startswith("creep.weights"):
            # A lag's weight is its share of the response to a step held for ever, which a lag
            # slower than the record never shows: a slow lag is a slow drift of the output with
            # a weight well above the slope. Either scale judges it (a weight near zero with a
            # small error is determined to be small; a large one known to a fraction of itself
            # is determined too).
            out[i] = max(y_half / u_half, abs(v))
        elif "weights" in n:
            # A weight's scale is the model's overall slope, not its own size: a weight estimated
            # near zero with a small error is determined (to be small), not undetermined.
            out[i] = y_half / u_half
        else:
            out[i] = abs(v)
    return out


def fit_fields(
    method, run, p, r, w, un, yn, mask, s, x0, z0, dt, lag_active, lag_base, fit_states, n_plays, n_lags
) -> dict:
    """The covariance fields of a `PIFit` from the chosen start's parameters `p` (normalised,
    padded; `r`, `w` its thresholds and weights): the Jacobian over every padded parameter (one
    compilation per padded shape), then the columns of the parameters in use."""
    # On the host in NumPy: eager JAX operations would each compile once per shape.
    p, r, w, s_np = (jax.tree.map(np.asarray, a) for a in (p, r, w, s))
    um, uh, ym, yh = (float(v) for v in (s_np.u_mid, s_np.u_half, s_np.y_mid, s_np.y_half))
    layout = Layout(r.shape[0], 0 if z0 is None else z0.shape[0], fit_states)
    parts = [r[1:] * uh, w * yh / uh, None]
    if fit_states:
        parts.append(um + uh * p["initial_states"])
    total = np.sum(parts[1])
    if layout.k:
        c = p["lag_weights"]
        c = c if lag_active is None else c * np.asarray(lag_active)
        parts += [np.exp(np.asarray(lag_log_tau(p["lag_theta"], lag_base))) * dt, c * yh / uh]
        total = total + np.sum(parts[-1])
        if fit_states:
            parts.append(um + uh * p["lag_states"])
    parts[2] = np.atleast_1d(ym + yh * p["offset"] - um * total)
    theta = np.concatenate(parts).astype(np.asarray(un).dtype)
    dt = np.asarray(dt, np.asarray(un).dtype)
    used = np.asarray(mask) > 0
    names, index = layout.names(n_plays, n_lags)
    eps = np.finfo(un.dtype).eps
    gaps = np.asarray(p["lag_theta"])[:n_lags] ** 2 if layout.k else np.zeros(0)
    T, held = on_bounds(names, gaps)
    if int(used.sum()) > LONG_RECORD:
        cov, se, deficient, info = _long_record_fields(
            method, run, layout, theta, un, yn, mask, s, x0, z0, dt, index, eps, CHUNK, T
        )
    else:
        pred, J = jacobian(run, layout, theta, un, s, x0, z0, dt)
        m = np.asarray(mask)[used]
        y = np.asarray(yn)[used] * yh + ym
        Ju = np.asarray(J)[used][:, index] * m[:, None]
        e = (y - np.asarray(pred)[used]) * m
        cov, se, deficient, info = estimate(Ju @ T, e, method=method, eps=eps)
    # Back to every parameter: a held time constant follows the one below it (or none).
    cov = T @ cov @ T.T
    deficient = (np.abs(T) > 0) @ deficient > 0
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    se[deficient] = np.inf
    values = theta[index]
    scale = scales(names, values, uh, yh)
    undetermined = deficient | ~(se < RELATIVE_LIMIT * scale)
    return dict(
        parameter_names=names,
        parameter_values=_checks.to_device(values),
        covariance=_checks.to_device(cov),
        std_errors=_checks.to_device(se),
        undetermined=_checks.to_device(undetermined),
        covariance_method=method,
        residual_std=_checks.to_device(theta.dtype.type(info["sigma"])),
        held=_checks.to_device(held),
    )


def on_bounds(names, gaps):
    """Which creep time constants sit on their bounds, and the map from the free parameters.

    A lag's free parameter θ_k (`time_constants.py`) is the square root of its time constant's
    gap above its bound, in log τ: the floor for the fastest lag, √10 times the previous lag for
    the others. A gap below `HOLD` (τ within 0.2 % of its bound) means the data pushed the lag
    onto the bound, where the constraint, not the data, fixes it: the fastest lag's time
    constant is then a constant, another lag's is √10 times the previous one's. The covariance
    treats such a time constant as the constraint does (the estimate's spread is that of the
    parameters it follows), rather than as a free parameter the data barely move, which its
    Jacobian column would make undetermined.

    **Arguments:** `names` (p,), the fit's parameter names; `gaps` (K,), the lags' θ_k².

    **Returns:** `(T, held)`: T (p, q) with the parameters = T · (the q free ones), locally, and
    `held` (p,) booleans.
    """
    p = len(names)
    A = np.eye(p)
    held = np.zeros(p, bool)
    where = {n: i for i, n in enumerate(names)}
    for k, gap in enumerate(gaps):
        if gap >= HOLD:
            continue
        i = where[f"creep.time_constants[{k}]"]
        held[i] = True
        A[i] = LAG_RATIO * A[where[f"creep.time_constants[{k - 1}]"]] if k else 0.0
    return A[:, ~held], held


def _long_record_fields(method, run, layout, theta, un, yn, mask, s, x0, z0, dt, index, eps, chunk, T):
    """`estimate`'s covariance from [`moments`][], on a record too long to hold J."""
    theta = _checks.to_device(theta)
    m = jnp.asarray(mask, theta.dtype)
    y = jnp.asarray(yn) * s.y_half + s.y_mid
    used = np.asarray(mask) > 0
    window = 1
    if method == "newey-west":
        # The block length comes from the residuals' lag-1 correlation: one pass without J.
        pred = _long_prediction(run, layout, theta, jnp.asarray(un), s, x0, z0, dt)
        window = bandwidth_of(*_lag_sums(np.asarray(y), np.asarray(pred), np.asarray(mask)))
        del pred
    R, Rw, ete = moments(
        run, layout, theta, jnp.asarray(un), y, m, s, x0, z0, dt, window, chunk, method == "newey-west"
    )
    # J's selected columns mapped by T are Q (R[:, index] T): the same singular values; the
    # block sums' factor maps alike.
    factor = np.asarray(R, np.float64)[:, index] @ T
    blocks = np.asarray(Rw, np.float64)[:, index] @ T
    return estimate_moments(factor, blocks, float(ete), int(used.sum()), method=method, window=window, eps=eps)


# The long-record covariance's prediction over every sample, compiled per layout and length.
_long_prediction = bounded_jit(2)(prediction)


def _lag_sums(y, pred, mask, block: int = 2**20):
    """Σ e², Σ e_t e_(t-1) and N of the weighted residuals e = (y - pred) mask on the used
    samples (mask > 0), consecutive used samples paired as [`bandwidth`][] pairs them, a block
    at a time: the whole (T,) residual and its selections would be several copies of the
    record's length."""
    den = cross = 0.0
    n = 0
    last = None
    for i in range(0, y.shape[0], block):
        mm = mask[i : i + block]
        keep = mm > 0
        e = ((y[i : i + block] - pred[i : i + block])[keep] * mm[keep]).astype(np.float64)
        if e.size == 0:
            continue
        den += float(e @ e)
        cross += float(e[1:] @ e[:-1]) + (0.0 if last is None else last * float(e[0]))
        last, n = float(e[-1]), n + e.size
    return den, cross, n


def flagged_names(names, flags) -> tuple:
    """The names whose flag is set (none when `flags` is None)."""
    if flags is None:
        return ()
    return tuple(n for n, bad in zip(names, np.asarray(flags)) if bad)


def report_keys(fit) -> dict:
    """A fit's uncertainty as fit.json has it: `std_errors` by parameter name, `covariance`
    (method, parameter names, matrix) and `undetermined` (names); none without a covariance."""
    if fit.std_errors is None:
        return {}
    return {
        "std_errors": dict(zip(fit.parameter_names, fit.std_errors)),
        "covariance": {
            "method": fit.covariance_method,
            "parameter_names": fit.parameter_names,
            "matrix": fit.covariance,
        },
        "undetermined": fit.undetermined_names,
        **({"held_on_bounds": fit.held_names} if getattr(fit, "held", None) is not None else {}),
    }


def play_flags(names, undetermined, n_plays):
    """Plays with an undetermined threshold, weight or initial state."""
    flags = np.zeros(n_plays, bool)
    for name, bad in zip(names, np.asarray(undetermined)):
        if bad and name.split("[")[0] in ("thresholds", "weights", "initial_states"):
            flags[int(name.split("[")[1][:-1])] = True
    return flags


def table(fit) -> str:
    """A `value ± std error` table of a fit's parameters in Markdown, each value rounded to its
    standard error, undetermined ones and ones held on a bound marked.

    **Arguments:** `fit`, a `PIFit` with a covariance.

    **Returns:** the table's text (one header, one row per parameter).
    """
    rows = [_table.HEADER]
    held = set(getattr(fit, "held_names", ()))
    for n, v, s, bad in zip(
        fit.parameter_names, np.asarray(fit.parameter_values), np.asarray(fit.std_errors), np.asarray(fit.undetermined)
    ):
        rows.append(_table.row(n, float(v), float(s), undetermined=bool(bad), held=n in held))
    return "\n".join(rows) + "\n"
