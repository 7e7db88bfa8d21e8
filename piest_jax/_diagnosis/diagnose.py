"""Name the effects a plain PI model misses: fit, score candidates on held-out blocks, repeat.

The loop: fit the base PI model (offset, relaxed initial states); for every effect not yet in the
model, add it and fit it over its grid of nonlinear parameters (`model`, `effects/`), and measure the
error on held-out blocks by blocked cross-validation (contiguous blocks, folds interleaved, the
model running through every block so states carry across; the first block, where the unrecorded
past acts, is fitted in every fold and never scored). The best candidate is named only if
its held-out gain, less a charge per parameter, is large against the noise floor and a real share
of the remaining error; then the loop repeats on what remains, and effects that a later one made
redundant are dropped again. Long records are sub-sampled for the search, with the plays run on
the kept samples plus the turning samples between them (`basis.turning_samples`), so the play
columns are the full-rate ones at the kept samples and no peak is lost; the model's time
constants and delay are physical, so the chosen model is then fitted and evaluated at full rate.
Finally the plain and the chosen model are refined jointly, every parameter at once, by optimistix
least squares (`_refine`), the machinery of `fit_pi`; a refinement is kept only when it lowers the
full-rate error.
"""

import itertools
import math

import numpy as np

from .._blas import on_one_blas_thread
from .._data.record import Record
from .._identification.compare import extrapolation, fit_percent
from .._identification.loop import loop_direction
from .._identification.solvers import check_solver
from .._progress import progress
from . import locate as _locate
from . import model as _model
from . import refine as _refine
from . import uncertainty as _uncertainty
from .diagnosis import Diagnosis, DiagnosisValidation
from .effect import AbstractEffect
from .effects import EFFECT, EFFECTS, chain, check_names
from .scaling import SMOOTHER, effective_samples, half_cycle
from .scaling import Scaling as Scaling
from .scaling import check_record as check_record
from .scaling import noise_std as noise_std
from .scaling import prepared as prepared
from .scaling import scaling_of as scaling_of

SEARCH_SAMPLES = 2048
REFINE_SAMPLES = 10_000
# Naming thresholds: the held-out MSE gain, less PARAM_PENALTY sigma^2 per parameter per sample,
# must exceed MIN_GAIN_NOISE sigma^2 and MIN_GAIN_REL of the current held-out MSE. A gain below
# about sigma^2 is what an imperfect form of the first effect leaves for a second one to pick up,
# and it moves the RMSE by less than the 1.5x-noise tolerance a model is judged by.
MIN_GAIN_NOISE = 1.2
MIN_GAIN_REL = 0.03
PARAM_PENALTY = 2.0
MAX_EFFECTS = 3


def _frozen(v):
    """A hashable stand-in for a configuration value that tells apart every value `fit` does:
    floats by their bits, tuples (and tuple subclasses such as creep's `Lags`) with their type
    and attributes."""
    if isinstance(v, dict):
        return ("dict", tuple(sorted((k, _frozen(x)) for k, x in v.items())))
    if isinstance(v, tuple | list):
        attrs = tuple(sorted((k, _frozen(x)) for k, x in vars(v).items())) if hasattr(v, "__dict__") else ()
        return (type(v).__name__, tuple(_frozen(x) for x in v), attrs)
    if isinstance(v, float | np.floating):
        return ("float", float(v).hex())
    return (type(v).__name__, v)


def _fit_many(p, cfg, effect, values):
    """Each grid value of `effect` added to `cfg`: (held-out MSE, value) of the best one.

    The search asks for the same addition again (a pass of `_revisit` that keeps the others,
    `_prune` revisiting what stays): the answer is kept on `p` for the search's life.
    """
    key = ("fit_many", effect, _frozen(cfg), _frozen(list(values)))
    if key not in p.cache:
        p.cache[key] = _fit_grid(p, cfg, effect, values)
    return p.cache[key]


