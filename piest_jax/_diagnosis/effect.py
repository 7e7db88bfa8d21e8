"""What a named effect is: one class that the search, the refinement, the generator and the CLI share.

A diagnosis model runs one signal chain, in stages:

    input map g(u) -> thresholds r(t) -> initial states x0 -> plays H = H_r(g)
    -> play terms: X = [H, 1, F(H)] (functions of each play's output)
    -> linear filters on X (delay, dynamics) -> v = X w
    -> output terms: y = v + sum_k T_k(v) c_k (output map, creep, drift over time)

Each effect acts at one or more stages and says how, twice: in NumPy for the variable-projection
search (`diagnose.py`, where the output terms are columns with linear coefficients) and in JAX for
the joint refinement (`refine.py`, where every parameter moves at once). Within a stage, effects
act in the order of their `rank`, which is also the order their coefficients take in the
coefficient vector [play weights, offset, play terms..., output terms...]. An effect also says what its
parameters are (`grid`, `neighbours`, `describe`) and how a synthetic record shows it
(`draw`, `synth_*`: the hidden-effect generator's physical forms, deliberately not the fitted
ones). The default of every hook is "this effect does not act here".

The configuration `q` of an effect is its grid value: a hashable tuple or number; the refined
parameters live in a dict `theta` under keys the effect chooses (distinct from every other
effect's).
"""

from typing import Any, ClassVar

import numpy as np


