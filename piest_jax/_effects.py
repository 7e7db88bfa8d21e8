"""The base PI model and the seven effects it can be augmented with, as one parameterised model.

All effects live in one model whose parameter groups are switched on or off by a 0/1 mask that is a
traced argument. Every candidate (the base model, one effect, two effects, ...) therefore shares a
single compiled residual and a single compiled Levenberg-Marquardt solve per record length; a switched-
off group is held at its neutral value and its Jacobian columns are zero.

The model, in normalised units (input and output scaled to about [-1, 1]):

    g_t   = u_t + b2 u_t^2 + b3 u_t^3                         (asymmetry: input envelope)
    r_j(t)= max(r_j (1 + beta rho_t^p) + gamma rho_t^p, 0)    (rate_dependence; rho = |du/dt| scaled)
    x_t   = clamp(x_{t-1}, g_t - r_j(t), g_t + r_j(t)),  x_{-1} = g_0 + dx0   (initial_state)
    v_t   = sum_j w_j x_{t,j}
    v'_t  = v(t - d)                                          (delay, fractional, linear interpolation)
    z     = H(s) v',  H = omega^2 / (s^2 + 2 zeta omega s + omega^2)   (linear_dynamics, unit DC gain)
    y_t   = z_t + a2 z_t^2 + a3 z_t^3                         (asymmetry: output nonlinearity)
            + sum_k c_k lowpass_{tau_k}(z)_t                  (creep, slow first-order modes)
            + offset + sum_k d_k cos(k pi s_t)                (offset_drift, s = time / duration)

Thresholds satisfy 0 = r_1 < r_2 < ... by construction (softplus increments). Time constants and the
delay are physical (seconds), so a model fitted on a sub-sampled record runs unchanged at full rate.
"""

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax import lax
from jaxtyping import Array

EFFECTS = (
    "initial_state",
    "delay",
    "linear_dynamics",
    "rate_dependence",
    "creep",
    "asymmetry",
    "offset_drift",
)
N_PLAYS = 8
_GROUP_SIZES = {
    "base": 2 * N_PLAYS,  # n - 1 threshold increments, n weights, one offset
    "initial_state": N_PLAYS,
    "delay": 1,
    "linear_dynamics": 2,
    "rate_dependence": 3,
    "creep": 5,
    "asymmetry": 4,
    "offset_drift": 4,
}
_ORDER = ("base", *EFFECTS)
# Creep modes: log-spaced time constants in units of the input's dominant period, times one fitted
# scale >= 1, so that exponential and logarithmic creep laws are both sums of these modes. Creep is
# slow by definition: no mode is faster than half a period, which keeps it apart from the
# actuator and sensor dynamics (fast, `linear_dynamics`).
CREEP_TAUS = (0.5, 2.0, 8.0, 32.0)
_STARTS = dict(zip(_ORDER, np.cumsum([0] + [_GROUP_SIZES[k] for k in _ORDER])[:-1].tolist()))
N_PARAMS = sum(_GROUP_SIZES.values())
# A weak pull of every effect parameter towards its starting value keeps the normal equations
# regular when an effect is switched off or not excited; it is far below any data term.
_RIDGE = 1e-4
_RHO_EPS = 1e-3


def n_effect_params(name: str) -> int:
    """The number of parameters an effect adds to the base PI model.

    **Arguments:** `name`, one of `EFFECTS`.

    **Returns:** the count.
    """
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; choose from {EFFECTS}")
    return _GROUP_SIZES[name]


def _sl(name):
    return slice(_STARTS[name], _STARTS[name] + _GROUP_SIZES[name])


def _softplus_inv(x):
    return np.log(np.expm1(x))


class ModelData(NamedTuple):
    """One record prepared for the model; every field is an array so records share compilations.

    `u`, `y`, `rho`, `s`, `fit_w` are (T,); `dt` is this record's sampling step, `delay_unit` the
    unit of the delay parameter (the full-rate step), `omega_ref` the natural frequency the dynamics
    start from, `period` the input's dominant period (the unit of the creep time constants).
    """

    u: Array
    y: Array
    rho: Array
    s: Array
    fit_w: Array
    dt: Array
    delay_unit: Array
    omega_ref: Array
    period: Array


def group_mask(names) -> np.ndarray:
    """A 0/1 vector over `EFFECTS` with ones for `names` (the effects switched on).

    **Arguments:** `names`, an iterable of effect names.

    **Returns:** float array (7,).
    """
    names = list(names)
    for n in names:
        n_effect_params(n)
    return np.array([1.0 if e in names else 0.0 for e in EFFECTS])


def initial_params(u0_thresholds_scale: float = 1.0) -> np.ndarray:
    """Starting parameters: uniform thresholds over [0, 0.9 scale), unit total weight, effects neutral.

    **Arguments:** `u0_thresholds_scale`, half the normalised input range (1 for inputs in [-1, 1]).

    **Returns:** the flat parameter vector (N_PARAMS,).
    """
    th = np.zeros(N_PARAMS)
    n = N_PLAYS
    base = np.concatenate(
        [np.full(n - 1, _softplus_inv(0.9 * u0_thresholds_scale / n)), np.full(n, 1.0 / n), [0.0]]
    )
    th[_sl("base")] = base
    th[_sl("delay")] = _softplus_inv(1.0)
    th[_sl("linear_dynamics")] = [0.0, _softplus_inv(0.7)]
    th[_sl("creep")] = 0.0
    return th


def thresholds_of(theta) -> Array:
    """The thresholds r (n,) encoded in a parameter vector (r_1 = 0, positive increments)."""
    inc = jax.nn.softplus(theta[_sl("base")][: N_PLAYS - 1])
    return jnp.concatenate([jnp.zeros(1, inc.dtype), jnp.cumsum(inc)])


