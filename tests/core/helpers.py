"""Shared pieces of the core property tests."""

import numpy as np
from hypothesis import strategies as st

#: every property test draws its random data from one integer seed, so failures replay exactly
seeds = st.integers(0, 2**32 - 1)


def rel_err(a, b):
    """Largest absolute difference, relative to the size of ``b`` (at least 1)."""
    return np.abs(a - b).max() / max(1.0, np.abs(b).max())
