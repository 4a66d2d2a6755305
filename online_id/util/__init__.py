"""Small utilities every layer may use: one BLAS thread (``threads``), numba's cached compilation (``jit``),
an interrupt that came through compiled code (``interrupts``)."""
