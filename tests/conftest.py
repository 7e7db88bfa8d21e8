"""Test configuration: float64 everywhere unless a test asks for float32, deterministic hypothesis."""

import jax
import pytest
from hypothesis import HealthCheck, settings

# Tests compare against float64 NumPy references; the library itself never touches jax.config.
jax.config.update("jax_enable_x64", True)

settings.register_profile(
    "ci",
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("ci")


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(12345)