def _fit_grid(p, cfg, effect, values):
    e = EFFECT[effect]
    H = None if e.play_side else _model.play_columns(p, cfg)
    Hs = None
    if e.play_side:
        g, r = _model.play_inputs(p, cfg)
        Hs = e.batch_play_columns(p, g, r, values)

    def sse(q, i):
        c = {**cfg, effect: q}
        f = _model.fit(p, c, X=_model.linear_part(p, c, Hs[i] if Hs is not None and i is not None else H))
        return float(np.sum((f.A @ f.w - f.target) ** 2)), f

    def cv(b):
        return _model.cv_mse(p, b[1].A, {**cfg, effect: b[2]}, b[1].target)[0]

    # The pattern search below steps back onto values it has fitted (a move and its reverse).
    nearby: dict = {}

    def near(q):
        k = _frozen(q)
        if k not in nearby:
            nearby[k] = (*sse(q, None), q)
        return nearby[k]

    # The grid is searched by the fitting error, and the few best values are scored on held-out
    # blocks: a value that fits better by bending where the data are sparse (a start-up
    # transient, one extreme excursion) does not predict the blocks it did not see.
    coarse = sorted(((*sse(q, i), q) for i, q in enumerate(values)), key=lambda b: b[0])[:3]
    best_cv, best = min(((cv(b), b) for b in coarse), key=lambda c: c[0])
    start = best
    for level in range(4):
        # A local refinement below the grid's spacing (a pattern search, moving while it gains):
        # the chosen model should fit as well as the effect's form allows, or the gap left
        # would be taken for a second effect.
        for _ in range(4):
            new = min([best, *(near(q) for q in e.neighbours(best[2], level))], key=lambda b: b[0])
            if new[2] is best[2]:
                break
            best = new
    if best is not start:
        refined = cv(best)
        if refined < best_cv:
            return refined, best[2]
    return best_cv, start[2]


def _cv(p, cfg):
    f = _model.fit(p, cfg)
    return _model.cv_mse(p, f.A, cfg, f.target)[0]


def _noise(p, cfg, floor, step):
    """The noise variance and effective sample size that judge a round, from the current residual.

    The residual of the current model holds the noise and what the model still misses, which
    follows the input and is no faster than its cycles. Its noise floor is measured by the local
    cubic on every `step`-th sample, spanning up to half the input's cycle (`half_cycle`):
    coloured noise, mostly slower than the cubic's 7 samples, is seen there and not at the full
    rate. `floor` (the whole record's 7-sample floor) is a lower bound, so white noise reads
    about as before. The effective sample size counts the residual's correlation over the same span.
    """
    f = _model.fit(p, cfg)
    r = p.y - _model.predict(p, cfg, f.w, f.w_v, f.norm)
    sigma = max(floor, noise_std(r, step))
    return max(sigma**2, 1e-12), effective_samples(r, SMOOTHER * step)


