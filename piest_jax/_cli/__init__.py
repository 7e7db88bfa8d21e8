"""The `piest` command-line tool: `piest COMMAND --help` describes each command."""

import argparse
import os
import sys

from ._common import CLIError
from . import diagnose, simulate, reproduce

# Each command module provides NAME, HELP, DESCRIPTION, add_arguments(parser) and run(args) -> int.
COMMANDS = [simulate, diagnose, reproduce]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="piest",
        description=(
            "Prandtl-Ishlinskii hysteresis toolkit. Each command writes its figures and a JSON "
            "report into --out and prints the paths it wrote. Exit codes: 0 success, 2 bad "
            "input or arguments (one-line message), 1 an internal error, 130 interrupted."
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
        p.set_defaults(_run=mod.run)
    return parser


def main(argv=None) -> int:
    """Entry point of `piest`; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    # The command-line tool is an application, not library code: it computes in float64 so the
    # numbers it reports do not depend on JAX's float32 default.
    import jax

    jax.config.update("jax_enable_x64", True)
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print(f"piest {args.command}: interrupted", file=sys.stderr)
        return 130
    except (CLIError, ValueError, OSError) as e:
        if os.environ.get("PIEST_DEBUG"):
            raise
        msg = " ".join(str(e).split()) or type(e).__name__
        print(f"piest {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except Exception as e:  # anything else is a bug: still one line, but a different code
        if os.environ.get("PIEST_DEBUG"):
            raise
        msg = " ".join(str(e).split())[:300]
        print(
            f"piest {args.command}: internal error ({type(e).__name__}: {msg}); "
            "rerun with PIEST_DEBUG=1 for the traceback",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
