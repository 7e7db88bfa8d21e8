"""`python -m piest_jax COMMAND ...` runs the `piest` command line."""

import sys

from ._cli import main

if __name__ == "__main__":
    sys.exit(main())
