"""The analytical reference of a structure test: the whole structure from the recorded record.

Imports no rclpy. The counterpart of :mod:`seft_ros.analysis.reference` for a structure
(:mod:`seft_ros.core.structure`): the whole linear structure, physical and computational DOFs
together, ``M x'' + C x' + K x = -M iota xg''``, simulated with ``scipy.signal.lsim`` on the
state ``[x, x']`` with the record linear between samples (first-order hold, exact for it:
Nigam and Jennings 1969).
"""

from dataclasses import dataclass

import numpy as np
from scipy import signal

from seft_msgs_py.errors import ParameterError
from seft_ros.core.structure import Structure

__all__ = ['StructureReference', 'structure_reference']


@dataclass(frozen=True)
class StructureReference:
    """Response of the whole structure, one sample per step, SI units, relative to the ground.

    Attributes
    ----------
    time_s : ndarray (n,)
    displacement_m, velocity_m_s, acceleration_m_s2 : ndarray (n, n_dof)
        Per DOF, in the structure's DOF order.
    absolute_acceleration_m_s2 : ndarray (n, n_dof)
        ``x'' + iota xg''`` (floor accelerations).
    interface_force_N : ndarray (n, n_p)
        At each physical DOF (structure order), the force its specimen carries,
        ``m_p x_p'' + c_p x_p' + k_p x_p``: what the rig's load cell should read (Eq. 2 of
        :mod:`seft_ros.core.structure`).
    """

    time_s: np.ndarray
    displacement_m: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray
    absolute_acceleration_m_s2: np.ndarray
    interface_force_N: np.ndarray


def structure_reference(structure: Structure, specimens, dt: float,
                        ground_acceleration_m_s2) -> StructureReference:
    """Simulate the whole structure from rest under a sampled ground acceleration.

    Parameters
    ----------
    structure : Structure
    specimens : sequence of (m, c, k)
        The specimen of each physical DOF, in structure order [kg, N s/m, N/m] (for the
        interface forces).
    dt : float > 0
        Sample period [s].
    ground_acceleration_m_s2 : array_like (n,)
        xg'' at ``k dt`` [m/s^2], finite.

    Returns
    -------
    StructureReference

    Raises
    ------
    ParameterError
        A bad dt or record.
    """
    if not (isinstance(dt, (int, float)) and dt > 0):
        raise ParameterError(f'dt={dt!r}: expected a float > 0')
    ag = np.asarray(ground_acceleration_m_s2, dtype=float)
    if ag.ndim != 1 or not np.all(np.isfinite(ag)):
        raise ParameterError('ground_acceleration_m_s2: expected a finite 1-D array')
    n_dof = structure.n
    m, c, k = structure.mass_kg, structure.damping_N_s_per_m, structure.stiffness_N_per_m
    minv = np.linalg.inv(m)
    a = np.block([[np.zeros((n_dof, n_dof)), np.eye(n_dof)], [-minv @ k, -minv @ c]])
    b = np.concatenate([np.zeros(n_dof), -structure.influence])[:, None]
    n = ag.shape[0]
    t = np.arange(n) * dt
    if n >= 2:
        system = signal.StateSpace(a, b, np.eye(2 * n_dof), np.zeros((2 * n_dof, 1)))
        _, _, states = signal.lsim(system, ag, t, interp=True)
        states = np.atleast_2d(states).reshape(n, 2 * n_dof)
    else:
        states = np.zeros((n, 2 * n_dof))
    x, v = states[:, :n_dof], states[:, n_dof:]
    acc = -(x @ (minv @ k).T + v @ (minv @ c).T) - ag[:, None] * structure.influence[None, :]
    absolute = acc + ag[:, None] * structure.influence[None, :]
    forces = []
    for (mp, cp, kp), i in zip(specimens, structure.physical_index):
        forces.append(mp * acc[:, i] + cp * v[:, i] + kp * x[:, i])
    return StructureReference(t, x, v, acc, absolute, np.column_stack(forces))
