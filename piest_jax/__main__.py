"""`python -m piest_jax COMMAND ...` runs the `piest` command line."""

from ._cli import entry

if __name__ == "__main__":
    entry()
