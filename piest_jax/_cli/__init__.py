"""The `piest` command-line tool: `piest COMMAND --help` describes each command."""

import argparse
import contextlib
import importlib
import io
import os
import signal
import sys
import threading
from pathlib import Path

from . import interrupt as _interrupt
from . import output as _io
from ._common import CLIError, print_notes

# Each command's one-line help. Its module (`_cli/<name>.py`, with NAME, DESCRIPTION,
# add_arguments(parser) and run(args) -> int) is imported only when the command is chosen, so
# `piest --help` and argument errors answer without loading JAX.
HELP = {
    "simulate": "run a PI operator on a sine, multi-sine, triangle, chirp or a CSV's u",
    "diagnose": "name the effects a plain PI model misses and show the gap shrink",
    "reproduce": "reproduce the paper's Figs. 5 and 6 (RLS weight estimation) as figures and JSON",
    "montecarlo": "map PE levels against Assumption 1 over random inputs, thresholds and initial states",
    "fit": "fit thresholds, weights and offset of a PI model to a measured (t, u, y) record",
    "compensate": "compute the feedforward input that makes a fitted PI model follow a desired output",
    "estimate": "run an online weight estimator (the paper's RLS, RLS with forgetting, gradient) on a record",
    "excite": "design an input that excites given plays with the largest guaranteed PE margin",
}


def command_module(name: str):
    """The module of the command `name` (a key of `HELP`)."""
    return importlib.import_module(f".{name}", __name__)


def __getattr__(name: str):
    if name == "COMMANDS":  # every command's module, for tests and documentation
        return [command_module(n) for n in HELP]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line on stderr (exit code 2), not the usage block."""

    def error(self, message):
        if message.endswith("expected one argument"):
            message += "; a value starting with '-' is written --option=-1,2"
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _Terminated(Exception):
    """SIGTERM (kill) arrived: unwind so that temporary files are removed."""


def _on_sigterm(signum, frame):
    raise _Terminated


def _one_line(e: BaseException) -> str:
    text = str(e)
    # A check inside jitted code (eqx.error_if) arrives wrapped in a runtime error whose text holds
    # a traceback; the user's message is the line after the marker.
    marker = "EquinoxRuntimeError: "
    if marker in text:
        text = text.split(marker, 1)[1].split("\n", 1)[0]
    return " ".join(text.split()) or type(e).__name__


def _protect_inputs(args) -> None:
    """Refuse an --out that would put a result on top of one of the command's input files."""
    out = getattr(args, "out", None)
    if out is None:
        return
    values = [v for v in vars(args).values() if isinstance(v, (str, Path))]
    values += [x for v in vars(args).values() if isinstance(v, list) for x in v if isinstance(x, (str, Path))]
    inputs = [Path(v) for v in values if Path(v).is_file()]
    for name in getattr(args._module, "OUTPUTS", ()):
        target = Path(out) / name
        for src in inputs:
            if target.exists() and os.path.samefile(target, src):
                raise CLIError(f"--out {out} would overwrite the input file {src}; choose another --out")


