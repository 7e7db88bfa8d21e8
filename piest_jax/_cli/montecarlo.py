"""`piest montecarlo`: the Monte Carlo map of persistent excitation against Assumption 1."""

import jax

from .._excitation.families import DEFAULT_FAMILIES, FAMILIES
from .._excitation.map_figure import pe_map_figure
from .._excitation.map_settings import make_settings
from .._excitation.montecarlo import pe_map
from . import memory
from . import output as _io
from ._common import CLIError, add_output_options, positive_float, positive_int, seed

NAME = "montecarlo"
DESCRIPTION = (
    """\
Draw N random cases (input family and parameters, thresholds, initial states, weights), one PRNG
key each, and for every draw compute the Assumption 1 ratio rho (smallest window range of u over
2 r_max), the PE level c1 (absolute, and normalised as lambda_min / lambda_max of the worst
window), which plays move in each window, the exact condition and the lower bound on c1 from
the input's swings (see docs/excitation_condition.md), the earlier sharper condition, the RLS
weight error after the whole record, when it falls below 1 % for good, and when the lower bound
guarantees that it has. The families take turns: """
    + ", ".join(DEFAULT_FAMILIES)
    + """ by default;
"""
    + ", ".join(FAMILIES[len(DEFAULT_FAMILIES) :])
    + """ (long monotone stretches, reversals
exactly 2 r_j apart with holds, loops just below 2 r_max) are adversarial cases asked for by name.
Writes
  DIR/pe_map.png   c1 against rho by family (rho = 1 marked), the PE fraction against rho,
                   the weight error against c1, c1 against its margin, and the time to 1 %
                   weight error against the time its margin guarantees
  DIR/pe_map.json  the counts (theorem_violations, pe_fraction_below_assumption, the exact
                   condition's, the margin's and the convergence guarantee's violations), the
                   tolerance, what --settle decided exactly, seconds, settings and every draw
The batch is sharded over all JAX devices and run in chunks of --chunk draws.

example:  piest montecarlo --inputs 2000 --samples 5000 --seed 0 --out pe-map"""
)

OUTPUTS = ("pe_map.png", "pe_map.json")


def add_arguments(p):
    p.add_argument("--inputs", type=positive_int, default=700, help="number of draws (default 700)")
    p.add_argument("--samples", type=positive_int, default=5000, help="samples per input T (default 5000)")
    p.add_argument("--seed", type=seed, default=0, help="PRNG seed (default 0)")
    p.add_argument("--plays", type=positive_int, default=10, help="plays per draw (default 10)")
    p.add_argument("--window", type=positive_int, help="PE window T0 in samples (default samples // 5)")
    p.add_argument("--stride", type=positive_int, help="samples between window starts (default window // 10)")
    p.add_argument("--dt", type=positive_float, default=2e-3, help="sampling step (default 2e-3)")
    p.add_argument("--p0", type=positive_float, default=1e6, help="RLS initial gain P0 (default 1e6)")
    p.add_argument(
        "--families",
        default=",".join(DEFAULT_FAMILIES),
        help="comma-separated input families (default: the seven non-adversarial ones; also "
        + ", ".join(FAMILIES[len(DEFAULT_FAMILIES) :])
        + ")",
    )
    p.add_argument(
        "--float32",
        action="store_true",
        help="compute in float32 (faster, but its tolerance 1.2e-3 on lambda_min / lambda_max is "
        "above the PE level of most draws, which is 1e-10 to 1e-5 with 10 plays)",
    )
    p.add_argument("--chunk", type=positive_int, default=1000, help="draws per compiled call (default 1000)")
    p.add_argument(
        "--settle",
        action="store_true",
        help="decide in exact arithmetic every draw whose verdict floating point cannot: event "
        "level below the rounding band, or the raw Gram and the exact condition disagreeing "
        "(most draws that are not PE; about 25 ms each at 2000 samples, on the host)",
    )
    p.add_argument(
        "--play-method",
        default="auto",
        choices=("auto", "scan", "associative", "kernel"),
        help="how the plays are computed: auto (default) takes the compiled kernel on a CPU and "
        "the associative scan on a GPU; scan, associative and kernel ask for one; all give the "
        "same outputs",
    )
    add_output_options(p, "piest-montecarlo")


def run(args) -> int:
    if args.samples < 2:
        raise CLIError(f"--samples must be at least 2, got {args.samples}")
    if args.window is not None and args.window > args.samples:
        raise CLIError(f"--window ({args.window} samples) is longer than the signal ({args.samples} samples)")
    families = [f for f in args.families.replace(" ", "").split(",") if f]
    unknown = [f for f in families if f not in FAMILIES]
    if unknown or not families:
        raise CLIError(f"unknown --families {unknown or families}; choose from {list(FAMILIES)}")
    memory.require(
        memory.map_bytes(args.samples, args.plays, len(families)),
        f"--samples {args.samples} with --plays {args.plays}",
        "use fewer samples or plays",
    )
    out = _io.check_outputs(args.out, OUTPUTS, args.force)
    settings = make_settings(
        n_samples=args.samples,
        n_plays=args.plays,
        window=args.window,
        stride=args.stride,
        dt=args.dt,
        P0=args.p0,
        families=families,
        dtype="float32" if args.float32 else "float64",
        play_method=args.play_method,
    )
    res = pe_map(
        jax.random.key(args.seed),
        args.inputs,
        settings,
        chunk=args.chunk,
        settle=args.settle,
        quiet=args.quiet,
    )
    report = {"seed": args.seed} | res.to_json()
    written = [_io.save_figure(pe_map_figure(res), out / "pe_map.png", dpi=110)]
    written.append(_io.write_json(out / "pe_map.json", report))
    for path in written:
        print(path)
    return 0