class AbstractEffect:
    """An effect a plain PI model misses, as the diagnosis models, searches and simulates it.

    Concrete effects are final classes, one module each in `effects/`, which finds them.
    """

    name: ClassVar[str]
    # One line for the CLI help and the docs.
    summary: ClassVar[str]
    # Position along the signal chain, within each stage (see the module docstring).
    rank: ClassVar[int]
    # Its place in the registry's listing (the order the search tries and reports candidates
    # in): a new effect takes the next free number.
    listed: ClassVar[int]
    # Parameters added: its linear coefficients plus its grid parameters (the search charges
    # each against the noise).
    n_params: ClassVar[int]
    # Tied to the record it was found on (the unrecorded past, a drift over the time axis): it
    # explains that record but cannot carry over to another run of the device.
    record_specific: ClassVar[bool] = False
    # A function of time rather than of the input: it gives way to an input-driven effect that
    # explains as much (`diagnose._prefer_input_driven`).
    time_driven: ClassVar[bool] = False
    # Acts before the plays (input map, thresholds, initial states): its grid needs fresh plays.
    play_side: ClassVar[bool] = False
    # Its output-term coefficients are kept >= 0 (for a form, see `positive_terms`).
    positive: ClassVar[bool] = False
    # Fixed-point or Gauss-Newton iterations its output terms need in `model.fit`.
    fit_iterations: ClassVar[int] = 1
    # Its output terms are nonlinear in v (`slope` is not None): `model.fit` keeps the best
    # Gauss-Newton iterate.
    bilinear: ClassVar[bool] = False

    def __init_subclass__(cls, abstract: bool = False, **kwargs):
        super().__init_subclass__(**kwargs)
        if abstract:  # a family of effects sharing hooks, not an effect of its own
            return
        missing = [a for a in ("name", "summary", "rank", "listed", "n_params") if not hasattr(cls, a)]
        if missing:
            raise TypeError(f"effect {cls.__name__} does not define {', '.join(missing)}")

    def __repr__(self) -> str:
        return f"<effect {self.name}>"

    # The search's parameters.

    def unidentifiable(self, p) -> str | None:
        """Why the prepared record `p` cannot show the effect, in words, or None when it can.

        An effect the record does not excite would be fitted to whatever it happens to match
        and would not carry over to another run; the search does not try it.
        """
        return None

    def grid(self, p) -> list:
        """The grid of the effect's nonlinear parameters for a prepared record `p`."""
        return [True]

    def neighbours(self, q, level: int) -> list:
        """Values around a grid point, for a local refinement (finer with each `level`)."""
        return []

    def describe(self, q) -> dict:
        """The parameters `q` in words (JSON-ready)."""
        return {}

    def charge(self, q) -> int:
        """The parameters the search charges against the noise at the value `q` (default: the
        class's `n_params`; an effect whose forms differ much in size decides per form)."""
        return self.n_params

    def positive_terms(self, q) -> bool:
        """Whether its output terms' coefficients are kept >= 0 at the value `q` (default:
        the class's `positive`; an effect whose forms differ decides per form)."""
        return self.positive

    # The NumPy model (variable projection).

    def changes_plays(self, q) -> bool:
        """Whether `q` changes the play columns (False lets the search reuse the plain ones)."""
        return self.play_side

    def input_map(self, q, g):
        """The plays' input after this effect (T,)."""
        return g

    def thresholds(self, q, p, r):
        """The plays' thresholds after this effect: (n,) or time-varying (T, n)."""
        return r

    def initial_states(self, q, g0, x0):
        """The plays' states before the first sample (n,)."""
        return x0

    def batch_play_columns(self, p, g, r, values):
        """Play columns for many grid values in one pass (C, T, n), or None."""
        return None

    def n_play_terms(self, q) -> int:
        """How many play-term columns (and coefficients) the effect adds."""
        return 0

    def play_terms(self, q, H):
        """Its play-term columns (T, n_play_terms): functions of the play outputs H (T, n)."""
        return np.zeros((len(H), 0))

    def linear(self, q, X, dt):
        """The columns X (T, p) after this effect's linear filter."""
        return X

    def n_columns(self, q) -> int:
        """How many output-term columns (and coefficients) the effect adds."""
        return 0

    def columns(self, q, p, v, drive, norm):
        """Its output-term columns (T, n_columns) at the hysteresis output `v`.

        `drive` is what slow terms follow (the output after the terms before this one), `norm`
        the (centre, half-range) of the identification record's hysteresis output.
        """
        return np.zeros((len(v), 0))

    def drive(self, q, drive, v0, norm, coef):
        """The drive for later terms once this effect's terms, at `v0` with `coef`, are added."""
        return drive

    def slope(self, q, v, norm, coef):
        """d(its terms @ coef)/dv (T,) for a Gauss-Newton step, or None when linear in v."""
        return None

    def transients(self, q, p):
        """Columns (T, k) of what its own state before the record adds (decays), or None."""
        return None

    # The JAX model (joint refinement).

    def static(self, q) -> Any:
        """The static (hashable) form of `q` that fixes the model's structure."""
        return True

    def init_theta(self, q, coef) -> dict:
        """Its refinement parameters from `q` and its output coefficients (NumPy)."""
        return {}

    def from_theta(self, q, theta) -> tuple[Any, list]:
        """The grid value and output coefficients a refined parameter set stands for."""
        return q, []

    def jax_input(self, theta, static, g):
        return g

    def jax_thresholds(self, theta, static, r, r0, rho):
        return r

    def jax_initial_states(self, theta, static, g0, x0):
        return x0

    def jax_play_terms(self, theta, static, H):
        """What its play terms add to the hysteresis output (T,), or None."""
        return None

    def jax_linear(self, theta, static, v, data):
        return v

    def jax_output(self, theta, static, y, v, data):
        """The output `y` (T,) after this effect's output terms; `v` is the hysteresis output,
        which the output map's terms are functions of (as in `columns`)."""
        return y

    # The synthetic form (hidden-effect generator).

    def draw(self, prng, ctx) -> dict:
        """Draw the effect's synthetic parameters; returns a state with its `form` in words."""
        return {"form": ""}

    def synth_input(self, state, ctx, chain) -> None:
        """Apply the effect before the plays: update `chain` (x0, u, rt, g) in place."""

    def synth_play_terms(self, state, ctx, X, w):
        """What the effect adds to the hysteresis output from the plays X (T, n) and weights w."""
        return 0.0

    def synth_linear(self, state, ctx, v):
        return v

    def synth_output(self, state, ctx, v, y):
        """The (hysteresis output, measured output) after this effect."""
        return v, y


def refinement_factor(level: int) -> float:
    """The ratio between a grid point and its neighbours at a refinement `level`.

    1.19, 1.09, 1.04, ...: below the grids' spacing, finer with each level.
    """
    return 2.0 ** (0.5 ** (level + 2))
