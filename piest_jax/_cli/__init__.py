"""The `piest` command-line tool: `piest COMMAND --help` describes each command."""

import argparse
import contextlib
import io
import os
import signal
import sys
import threading
from pathlib import Path

from . import output as _io
from ._common import CLIError
from . import compensate, diagnose, estimate, fit, montecarlo, simulate, reproduce

# Each command module provides NAME, HELP, DESCRIPTION, add_arguments(parser) and run(args) -> int.
COMMANDS = [simulate, diagnose, reproduce, montecarlo, fit, compensate, estimate]


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


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="piest",
        description=(
            "Prandtl-Ishlinskii hysteresis toolkit. Each command writes its figures and a JSON "
            "report into --out and prints the paths it wrote. Exit codes: 0 success, 2 bad "
            "input or arguments (one-line message), 1 an internal error, 130 interrupted (Ctrl-C), "
            "143 terminated (kill), 141 the reader of the output went away."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for mod in COMMANDS:
        p = sub.add_parser(
            mod.NAME,
            help=mod.HELP,
            description=mod.DESCRIPTION,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _module=mod)
    return parser


def main(argv=None) -> int:
    """Entry point of `piest`; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    # The command-line tool is an application, not library code: it computes in float64 so the
    # numbers it reports do not depend on JAX's float32 default.
    import jax

    jax.config.update("jax_enable_x64", True)
    in_main_thread = threading.current_thread() is threading.main_thread()
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
        f"piest {args.command}: internal error ({type(e).__name__}: {msg}); "
        "rerun with PIEST_DEBUG=1 for the traceback",
        file=sys.stderr,
    )
    return 1


if __name__ == "__main__":
    sys.exit(main())
