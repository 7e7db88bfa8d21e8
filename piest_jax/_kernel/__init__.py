"""The optional compiled CPU kernel for the play bank (see `_kernel.py`)."""

from ._kernel import available as available
from ._kernel import bank as bank
from ._kernel import pi_output as pi_output
from ._kernel import use_kernel as use_kernel
