import numpy as np

T = np.round(np.arange(0.0, 20.0 + 1e-9, 0.1), 6)


POSES = np.column_stack([T, T, np.zeros_like(T), np.zeros_like(T)])  # (N, 4) [t, x, y, z]
