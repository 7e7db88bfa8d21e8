"""The optimistix solvers the fits accept: by name, or as a solver object the user configured.

A name picks a solver with the fit's own tolerances: `"lm"` (Levenberg-Marquardt, the default:
damped, robust from poor starts), `"gn"` (Gauss-Newton: fastest near a solution, no damping) or
`"bfgs"` (a quasi-Newton minimiser of the squared residuals). Any optimistix least-squares solver
or minimiser may be passed instead (for example `optx.Dogleg(rtol, atol)` or an
`optx.LevenbergMarquardt` with a custom linear solver); it is used as given, with its own
tolerances.
"""

import optimistix as optx

SOLVERS = ("lm", "gn", "bfgs")
# The optimistix result codes by name, looked up through the public attributes of `optx.RESULTS`.
_RESULT_NAMES = (
    "successful",
    "max_steps_reached",
    "nonlinear_max_steps_reached",
    "nonlinear_divergence",
    "singular",
    "breakdown",
    "stagnation",
    "conlim",
    "nonfinite_input",
    "nonfinite",
)


def is_solver(spec) -> bool:
    """Whether `spec` is an optimistix solver object a least-squares fit can use."""
    return isinstance(spec, optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser)


def check_solver(spec) -> None:
    """Refuse what is neither a solver name nor a solver object, naming the choices.

    **Arguments:** `spec`, a name from `SOLVERS` or an optimistix solver object.

    **Returns:** nothing; raises `ValueError`.
    """
    if is_solver(spec):
        return
    if isinstance(spec, type) and issubclass(spec, optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser):
        raise ValueError(
            f"`solver` is the class {spec.__name__}, not a solver: pass an instance, "
            f"e.g. {spec.__name__}(rtol=1e-6, atol=1e-9)"
        )
    if not isinstance(spec, str) or spec not in SOLVERS:
        raise ValueError(
            f"unknown solver {spec!r}; choose one of {SOLVERS} or pass an optimistix least-squares solver or minimiser"
        )


def least_squares_solver(spec, rtol: float, atol: float):
    """The solver object for `spec`: a name with these tolerances, or the object itself.

    **Arguments:** `spec`, a name from `SOLVERS` or an optimistix solver object; `rtol`, `atol`,
    the tolerances a named solver gets.

    **Returns:** an optimistix least-squares solver or minimiser.
    """
    check_solver(spec)
    if not isinstance(spec, str):
        return spec
    if spec == "lm":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    if spec == "gn":
        return optx.GaussNewton(rtol=rtol, atol=atol)
    return optx.BFGS(rtol=rtol, atol=atol)


def solver_label(spec) -> str:
    """A name for reports: the solver's name, or its class name for a solver object."""
    return spec if isinstance(spec, str) else type(spec).__name__


def result_name(result) -> str:
    """The name of a concrete optimistix result code (`"successful"`, `"max_steps_reached"`, ...).

    **Arguments:** `result`, an `optx.RESULTS` value (concrete, not traced).

    **Returns:** its name, or `"unknown"` for a code this list does not know.
    """
    for name in _RESULT_NAMES:
        item = getattr(optx.RESULTS, name, None)
        if item is not None and bool(result == item):
            return name
    return "unknown"
