"""`piest montecarlo`: the Monte Carlo map of persistent excitation against Assumption 1."""

import argparse
import contextlib
import os

import jax
import numpy as np
from jax.experimental import multihost_utils

from .._excitation.families import DEFAULT_FAMILIES, FAMILIES
from .._excitation.map_figure import pe_map_figure
from .._excitation.map_settings import make_settings
from .._excitation.montecarlo import pe_map
from . import memory
from . import output as _io
from ._common import MAX_COUNT, CLIError, _whole, add_output_options, positive_float, positive_int, seed

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
The batch is sharded over all JAX devices and run in chunks of --chunk draws. Several processes
(hosts) share one map when each is started with --coordinator, --num-processes and its own
--process-id, or with --distributed under SLURM or Open MPI: the batch is then sharded over every
process's devices, the draws are the same as in one process, and process 0 alone writes the
results; the others write nothing (their --out is not touched) and exit 0.

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
    p.add_argument(
        "--coordinator",
        type=coordinator,
        metavar="HOST:PORT",
        help="run as one of several processes (hosts): the address of process 0, where it serves "
        "the others (the same on every process); with --num-processes and --process-id",
    )
    p.add_argument("--num-processes", type=positive_int, metavar="N", help="how many processes share the map")
    p.add_argument(
        "--process-id",
        type=process_id,
        metavar="I",
        help="this process's number, 0 to N - 1; process 0 alone writes the results, the others leave --out untouched",
    )
    p.add_argument(
        "--distributed",
        action="store_true",
        help="run as one of several processes whose coordinator, number and ids JAX reads from "
        "the cluster's environment (SLURM, Open MPI): e.g. srun -n 4 piest montecarlo ... "
        "--distributed",
    )
    add_output_options(p, "piest-montecarlo")


def coordinator(text: str) -> str:
    host, colon, port = text.rpartition(":")
    if not (colon and host and port.isascii() and port.isdigit() and 0 < int(port) < 65536):
        raise argparse.ArgumentTypeError(f"expected HOST:PORT such as 10.0.0.1:1234, got {text!r}")
    return text


def process_id(text: str) -> int:
    v = _whole(text)
    if not 0 <= v <= MAX_COUNT:
        raise argparse.ArgumentTypeError(f"a process number is from 0 to {MAX_COUNT}, got {v}")
    return v


def _distributed(args) -> dict | None:
    """The arguments of `jax.distributed.initialize` that the options ask for (None: one process)."""
    given = {"--coordinator": args.coordinator, "--num-processes": args.num_processes, "--process-id": args.process_id}
    named = [k for k, v in given.items() if v is not None]
    if args.distributed:
        if named:
            raise CLIError(
                f"--distributed takes the processes from the cluster's environment; give it or "
                f"--coordinator, --num-processes and --process-id, not {named[0]} too"
            )
        return {}
    if not named:
        return None
    if len(named) < len(given):
        missing = " and ".join(k for k in given if k not in named)
        raise CLIError(
            f"--coordinator, --num-processes and --process-id go together: {', '.join(named)} given without {missing}"
        )
    if args.process_id >= args.num_processes:
        raise CLIError(
            f"--process-id {args.process_id} is not below --num-processes {args.num_processes} "
            "(the processes are numbered 0 to N - 1)"
        )
    return dict(coordinator_address=args.coordinator, num_processes=args.num_processes, process_id=args.process_id)


def _join(kwargs: dict) -> None:
    """Join the other processes: before anything else in JAX computes or lists devices."""
    # The results are gathered across processes; on CPUs that takes cross-process collectives,
    # which need an implementation chosen before the backend starts. gloo is JAX's default;
    # one the user chose (mpi) stays.
    if jax.config.jax_cpu_collectives_implementation is None:  # type: ignore[attr-defined]
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    try:
        jax.distributed.initialize(**kwargs)
    except ValueError as e:
        if kwargs:
            raise CLIError(f"cannot join the processes through {kwargs['coordinator_address']}: {e}") from None
        raise CLIError(
            f"--distributed: JAX read no processes from the environment ({str(e).rstrip('.')}): it "
            "knows SLURM, Open MPI, Kubernetes and Cloud TPU; elsewhere give --coordinator, "
            "--num-processes and --process-id"
        ) from None
    except RuntimeError as e:
        where = f" through {kwargs['coordinator_address']}" if kwargs else ""
        raise CLIError(f"cannot join the processes{where}: {e}") from None


@contextlib.contextmanager
def _native_stdout_to_stderr():
    """Send what native code writes to standard output (file descriptor 1) to stderr instead.

    The cross-process collectives announce their connections there ("[Gloo] Rank 0 is
    connected ..."), and a command's stdout holds only the paths it wrote.
    """
    try:
        saved = os.dup(1)
        os.dup2(2, 1)
    except OSError:  # no such descriptors (an embedding program closed them): nothing to move
        yield
        return
    try:
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _check_outputs(args):
    """Process 0's output folder, checked before the computation (None on the other processes).

    In a distributed run every process learns whether process 0 refused its --out, so that all
    stop together instead of computing without it, or waiting for it.
    """
    refusal, out = None, None
    if jax.process_index() == 0:
        try:
            out = _io.check_outputs(args.out, OUTPUTS, args.force)
        except (CLIError, OSError, ValueError) as e:
            refusal = e
    if jax.process_count() > 1:
        refused = multihost_utils.broadcast_one_to_all(np.int32(refusal is not None))
        if refusal is None and refused:
            raise CLIError("process 0 cannot write its --out (its own message says why); nothing was computed")
    if refusal is not None:
        raise refusal
    return out


def run(args) -> int:
    processes = _distributed(args)
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
    if processes is None:
        out = _io.check_outputs(args.out, OUTPUTS, args.force)
        res = _map(args, families, quiet=args.quiet)
    else:
        with _native_stdout_to_stderr():
            _join(processes)
            out = _check_outputs(args)
            # One progress bar, not one per process on the same terminal.
            res = _map(args, families, quiet=args.quiet or out is None)
        if out is None:  # a process other than 0 of a distributed run: its part is done
            return 0
    report = {"seed": args.seed} | res.to_json()
    written = [_io.save_figure(pe_map_figure(res), out / "pe_map.png", dpi=110)]
    written.append(_io.write_json(out / "pe_map.json", report))
    for path in written:
        print(path)
    return 0


def _map(args, families: list, quiet: bool):
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
    return pe_map(jax.random.key(args.seed), args.inputs, settings, chunk=args.chunk, settle=args.settle, quiet=quiet)
