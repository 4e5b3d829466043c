"""Sampled-data helpers shared by the rigs, the compensators and the stability analysis."""

import math

import numpy as np
from scipy.signal import cont2discrete

__all__ = ['zoh', 'split_delay']


def zoh(a, b, h: float):
    """Zero-order-hold discretization of ``x' = a x + b u`` over a hold of length `h`.

    Parameters
    ----------
    a : ndarray, shape (n, n)
    b : ndarray, shape (n, m)
    h : float >= 0
        Hold length [s]; 0 gives the identity and a zero input matrix.

    Returns
    -------
    phi : ndarray, shape (n, n)
        ``exp(a h)``.
    gamma : ndarray, shape (n, m)
        ``int_0^h exp(a s) ds b`` (``scipy.signal.cont2discrete(method='zoh')``).
    """
    if h <= 0.0:
        return np.eye(a.shape[0]), np.zeros_like(b)
    phi, gamma, *_ = cont2discrete((a, b, np.eye(a.shape[0]), np.zeros_like(b)), h, 'zoh')
    return phi, gamma


def split_delay(tau_s: float, dt: float) -> tuple[int, float]:
    """Split a delay into whole steps and a remainder: ``tau = n dt + delta``.

    ``0 <= delta < dt``; a remainder within 1e-9 dt of a step multiple snaps to 0, so that
    0.01 s at dt = 0.002 s is exactly 5 steps despite floating point.

    Returns
    -------
    n : int
        Whole steps.
    delta : float
        Remainder [s].
    """
    n = int(math.floor(tau_s / dt + 1e-9))
    delta = tau_s - n * dt
    if abs(delta) < 1e-9 * dt:
        delta = 0.0
    return n, max(delta, 0.0)
