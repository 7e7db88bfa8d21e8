"""The optional compiled CPU kernel for the play bank (see `binding.py`)."""

from .binding import available as available
from .binding import bank as bank
from .binding import isa as isa
from .binding import pi_output as pi_output
from .binding import use_kernel as use_kernel
