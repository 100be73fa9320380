"""Validation of a ROM against the model it replaces: the paper's error measure and reports."""

from __future__ import annotations

import numpy as np

from .errors import DimensionError

__all__ = ["output_error"]


def output_error(y_ref: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Relative output error over time, paper eq. (19).

    ``eps_y(t_i) = ||y_ref(t_i) - y(t_i)||_2^2 / max_t ||y_ref(t)||_2^2``

    Parameters
    ----------
    y_ref, y : (p, k) ndarray
        Reference (full-order) and approximate outputs on the same time grid.

    Returns
    -------
    (k,) ndarray
    """
    y_ref = np.atleast_2d(np.asarray(y_ref, dtype=float))
    y = np.atleast_2d(np.asarray(y, dtype=float))
    if y_ref.shape != y.shape:
        raise DimensionError(f"outputs differ in shape: reference {y_ref.shape}, ROM {y.shape}")
    scale = np.max(np.sum(y_ref**2, axis=0))
    if scale == 0:
        raise DimensionError("the reference output is identically zero; eq. (19) is undefined")
    return np.sum((y_ref - y) ** 2, axis=0) / scale