def _version() -> str:
    from .. import __version__

    return f"piest {__version__}"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser: every command's options, or only `command`'s when one is named."""
    parser = _Parser(
        prog="piest",
        description=(
            "Prandtl-Ishlinskii hysteresis toolkit. Each command writes its figures and a JSON "
            "report into --out and prints the paths it wrote. Exit codes: 0 success, 2 bad "
            "input or arguments (one-line message), 1 an internal error, 130 interrupted (Ctrl-C), "
            "143 terminated (kill), 141 the reader of the output went away. Compiled programs are "
            "kept between runs in the user's cache folder; PIEST_COMPILE_CACHE=off turns that off, "
            "PIEST_COMPILE_CACHE=DIR moves it."
        ),
    )
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, text in HELP.items():
        if command is not None and name != command:
            sub.add_parser(name, help=text)
            continue
        mod = command_module(name)
        p = sub.add_parser(
            name,
            help=text,
            description=mod.DESCRIPTION,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _module=mod)
    return parser


def _chosen(argv) -> str:
    """The command named on the command line ("" for none): the first word not an option."""
    return next((a for a in argv if not a.startswith("-")), "")


def main(argv=None) -> int:
    """Run the `piest` command line in this process (`piest_jax.run_cli`).

    **Arguments:** `argv`, the words after `piest`, e.g. `["fit", "data.csv", "--out", "fitted"]`
    (default: `sys.argv[1:]`). Like `piest`, it switches JAX to float64; its figures are drawn
    without pyplot, so matplotlib's backend and pyplot's figures stay as they were.

    **Returns:** the exit code: 0 success, 2 bad input (a one-line message on stderr), 1 an
    internal error, 130 interrupted, 143 terminated.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(_chosen(argv))
    args = parser.parse_args(argv)
    try:
        _require_plotting()
    except CLIError as e:
        print(f"piest {args.command}: error: {e}", file=sys.stderr)
        return 2
    # The command-line tool is an application, not library code: it computes in float64 so the
    # numbers it reports do not depend on JAX's float32 default.
    import jax

    jax.config.update("jax_enable_x64", True)
    # Under the `piest` entry (`interrupt.entry`) a signal ends the process at once; in someone
    # else's program SIGTERM unwinds as an exception, as Ctrl-C does.
    in_main_thread = threading.current_thread() is threading.main_thread() and not _interrupt.guarding()
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if in_main_thread else None
    try:
        _protect_inputs(args)
        # The command's files land together when it succeeds, or not at all (see _io); the
        # paths it prints are held back until they exist.
        mod = args._module
        with contextlib.redirect_stdout(io.StringIO()) as paths:
            with _io.output_transaction(
                nonfinite=getattr(mod, "NONFINITE", ()), outputs=getattr(mod, "OUTPUTS", ())
            ) as tx:
                code = int(args._run(args) or 0)
                if code:
                    tx.abort()
        if not code:
            print_notes(args)
        sys.stdout.write(paths.getvalue())
        sys.stdout.flush()
        return code
    except KeyboardInterrupt:
        print(f"piest {args.command}: interrupted", file=sys.stderr)
        return 130
    except _Terminated:
        print(f"piest {args.command}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except BrokenPipeError:
        # The reader of stdout went away (`piest ... | head -1`): stop quietly, as a shell tool
        # killed by SIGPIPE would, and keep the interpreter from failing again on its last flush.
        _silence_stdout()
        return 128 + signal.SIGPIPE
    except (CLIError, ValueError, OSError) as e:
        if os.environ.get("PIEST_DEBUG"):
            raise
        print(f"piest {args.command}: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except RuntimeError as e:
        if "EquinoxRuntimeError: " not in str(e) or os.environ.get("PIEST_DEBUG"):
            return _internal(args, e)
        print(f"piest {args.command}: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except Exception as e:  # anything else is a bug: still one line, but a different code
        return _internal(args, e)
    finally:
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous)


def _require_plotting() -> None:
    """Every command draws its figures with matplotlib, which the `cli` extra installs; say so
    before any computation rather than fail at the end."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise CLIError(
            "matplotlib is needed to draw the figures; install the command line's extras with "
            "pip install 'piest_jax[cli]'"
        ) from None


def _silence_stdout() -> None:
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # stdout is not a real file (captured)
        pass


def _internal(args, e: Exception) -> int:
    if os.environ.get("PIEST_DEBUG"):
        raise e
    msg = _one_line(e)[:300]
    print(
        f"piest {args.command}: internal error ({type(e).__name__}: {msg}); rerun with PIEST_DEBUG=1 for the traceback",
        file=sys.stderr,
    )
    return 1


def entry() -> None:
    """The `piest` console script (see `interrupt.py`)."""
    from .interrupt import entry as run

    run()


if __name__ == "__main__":
    entry()
