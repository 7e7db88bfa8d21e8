"""The discrete Preisach model, built on the play bank.

**Relays are plays read at a level.** A relay with switching values β ≤ α (it switches up when
u ≥ α, down when u ≤ β, and otherwise keeps its state) has centre c = (α + β)/2 and half-width
r = (α - β)/2. Its state equals sign(H_r[u] - c), H_r the play with threshold r: the play state x
lies in [u - r, u + r], so u ≥ α = c + r forces x ≥ c and u ≤ β = c - r forces x ≤ c, while for
u in (β, α) a push of the play moves x to u ∓ r, which stays on the same side of c. The two agree
except at ties (x = c exactly), and the play's initial state sets every relay's initial state.
So one play per half-width serves a whole row of relays: K plays give K·M relays.

**Blurred relays.** Each relay is read through s = clip((H_r[u] - c)/δ, -1, 1) instead of the sign:
a relay spread over its centre cell, δ half the centre spacing. The model

    y = offset + Σ_km μ_km clip((H_{r_k}[u] - c_m)/δ_m, -1, 1)

is then continuous and piecewise linear in the input and in every parameter, so gradients exist
almost everywhere (the sign would give none), and it tends to the relay model as δ -> 0. With
uniform centres whose cells tile [c_1 - δ, c_M + δ], equal weights along c sum to an affine
function of the play output there: the PI model is the special case μ_km = w_k. A general density
gives minor loops whose shape depends on where they sit (non-congruent), which no PI can.

**Properties that hold for every density.** |y - offset| ≤ Σ|μ| (each s in [-1, 1]); wiping-out
(an excursion to a new maximum and then a new minimum erases the memory of smaller earlier ones,
because each play's state does); rate independence. With μ ≥ 0 the output is non-decreasing in the
current input for a fixed past (each s is non-decreasing in H_r, each H_r in u), which is what the
inverse needs: `Preisach.inverse` finds, sample by sample in a `lax.scan` carrying the play
states, the set [u_L, u_U] of inputs that give the target output (two bisections) and takes the
point of it nearest the previous input (the least motion; the set is one point wherever the output
is strictly increasing). A target beyond what the model can reach gives the nearest end of the
input range it saturates at. A negative density raises `ValueError` ("cannot be inverted").

The play bank is `_operators.play.play`, so the compiled kernel path is the same as the PI's.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float

from .. import _checks
from .._custom_types import Signal, SignalLike
from .._operators.play import Method, play, play_step
from .model import AbstractHysteresisModel

Widths = Float[Array, " widths"]
Centres = Float[Array, " centres"]
Density = Float[Array, "widths centres"]


def default_blur(centres) -> np.ndarray:
    """Half the spacing of each centre to its nearest neighbour, (M,), for concrete centres (M ≥ 2)."""
    c = np.asarray(centres, dtype=np.float64)
    gaps = np.diff(c)
    left = np.concatenate([gaps[:1], gaps])
    right = np.concatenate([gaps, gaps[-1:]])
    return 0.5 * np.minimum(left, right)


def relay_columns(H: Array, centres: Array, blur: Array) -> Array:
    """The blurred relays s (T, K·M) from play outputs H (T, K): row-major over (k, m).

    **Arguments:** `H` (T, K) play outputs; `centres` (M,); `blur` (M,) > 0.

    **Returns:** (T, K·M), column k·M + m holding clip((H_k - c_m)/δ_m, -1, 1).
    """
    s = jnp.clip((H[:, :, None] - centres) / blur, -1.0, 1.0)
    return s.reshape(H.shape[0], -1)


def relay_chunk(uu, x, half_widths, centres, blur, method: Method = "scan"):
    """One chunk of the regressors: the blurred relays plus a constant, as the plays run on.

    **Arguments:** `uu` (m,), the chunk's input; `x` (K,), the plays' states before it; the grid
    (`half_widths` (K,), `centres` (M,), `blur` (M,)); `method`, the play bank's method.

    **Returns:** `(S, x_after)`: S (m, K·M + 1), the constant last, and the plays' states after
    the chunk.
    """
    H = play(uu, half_widths, x, method=method)
    ones = jnp.ones((uu.shape[0], 1), uu.dtype)
    return jnp.concatenate([relay_columns(H, centres, blur), ones], 1), H[-1]


def _vector(x, name: str) -> Array:
    x = jnp.atleast_1d(_checks.as_float_array(x, name))
    if x.ndim != 1 or x.shape[0] < 1:
        raise ValueError(f"`{name}` must be a non-empty vector, got shape {x.shape}")
    return _checks.finite(x, name)


def _increasing(x: Array, name: str, strict: bool) -> Array:
    if _checks.is_concrete(x):
        d = np.diff(np.asarray(x))
        if np.any(d <= 0) if strict else np.any(d < 0):
            raise ValueError(
                f"`{name}` must be {'strictly ' if strict else ''}increasing, got {np.asarray(x).tolist()}"
            )
        return x
    bad = jnp.any(jnp.diff(x) <= 0) if strict else jnp.any(jnp.diff(x) < 0)
    return eqx.error_if(x, bad, f"`{name}` must be increasing")


class Preisach(AbstractHysteresisModel):
    """A discrete Preisach model: blurred relays on a grid of half-widths × centres.

    y = offset + Σ_km μ_km clip((H_{r_k}[u] - c_m)/δ_m, -1, 1), H_r the play with threshold r (a
    relay with switching values c ± r is sign(H_r[u] - c)); see the module notes for why.

    **Arguments:**

    - `half_widths` (K,): r_k ≥ 0, increasing (the relays' (α - β)/2; one play each).
    - `centres` (M,): c_m, strictly increasing (the relays' (α + β)/2).
    - `density` (K, M): μ_km, the weight of the relay (r_k, c_m).
    - `offset`: the constant added to the output.
    - `initial_states`: the plays' states before the first sample, a scalar or (K,); None (the
      default) starts every play relaxed at the first input, x_k = u_0.
    - `blur`: δ, a positive scalar or (M,); None (the default) takes half the distance from each
      centre to its nearest neighbour (needs M ≥ 2).
    - `method`: the play bank's method (`"scan"`, `"associative"`, `"kernel"` or `"auto"`, as
      for [`play`][piest_jax.play]).

    Shapes, ordering and non-finite values raise `ValueError` (through `eqx.error_if` for traced
    values). `__call__` takes one signal (T,); batch with `jax.vmap`. With a non-negative density
    the model is invertible: [`inverse`][piest_jax.Preisach.inverse].
    """

    half_widths: Widths
    centres: Centres
    density: Density
    offset: Array
    initial_states: Float[Array, " widths"] | None
    blur: Centres
    method: Method = eqx.field(static=True)

    def __init__(
        self, half_widths, centres, density, offset=0.0, initial_states=None, blur=None, method: Method = "scan"
    ):
        r = _checks.thresholds(_vector(half_widths, "half_widths"), "half_widths")
        r = _increasing(r, "half_widths", strict=False)
        c = _increasing(_vector(centres, "centres"), "centres", strict=True)
        k, m = r.shape[0], c.shape[0]
        mu = _checks.as_float_array(density, "density")
        if mu.shape != (k, m):
            raise ValueError(
                f"`density` must have shape (K, M) = ({k}, {m}) for {k} half-widths and {m} centres, got {mu.shape}"
            )
        mu = _checks.finite(mu, "density")
        off = _checks.as_float_array(offset, "offset")
        if off.ndim != 0:
            raise ValueError(f"`offset` must be a scalar, got shape {off.shape}")
        off = _checks.finite(off, "offset")
        if blur is None:
            if m < 2:
                raise ValueError("one centre has no spacing: give `blur` (δ > 0) explicitly")
            if not _checks.is_concrete(c):
                raise ValueError("traced `centres` need an explicit `blur`")
            d = jnp.asarray(default_blur(c))
        else:
            d = _vector(blur, "blur")
            if d.shape[0] not in (1, m):
                raise ValueError(f"`blur` must be a scalar or ({m},), got {d.shape[0]} entries")
            d = jnp.broadcast_to(d, (m,))
            if _checks.is_concrete(d):
                if np.any(np.asarray(d) <= 0):
                    raise ValueError(f"`blur` must be positive, got {np.asarray(d).tolist()}")
            else:
                d = eqx.error_if(d, jnp.any(d <= 0), "`blur` must be positive")
        if method not in ("scan", "associative", "kernel", "auto"):
            raise ValueError(f"unknown play method {method!r}")
        dtype = jnp.result_type(r, c, mu, off, d)
        self.half_widths = r.astype(dtype)
        self.centres = c.astype(dtype)
        self.density = mu.astype(dtype)
        self.offset = off.astype(dtype)
        self.blur = d.astype(dtype)
        if initial_states is None:
            self.initial_states = None
        else:
            x0 = _checks.finite(_checks.per_play(initial_states, k, "initial_states"), "initial_states")
            self.initial_states = jnp.broadcast_to(x0, (k,)).astype(dtype)
        self.method = method

    @property
    def structure(self) -> str:
        """`"preisach"`, the name model files give this structure."""
        return "preisach"

    @property
    def shape(self) -> tuple[int, int]:
        """(K, M): the number of half-widths and of centres."""
        K, M = self.density.shape
        return K, M

    def _start(self, u: Array) -> Array:
        if self.initial_states is None:
            return jnp.broadcast_to(u[0], self.half_widths.shape)
        return self.initial_states

    def plays(self, u: SignalLike) -> Float[Array, "time widths"]:
        """The play outputs H_{r_k}[u] (T, K) that drive the relays.

        **Arguments:** `u` (T,), the input.

        **Returns:** (T, K).
        """
        u = _checks.signal(u)
        u = u.astype(jnp.result_type(u, self.density))
        return play(u, self.half_widths.astype(u.dtype), self._start(u).astype(u.dtype), method=self.method)

    def basis(self, u: SignalLike) -> Float[Array, "time cells"]:
        """The blurred relay outputs s_km (T, K·M), so that y = offset + basis(u) @ density.ravel().

        **Arguments:** `u` (T,), the input.

        **Returns:** (T, K·M), row-major over (half-width, centre).
        """
        H = self.plays(u)
        return relay_columns(H, self.centres.astype(H.dtype), self.blur.astype(H.dtype))

    def init_state(self, u0):
        """The plays' states before the first sample: the model's own, else relaxed at `u0`."""
        if self.initial_states is None:
            return jnp.broadcast_to(jnp.asarray(u0, self.density.dtype), self.half_widths.shape)
        return self.initial_states

    def step(self, state, u):
        """One sample: the plays' states after the input `u`, and the output there."""
        return self._step_output(state, u)

    def with_state(self, state) -> "Preisach":
        """The same model with its plays started from `state`."""
        return self.with_initial_states(state)

    def __call__(self, u: SignalLike, state=None) -> Signal:
        """The model output (T,) for one input signal `u` (T,), from `state` (the plays' states;
        default the model's own, else relaxed at the first input)."""
        m = self if state is None else self.with_state(state)
        return _relay_sum(m.plays(u), m.centres, m.blur, m.density, m.offset)

    def final_state(self, u: SignalLike, state=None):
        """The plays' states after the last sample of `u`."""
        m = self if state is None else self.with_state(state)
        return m.final_states(u)

    def with_initial_states(self, play_states) -> "Preisach":
        """The same model with its plays started from `play_states` (scalar or (K,); None: at
        rest at each record's first input).

        **Arguments:** `play_states`, the plays' states before the first sample, or None.

        **Returns:** a new `Preisach`.
        """
        return Preisach(self.half_widths, self.centres, self.density, self.offset, play_states, self.blur, self.method)

    def final_states(self, u: SignalLike) -> Float[Array, " widths"]:
        """The plays' states after the last sample of `u` (to continue a run where it ended).

        **Arguments:** `u` (T,), the input.

        **Returns:** (K,).
        """
        return self.plays(u)[-1]

    def _step_output(self, x: Array, u: Array) -> tuple[Array, Array]:
        """The play states after input `u` from states `x` (K,), and the model output there."""
        x = play_step(x, u, self.half_widths)
        s = jnp.clip((x[:, None] - self.centres) / self.blur, -1.0, 1.0)
        return x, self.offset + jnp.sum(self.density * s)

    def input_range(self) -> tuple[Array, Array]:
        """The inputs beyond which every relay is saturated: (c_1 - δ_1 - r_K, c_M + δ_M + r_K).

        **Returns:** `(lo, hi)`, scalars.
        """
        r = self.half_widths[-1]
        return self.centres[0] - self.blur[0] - r, self.centres[-1] + self.blur[-1] + r

    def inverse_step(self, x: Array, y: Array, u_prev: Array, n_iter: int = 60):
        """One sample of the inverse: the input that takes the output to `y` from play states `x`.

        Needs a non-negative density (then the output is non-decreasing in the input for fixed
        states). Two bisections on [lo, hi] = `input_range()` find the smallest input u_L whose
        output reaches `y` and the largest u_U whose output does not pass it; the input returned is
        `u_prev` clipped to [u_L, u_U].

        **Arguments:** `x` (K,), the play states before this sample; `y`, the target output;
        `u_prev`, the previous input; `n_iter`, bisection steps (60 reach float64 resolution).

        **Returns:** `(x_new, u)`: the play states after the input, and the input.
        """
        lo, hi = self.input_range()

        def bisect(reach):
            def body(_, bounds):
                a, b = bounds
                mid = 0.5 * (a + b)
                ok = reach(self._step_output(x, mid)[1])
                return jnp.where(ok, a, mid), jnp.where(ok, mid, b)

            return lax.fori_loop(0, n_iter, body, (lo, hi))

        # Smallest u with f(u) >= y (b), largest u with f(u) <= y (a).
        _, u_lo = bisect(lambda f: f >= y)
        u_hi, _ = bisect(lambda f: f > y)
        u = jnp.clip(u_prev, jnp.minimum(u_lo, u_hi), jnp.maximum(u_lo, u_hi))
        return self._step_output(x, u)[0], u

    def inverse_problem(self) -> str | None:
        """Why the model has no inverse (a negative density entry), or None."""
        mu = np.asarray(self.density)
        if np.any(mu < 0):
            return f"its density has {int(np.sum(mu < 0))} negative entries (down to {mu.min():.4g})"
        return None

    def inverse(self, y: SignalLike, state=None, *, n_iter: int = 60) -> Signal:
        """The input u (T,) whose output follows `y` (T,): the compensator of a monotone model.

        The plays start from `initial_states`; when those are None (relaxed at the first input),
        the first input solves the relaxed model offset + Σ μ_km clip((u - c_m)/δ_m, -1, 1) = y_0
        and the plays start at it (from given states, the first step starts at their mean). Then
        each sample is [`inverse_step`][piest_jax.Preisach.inverse_step] in a `lax.scan`. Where
        `y` is beyond what the model reaches, the input saturates at an end of `input_range()`.

        **Arguments:** `y` (T,), the desired output; `state`, the plays' states at the start
        (default `initial_states`); `n_iter`, bisection steps per sample.

        **Returns:** the input u (T,), with `self(u)` equal to `y` wherever `y` is reachable.
        """
        y = _checks.finite(_checks.signal(y, "y"), "y").astype(self.density.dtype)
        mu = self.density
        if _checks.is_concrete(mu):
            if np.any(np.asarray(mu) < 0):
                raise ValueError(
                    "this Preisach model cannot be inverted: its density has negative "
                    "entries (fit with monotone=True for an invertible model)"
                )
        else:
            mu = eqx.error_if(mu, jnp.any(mu < 0), "a negative density cannot be inverted")
        m = self if state is None else self.with_state(state)
        return _inverse(eqx.tree_at(lambda m: m.density, m, mu), y, n_iter)


