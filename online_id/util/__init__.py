"""Small utilities every layer may use: one BLAS thread (``threads``), numba's cached compilation (``jit``)."""