def _noise_step(p):
    """The spacing of the samples `_noise` runs its local cubic on (see there)."""
    return max(1, min(half_cycle(p.u) // SMOOTHER, len(p.y) // (8 * SMOOTHER)))


def _round_noise(p, cfg, top_cfg, floor, step):
    """The noise variance and effective sample size that judge a round (`_noise` of each).

    What the current model `cfg` misses leaks into its residual: it raises the noise floor and,
    being slow, lowers the effective sample size. The best candidate's residual (`top_cfg`)
    holds less of it when the candidate is right and as much noise either way, so the smaller
    floor and the larger sample size judge the round, each from whichever residual is the
    cleaner in that respect: a slow misfit left in one residual must not set the charge per
    parameter for every candidate.
    """
    now, then = _noise(p, cfg, floor, step), _noise(p, top_cfg, floor, step)
    return min(now[0], then[0]), max(now[1], then[1])


def _significant(gain, n_params, cur_mse, sigma2, n):
    score = (gain - PARAM_PENALTY * sigma2 * n_params / n) / sigma2
    return score, bool(score > MIN_GAIN_NOISE and gain > MIN_GAIN_REL * cur_mse)


def _stuck(cur, sigma2, n):
    """Whether a model still misses more than the naming rule lets pass: a model at the noise
    floor would gain significantly on its held-out MSE `cur` (when no single addition does,
    `_pair_restart` tries pairs)."""
    return _significant(cur - sigma2, 0, cur, sigma2, n)[1]


def _prefer_input_driven(scores, best, cur, sigma2, n):
    """A time drift that wins a round gives way to an input-driven effect that explains as much.

    Creep and a drift over time can fit the same slow residual on one record, but only creep,
    a function of the input, carries over to another run. The drift keeps its place only when
    its held-out gain over the best significant input-driven candidate is itself significant:
    the held-out blocks then include stretches where the output moves while the input does not
    (a pause, a steady periodic drive), which no function of the input explains.
    """
    if not EFFECT[best].time_driven:
        return best
    alts = [c for c, v in scores.items() if not EFFECT[c].record_specific and v["significant"]]
    if not alts:
        return best
    alt = max(alts, key=lambda c: scores[c]["score"])
    if _significant(scores[alt]["mse"] - scores[best]["mse"], 0, cur, sigma2, n)[1]:
        return best
    return alt


def _revisit(p, cfg, named, candidates, cur, sigma2, n):
    """Re-choose each named effect given the others (one backfitting pass).

    An effect named while a second one was still unmodelled may have been the best stand-in for
    the pair (a lag for a delay seen through a saturation); with the second in place, the first
    is chosen again among all candidates, its own form and parameters included, and then the
    second given the new first. A swap keeps the rounds' preference (`_prefer_input_driven`):
    a drift over time replaces an input-driven effect only when it is significantly better
    (`sigma2`, `n`: the noise variance and effective sample size that judge it).
    """
    for sweep in range(4):
        before = cur
        for e in list(named):
            rest = {k: v for k, v in cfg.items() if k != e}
            best = (cur, e, cfg[e])
            # The first sweep may swap effects; later ones re-fit each effect's own parameters
            # given the others (coordinate descent: a delay and an envelope trade off).
            for c in candidates if sweep == 0 else [e]:
                if c in rest:
                    continue
                mse, q = _fit_many(p, rest, c, EFFECT[c].grid(p))
                if mse >= best[0]:
                    continue
                if EFFECT[c].time_driven and not EFFECT[best[1]].record_specific:
                    if not _significant(best[0] - mse, 0, best[0], sigma2, n)[1]:
                        continue
                best = (mse, c, q)
            named = [best[1] if x == e else x for x in named]
            cfg, cur = {**rest, best[1]: best[2]}, best[0]
        if sweep > 0 and cur > 0.99 * before:
            break
    return cfg, named, cur


def _pair_restart(p, first, cur, sigma2, n):
    """Pairs of the first round's three best candidates, each fitted from the plain model.

    One effect chosen first can absorb two (a resonant lag standing in for a delay seen
    through an output nonlinearity; a saturation whose off-centre envelope stands in for an
    asymmetry) and leave a residual that a model at the noise floor would improve on by the
    naming rule's margin, which no single addition does: the second effect only helps once the
    first is fitted again beside it. The pair that explains the record best replaces it if it is
    better by a significant margin; otherwise None.
    """
    top = sorted(first, key=lambda k: -first[k]["score"])[:3]
    best = None
    for a, b in itertools.combinations(top, 2):
        cfg = {a: first[a]["value"]}
        mse, q = _fit_many(p, cfg, b, EFFECT[b].grid(p))
        cfg, named, mse = _revisit(p, {**cfg, b: q}, [a, b], [a, b], mse, sigma2, n)
        if best is None or mse < best[2]:
            best = (cfg, named, mse)
    gain_ok = best is not None and _significant(cur - best[2], 0, cur, sigma2, n)[1]
    return best if gain_ok else None


def _prune(p, cfg, named, sigma2, n):
    """Drop a named effect that the others make redundant (backward elimination).

    A lag can stand in for a delay, slow creep for a drift or for dynamics: when the model
    without an effect is as good on held-out blocks, that effect is dropped. The others' own
    parameters are chosen again without it first (`_revisit` over them alone): an effect named
    early, beside which a later one settled on a compromise (a first-order lag next to creep
    where the record's dynamics are of second order), is redundant only once the later one
    takes its own best form.
    """
    pruned = []
    while len(named) > 1:
        cur = _cv(p, cfg)
        for e in named:
            others = [x for x in named if x != e]
            rest = {k: v for k, v in cfg.items() if k != e}
            rest, others, mse = _revisit(p, rest, others, others, _cv(p, rest), sigma2, n)
            if not _significant(mse - cur, EFFECT[e].charge(cfg[e]), cur, sigma2, n)[1]:
                cfg, named = rest, others
                pruned.append(e)
                break
        else:
            break
    return cfg, named, pruned


@on_one_blas_thread
def search(
    rec: Record,
    *,
    max_effects: int = MAX_EFFECTS,
    candidates=EFFECTS,
    refit: bool = True,
    solver: str | None = "lm",
    uncertainty: bool = True,
    quiet: bool = True,
):
    """Run the naming loop on one identification record.

    **Arguments:**

    - `rec`: the record (checked with `check_record`).
    - `max_effects`: stop after naming this many.
    - `candidates`: the effects to consider.
    - `refit`: fit the final weights on the full-rate record (otherwise on the search's samples).
    - `solver`: refine the base and the final model jointly with this optimistix solver
      (`_refine.refine`: `"lm"`, `"gn"` or `"bfgs"`), or None to keep the variable-projection fit.
    - `uncertainty`: compute the named effects' standard errors (False: `uncertainty` is None,
      for studies that read only the names and errors; it compiles the model's Jacobian).
    - `quiet`: no progress bar (it shows only on a terminal anyway).

    **Returns:** a dict with `effects` (named, in order), `pruned`, `rounds` (each candidate's
    held-out RMSE and score per round; the first round's `untried` names the candidates the
    record cannot show, with why), `model_base` and `model_final` (configuration,
    weights and, with a `solver`, how the refinement went and which fit was kept), `scaling`,
    `loop` (the record's `loop_direction`, which decides whether the plays' weights are signed),
    `noise_std` and the held-out RMSEs (in the data's units).
    """
    candidates = list(candidates)
    check_names(candidates)
    if solver is not None:
        check_solver(solver)
    check_record(rec)
    loop = loop_direction(rec.u, rec.y)
    sc = scaling_of(rec, loop)
    step = int(math.ceil(rec.n_samples / SEARCH_SAMPLES))
    p = prepared(rec, sc, step=step, folds=True)
    untried = {c: why for c in candidates if (why := EFFECT[c].unidentifiable(p)) is not None}
    candidates = [c for c in candidates if c not in untried]
    floor = noise_std(rec.y) / sc.y_half
    step_noise = _noise_step(p)
    cfg: dict[str, object] = {}
    named: list[str] = []
    rounds: list[dict[str, object]] = []
    first, restarted = {}, False
    base_mse = cur = _cv(p, cfg)
    while len(named) < max_effects:
        todo = [c for c in candidates if c not in named]
        fits = {
            c: _fit_many(p, cfg, c, EFFECT[c].grid(p))
            for c in progress(todo, desc=f"diagnose, round {len(rounds) + 1}", quiet=quiet)
        }
        if not fits:
            break
        top = min(fits, key=lambda c: fits[c][0])
        sigma2, n = _round_noise(p, cfg, {**cfg, top: fits[top][1]}, floor, step_noise)
        scores = {}
        for c, (mse, q) in fits.items():
            score, ok = _significant(cur - mse, EFFECT[c].charge(q), cur, sigma2, n)
            scores[c] = dict(
                heldout_rmse=float(np.sqrt(mse)) * sc.y_half, score=float(score), significant=ok, value=q, mse=mse
            )
        best = _prefer_input_driven(scores, max(scores, key=lambda k: scores[k]["score"]), cur, sigma2, n)
        ok = scores[best]["significant"]
        rounds.append(
            dict(
                current_heldout_rmse=float(np.sqrt(cur)) * sc.y_half,
                noise_std=float(np.sqrt(sigma2)) * sc.y_half,
                effective_samples=n,
                candidates={
                    k: {kk: v[kk] for kk in ("heldout_rmse", "score", "significant")} for k, v in scores.items()
                },
                best=best,
                named=ok,
                parameters=EFFECT[best].describe(scores[best]["value"]),
            )
        )
        if len(rounds) == 1:
            first = scores
            if untried:
                rounds[0]["untried"] = untried
        if not ok:
            if len(named) == 1 and _stuck(cur, sigma2, n) and max_effects > 1 and not restarted:
                restarted = True
                alt = _pair_restart(p, first, cur, sigma2, n)
                if alt is not None:
                    cfg, named, cur = alt
                    rounds[-1]["pair_restart"] = list(named)
                    continue
            break
        named.append(best)
        cfg = {**cfg, best: scores[best]["value"]}
        cur = scores[best]["mse"]
        if len(named) > 1:
            cfg, named, cur = _revisit(p, cfg, named, candidates, cur, sigma2, n)
            rounds[-1]["effects_after_revisit"] = list(named)
    sigma2, n = _noise(p, cfg, floor, step_noise)
    cfg, named, pruned = _prune(p, cfg, named, sigma2, n)
    cfg = {k: cfg[k] for k in named}
    final_mse = _cv(p, cfg)
    full = prepared(rec, sc) if refit else p
    # The joint refinement costs a Jacobian per step; on long records it runs on every k-th
    # sample (the parameters are physical, so the model carries over to the full rate) and is
    # kept only if it also lowers the error at the full rate.
    thin = prepared(rec, sc, step=int(math.ceil(len(full.y) / REFINE_SAMPLES))) if refit else p
    models = {}
    for label, c in (("model_base", {}), ("model_final", cfg)):
        f = _model.fit(full, c)
        # Both models get the same joint refinement, so the comparison stays fair.
        models[label] = (
            dict(cfg=c, coef=f.w, coef_v=f.w_v, norm=f.norm) if solver is None else _refined(full, thin, c, f, solver)
        )
    # The named effects' standard errors, on the samples the refinement ran on.
    errors = _uncertainty.parameter_uncertainty(thin, models["model_final"], sc) if cfg and uncertainty else None
    return dict(
        effects=named,
        pruned=pruned,
        rounds=rounds,
        scaling=sc,
        noise_std=float(np.sqrt(sigma2)) * sc.y_half,
        step=step,
        heldout_rmse_base=float(np.sqrt(base_mse)) * sc.y_half,
        heldout_rmse_final=float(np.sqrt(final_mse)) * sc.y_half,
        uncertainty=errors,
        loop=loop,
        **models,
    )


def _refined(full, thin, cfg, f, solver):
    """The best of the grid fit, its joint refinement, and the refined parameters' exact weights.

    The solver moves every parameter at once but, through the positivity transform, slowly
    moves weights that sit at zero; the variable-projection fit at the refinement's nonlinear
    parameters gives those weights exactly. All three are judged at the full rate.
    """

    def mse(pred):
        return float(np.mean((pred - full.y) ** 2))

    def vp_model(c, g):
        return dict(cfg=c, coef=g.w, coef_v=g.w_v, norm=g.norm)

    ref = _refine.refine(thin, cfg, f.w, f.norm, solver=solver)
    options = [("grid", mse(_model.predict(full, cfg, f.w, f.w_v, f.norm)), vp_model(cfg, f))]
    if ref.accepted:
        refined = dict(vp_model(cfg, f), cfg=ref.cfg, refined=ref)
        options.append(("solver", mse(_refine.predict(ref, full, f.norm)), refined))
        if ref.cfg != cfg:
            g = _model.fit(full, ref.cfg)
            pred = _model.predict(full, ref.cfg, g.w, g.w_v, g.norm)
            options.append(("solver_then_weights", mse(pred), vp_model(ref.cfg, g)))
    kept, best, model = min(options, key=lambda o: o[1] if np.isfinite(o[1]) else np.inf)
    model["refinement"] = dict(
        result=ref.result,
        steps=ref.steps,
        kept=kept,
        rmse_start=float(np.sqrt(options[0][1])),
        rmse=float(np.sqrt(best)),
    )
    return model


def _refinement(model, sc):
    """How the joint optimistix refinement of a model went (RMSEs in the data's units)."""
    r = model["refinement"]
    return dict(r, rmse_start=r["rmse_start"] * sc.y_half, rmse=r["rmse"] * sc.y_half)


def evaluate(rec: Record, sc: Scaling, model, *, transferable_only=False, history=None):
    """Run a fitted model on a record at full rate; returns (prediction in data units, RMSE).

    **Arguments:**

    - `rec`: the record; `sc`: the identification record's `Scaling`.
    - `model`: `search(...)["model_base"]` or `["model_final"]`.
    - `transferable_only`: for another record, switch off what is tied to the identification
      record itself (its plays' initial states and its drift over time).
    - `history`: turning points (normalised input) of an input history that sets the plays'
      initial states on this record; implies `transferable_only` for the drift.

    **Returns:** `(prediction, rmse)`.
    """
    pred = _predict(prepared(rec, sc), model, transferable_only, history) * sc.y_half + sc.y_mid
    return pred, float(np.sqrt(np.mean((pred - rec.y) ** 2)))


def _predict(p, model, transferable_only, history):
    """A model's output on a prepared record, normalised units (see `evaluate`)."""
    if model.get("refined") is not None:
        return _refine.predict(model["refined"], p, model["norm"], transferable_only=transferable_only, history=history)
    cfg, w, w_v = dict(model["cfg"]), np.asarray(model["coef"]), np.asarray(model["coef_v"])
    if transferable_only or history is not None:
        cfg, w, w_v = _model.without(cfg, [n for n in cfg if EFFECT[n].record_specific], w, w_v)
    if history is not None:
        cfg["initial_state"] = tuple(history)
    return _model.predict(p, cfg, w, w_v, model["norm"])


def _transients(model, p):
    """What the transferable effects' own states before a record add: {effect: (T, k) columns}."""
    cfg = model["refined"].cfg if model.get("refined") is not None else model["cfg"]
    out = {}
    for e in chain(cfg):
        cols = None if e.record_specific else e.transients(cfg[e.name], p)
        if cols is not None:
            out[e.name] = cols
    return out


def _states(transients, coef):
    """The estimated states of each effect with transients, `<effect>_states` (empty when absent)."""
    out: dict[str, list[float]] = {
        f"{e.name}_states": [] for e in EFFECT.values() if type(e).transients is not AbstractEffect.transients
    }
    k = 0
    for name, cols in transients.items():
        out[f"{name}_states"] = [float(c) for c in coef[k : k + cols.shape[1]]]
        k += cols.shape[1]
    return out


def evaluate_ic(rec: Record, sc: Scaling, model):
    """A model's prediction of another record with its initial conditions estimated on that record.

    As system identification tools compare a model with data (MATLAB's `compare`): the model
    is fixed, and only what no model of the input can know is estimated on the record: the
    output offset (a sensor zero that moved between runs), the plays' initial states and the
    states of the effects with their own memory (creep's lags). The plays' states are those an
    input history leaves (the `initial_state` effect's grid of histories, so they stay
    reachable); a state of an effect's own adds a known transient (a creep lag starting away
    from rest adds a decaying exponential lam_k^t), so those states and the offset enter
    linearly and are fitted by least squares for each history. Drift over time is not used.

    **Arguments:** as `evaluate`.

    **Returns:** `(prediction, rmse, estimated)` with `estimated` a dict: `offset`, the history's
    turning points in the record's input units (empty for relaxed plays) and `<effect>_states`
    for every effect with transients (`creep_states`).
    """
    p = prepared(rec, sc)
    transients = _transients(model, p)
    C = np.column_stack([np.ones(len(rec.y)), *transients.values()])
    best = None
    for history in [None, *EFFECT["initial_state"].grid(p)]:
        pred = _predict(p, model, True, history) * sc.y_half + sc.y_mid
        coef = np.linalg.lstsq(C, rec.y - pred, rcond=None)[0]
        full = pred + C @ coef
        rmse = float(np.sqrt(np.mean((full - rec.y) ** 2)))
        if best is None or rmse < best[1]:
            turns = [] if history is None else [float(a) * sc.u_half + sc.u_mid for a in history]
            best = (
                full,
                rmse,
                dict(offset=float(coef[0]), history_turning_points=turns, **_states(transients, coef[1:])),
            )
    return best


@on_one_blas_thread
def diagnose(rec: Record, validation: Record | None = None, **kwargs) -> Diagnosis:
    """The whole workflow on one record: locate, name, and show the gap shrink.

    **Arguments:**

    - `rec`: the identification record.
    - `validation`: an optional second record of the same device, run through both models.
    - `**kwargs`: passed to `search` (`max_effects`, `candidates`, `solver`, `quiet`, ...).

    **Returns:** a [`Diagnosis`][piest_jax.Diagnosis]: the effects named, in order (split into
    transferable and record-specific ones), the RMSE of the plain PI model and of the model with
    the named effects on the whole record and on held-out blocks, the named effects' parameters
    after refinement, how the refinement went, the search's rounds, where the plain model's
    residual is structured, both models' predictions and, with a validation record, a
    [`DiagnosisValidation`][piest_jax.DiagnosisValidation]: the raw RMSEs (each model from rest,
    transferable effects only), those with the offset and initial states estimated on the
    validation record (`evaluate_ic`), the fit percentages and the estimated initial conditions.
    Its `to_json()`, which its mapping view reads, is `piest diagnose`'s report.json.
    """
    s = search(rec, **kwargs)
    sc, named = s["scaling"], s["effects"]
    pred_b, rmse_b = evaluate(rec, sc, s["model_base"])
    pred_f, rmse_f = evaluate(rec, sc, s["model_final"])
    checked = None
    if validation is not None:
        check_record(validation, validation=True)
        checked = _validate(validation, sc, s, named, (float(np.min(rec.u)), float(np.max(rec.u))))
    return Diagnosis(
        record=rec,
        effects=named,
        baseline_rmse=rmse_b,
        final_rmse=rmse_f,
        noise_std_estimate=s["noise_std"],
        parameters={e: EFFECT[e].describe(s["model_final"]["cfg"][e]) for e in named},
        refinement={k: _refinement(s[k], sc) for k in ("model_base", "model_final") if "refinement" in s[k]},
        uncertainty=s["uncertainty"],
        rounds=s["rounds"],
        pruned=s["pruned"],
        heldout_baseline_rmse=s["heldout_rmse_base"],
        heldout_final_rmse=s["heldout_rmse_final"],
        search_step=s["step"],
        where=_locate.locate(rec.t, rec.u, rec.y, pred_b, s["noise_std"]),
        baseline_prediction=pred_b,
        final_prediction=pred_f,
        validation=checked,
        loop=s["loop"],
    )


def _validate(validation: Record, sc: Scaling, s, named, identified_range) -> DiagnosisValidation:
    """Both models of a search on a second record, raw and with its initial conditions estimated
    (`identified_range`: the identification record's input range)."""
    vb, rb = evaluate(validation, sc, s["model_base"], transferable_only=True)
    vf, rf = evaluate(validation, sc, s["model_final"], transferable_only=True)
    vbi, rbi, est_b = evaluate_ic(validation, sc, s["model_base"])
    vfi, rfi, est_f = evaluate_ic(validation, sc, s["model_final"])
    outside, inside = extrapolation(
        validation.u,
        identified_range,
        validation.y,
        baseline_rmse=vb,
        final_rmse=vf,
        baseline_rmse_ic=vbi,
        final_rmse_ic=vfi,
    )
    return DiagnosisValidation(
        record=validation,
        baseline_rmse=rb,
        final_rmse=rf,
        # With the validation record's own initial conditions (offset, play and creep
        # states) estimated on it, everything else fixed: what the model predicts of a run
        # already in motion, as system identification tools report it.
        baseline_rmse_ic=rbi,
        final_rmse_ic=rfi,
        baseline_fit_percent=float(fit_percent(validation.y, vb)),
        final_fit_percent=float(fit_percent(validation.y, vf)),
        baseline_fit_percent_ic=float(fit_percent(validation.y, vbi)),
        final_fit_percent_ic=float(fit_percent(validation.y, vfi)),
        initial_conditions=dict(baseline=est_b, final=est_f),
        noise_std_estimate=noise_std(validation.y),
        # The same with each model's mean residual removed: a sensor zero that moved
        # between the two runs is no failure of either model.
        baseline_rmse_offset_removed=float(np.std(validation.y - vb)),
        final_rmse_offset_removed=float(np.std(validation.y - vf)),
        effects_used=[e for e in named if not EFFECT[e].record_specific],
        outside_input_range=outside,
        inside_input_range=inside,
        baseline_prediction=vb,
        final_prediction=vf,
    )