# Compiled as one program: run op by op, a new record length compiled each of its operations.
@jax.jit
def _relay_sum(H, centres, blur, density, offset):
    """offset + Σ_km density_km s_km with s_km the relays blurred over `blur` around `centres`."""
    s = jnp.clip((H[:, :, None] - centres) / blur, -1.0, 1.0)
    return offset + jnp.einsum("tkm,km->t", s, density)


# Jitted at module level so that repeat calls with the same shapes reuse one compiled program (the
# eager loops below would compile, and keep, new ones on every call).
@eqx.filter_jit
def _inverse(model: Preisach, y, n_iter: int):
    mu = model.density
    if model.initial_states is None:
        lo, hi = model.input_range()

        # Relaxed plays sit at the input itself: bisection with x = u for every play.
        def f0(u):
            s = jnp.clip((u - model.centres) / model.blur, -1.0, 1.0)
            return model.offset + jnp.sum(mu * s)

        def body(_, bounds):
            a, b = bounds
            mid = 0.5 * (a + b)
            ok = f0(mid) >= y[0]
            return jnp.where(ok, a, mid), jnp.where(ok, mid, b)

        _, u0 = lax.fori_loop(0, n_iter, body, (lo, hi))
        # The first input is u0 itself: the forward model starts its plays at its first input.
        x0, first, rest = jnp.full_like(model.half_widths, u0), u0[None], y[1:]
    else:
        x0 = model.initial_states
        u0, first, rest = jnp.mean(x0), y[:0], y

    def step(carry, yt):
        x, u_prev = carry
        x, u = model.inverse_step(x, yt, u_prev, n_iter)
        return (x, u), u

    _, us = lax.scan(step, (x0, u0), rest)
    return jnp.concatenate([first, us])