def weights_of(theta) -> Array:
    """The play weights (n,) encoded in a parameter vector."""
    return theta[_sl("base")][N_PLAYS - 1 : 2 * N_PLAYS - 1]


def _zoh2(omega, zeta, dt):
    a = jnp.array([[0.0, 1.0], [-(omega**2), -2 * zeta * omega]], dtype=dt.dtype)
    b = jnp.array([[0.0], [1.0]], dtype=dt.dtype) * omega**2
    m = jnp.zeros((3, 3), dt.dtype).at[:2, :2].set(a).at[:2, 2:].set(b)
    e = jax.scipy.linalg.expm(m * dt)
    return e[:2, :2], e[:2, 2]


def predict(theta: Array, groups: Array, data: ModelData) -> Array:
    """The augmented model's normalised output for one record.

    **Arguments:**

    - `theta`: the flat parameter vector (N_PARAMS,).
    - `groups`: the 0/1 effect mask (7,), in the order of `EFFECTS`.
    - `data`: the record, a `ModelData`.

    **Returns:** the model output (T,).
    """
    m_init, m_delay, m_dyn, m_rate, m_creep, m_asym, m_drift = (groups[i] for i in range(7))
    u, rho = data.u, data.rho
    b2, b3, a2, a3 = theta[_sl("asymmetry")]
    g = u + m_asym * (b2 * u**2 + b3 * u**3)
    r = thresholds_of(theta)
    beta, gamma, lp = theta[_sl("rate_dependence")]
    # rho^p with a fitted exponent (p = 1 at the start); the small shift keeps d/dp finite at rho = 0.
    rp = (jnp.exp(jnp.exp(lp) * jnp.log(rho + _RHO_EPS)) - jnp.exp(jnp.exp(lp) * jnp.log(_RHO_EPS)))[:, None]
    rt = jnp.maximum(r[None, :] * (1 + m_rate * beta * rp) + m_rate * gamma * rp, 0.0)
    x0 = g[0] + m_init * theta[_sl("initial_state")]

    def play_step(x, inp):
        gt, rtt = inp
        x = jnp.maximum(gt - rtt, jnp.minimum(gt + rtt, x))
        return x, x

    _, xs = lax.scan(play_step, x0, (g, rt))
    v = xs @ weights_of(theta)

    d = m_delay * jax.nn.softplus(theta[_sl("delay")][0]) * data.delay_unit / data.dt
    idx = jnp.arange(v.shape[0], dtype=v.dtype)
    v = jnp.interp(idx - d, idx, v)

    lw, zr = theta[_sl("linear_dynamics")]
    ad, bd = _zoh2(data.omega_ref * jnp.exp(lw), jax.nn.softplus(zr), data.dt)
    cp = theta[_sl("creep")]
    taus = data.period * (1 + jax.nn.softplus(cp[4])) * jnp.asarray(CREEP_TAUS, dtype=v.dtype)
    lam = jnp.exp(-data.dt / taus)

    def filt_step(carry, vt):
        s, c, vprev = carry
        # The input averaged over the step (a first-order hold) keeps the filter free of the
        # half-sample lag a zero-order hold would add, which would look like a delay.
        s = ad @ s + bd * 0.5 * (vt + vprev)
        z = m_dyn * s[0] + (1 - m_dyn) * vt
        c = lam * c + (1 - lam) * z
        return (s, c, vt), (z, c)

    init = (jnp.stack([v[0], jnp.zeros_like(v[0])]), jnp.full(len(CREEP_TAUS), v[0]), v[0])
    _, (z, cs) = lax.scan(filt_step, init, v)
    y = z + m_asym * (a2 * z**2 + a3 * z**3)
    y = y + m_creep * (cs @ cp[:4])
    k = jnp.arange(1, 5, dtype=v.dtype)
    drift = jnp.cos(jnp.pi * data.s[:, None] * k[None, :]) @ theta[_sl("offset_drift")]
    return y + theta[_STARTS["base"] + 2 * N_PLAYS - 1] + m_drift * drift


def _residual(theta, args):
    groups, data, theta_ref = args
    res = data.fit_w * (predict(theta, groups, data) - data.y)
    start = _STARTS["initial_state"]
    return jnp.concatenate([res, _RIDGE * (theta[start:] - theta_ref[start:])])


class FitResult(NamedTuple):
    """A fit's parameters, whether the solver reported success, and its step count."""

    theta: Array
    success: Array
    steps: Array


@functools.partial(jax.jit, static_argnames="max_steps")
def fit(theta0: Array, groups: Array, data: ModelData, *, max_steps: int = 60) -> FitResult:
    """Fit the model with the effects in `groups` switched on, by Levenberg-Marquardt (optimistix).

    Samples with `data.fit_w == 0` (held-out blocks, padding) do not enter the fit but the model
    still runs through them, so states carry across. Compiled once per record length.

    **Arguments:**

    - `theta0`: starting parameters (N_PARAMS,), e.g. the current model's fit with a new effect's
      parameters at their neutral start.
    - `groups`: the 0/1 effect mask (7,).
    - `data`: a `ModelData`.
    - `max_steps`: the solver's step budget.

    **Returns:** a `FitResult`; `success` is False when the solver stopped without converging (the
    parameters are still its best point).
    """
    solver = optx.LevenbergMarquardt(rtol=1e-5, atol=1e-7)
    sol = optx.least_squares(
        _residual, solver, theta0, args=(groups, data, theta0), max_steps=max_steps, throw=False
    )
    theta = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, theta0)
    return FitResult(theta, sol.result == optx.RESULTS.successful, sol.stats["num_steps"])


predict_jit = jax.jit(predict)
