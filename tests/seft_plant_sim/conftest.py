"""Shared helpers of the plant-simulation tests."""

import numpy as np
import pytest


def _drive(rig, commands):
    """Apply `commands` (reference forces [N] or valve commands [V]) one step each; return the
    readings before each step, shape (n, 4): force [N], displacement [m], velocity [m/s],
    acceleration [m/s^2]."""
    rows = []
    for c in commands:
        m = rig.measure()
        rows.append((m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2))
        rig.apply(c)
    return np.array(rows)


@pytest.fixture(scope='session')
def drive():
    """:func:`_drive`: a rig driven open loop, its readings."""
    return _drive
