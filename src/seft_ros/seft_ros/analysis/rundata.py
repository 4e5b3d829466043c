"""The recorded signals of one substructure EFT run, whatever produced them (bag or simulate)."""

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ['RunData', 'SIGNALS', 'StructureRunData']

#: Signals compared against the reference analysis, in report order.
SIGNALS = ('displacement', 'force', 'acceleration')


@dataclass
class RunData:
    """Sampled signals of one run, one sample per control step, SI units.

    All arrays have shape ``(n,)`` where n is the number of steps that were completed (an
    aborted run is shorter than its record). Sample k is at ``time_s[k] = k*dt``.

    Attributes
    ----------
    params : dict
        Resolved run parameters (schema of ``seft_msgs_py.parameters``): ``alpha``, ``dt``,
        ``mass_kg``, ``damping_N_s_per_m``, ``stiffness_N_per_m``, ``rig_model``,
        ``predictor``, ``record``, ...
    time_s : ndarray (n,)
        Sample times [s].
    ground_acceleration_m_s2 : ndarray (n,)
        Ground acceleration xg'' after scaling and resampling [m/s^2].
    reference_force_N : ndarray (n,)
        Reference force f_r commanded at each step [N] (paper Eq. 5.3).
    measured_force_N : ndarray (n,)
        Load-cell force [N].
    displacement_m, velocity_m_s, acceleration_m_s2 : ndarray (n,)
        Measured specimen response [m], [m/s], [m/s^2] (relative to the ground).
    valve_command_V : ndarray (n,) or None
        Servo-valve command [V] (None for the 'delay' rig).
    stable : bool
        False if the run was aborted (limit exceeded or instability detected).
    unstable_at_s : float or None
        Time the run was aborted [s].
    abort_reason : str or None
        One-line reason of the abort.
    record_name : str
        Name of the ground-motion record.
    source : str
        Where the data came from (bag path or 'simulate').
    extra : dict
        Further data of the source. A run read from a bag (``analysis.bag.read_run``) has
        ``'rig_final'`` (the rig's final status), ``'counts'`` (messages per topic),
        ``'node_params'`` (``{node: {parameter: value}}`` as each node published them; empty
        for a bag without node parameters), ``'param_sources'`` (``{parameter: node,
        'run_parameters' or 'default'}``: where each value of `params` was taken from) and
        ``'parameter_mismatches'`` (one line per shared parameter on which the nodes
        disagreed, ``seft_msgs_py.parameters.shared_mismatches``; empty when they agree) and
        ``'recording'`` (how the recording ended: ``'end'`` is ``'closed'``, ``'stopped'``
        before the run's end, ``'crashed'``, the recorder killed and the bag recovered from
        its file, or ``'unknown'``; with the steps, messages and a one-line ``'note'``,
        ``seft_ros.analysis.bag.recording_end``; a gap adds ``'gap_at_step'`` and
        ``'steps_not_analysed'``), and, where the bag has them, ``'gaps'`` (the steps each
        topic misses and the complete steps after the first gap, not analysed),
        ``'duplicates'`` (steps recorded twice with the same value, read once) and
        ``'estimates_missing_steps'`` (``seft_ros.analysis.bag.read_run``).
    estimates : dict of str to ndarray (n,), or None
        The compensator's online estimates in effect for each sample's reference force,
        keyed by the compensator's ``ESTIMATES`` names (units in the name, e.g. ``mass_kg``,
        ``tau_s``; ATS ``a0`` [-], ``a1`` [s], ``a2`` [s^2]); None for a compensator without
        estimates.
    """

    params: dict[str, Any]
    time_s: np.ndarray
    ground_acceleration_m_s2: np.ndarray
    reference_force_N: np.ndarray
    measured_force_N: np.ndarray
    displacement_m: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray
    valve_command_V: np.ndarray | None = None
    stable: bool = True
    unstable_at_s: float | None = None
    abort_reason: str | None = None
    record_name: str = ''
    source: str = ''
    extra: dict[str, Any] = field(default_factory=dict)
    estimates: dict[str, np.ndarray] | None = None

    @property
    def n_steps(self) -> int:
        """Number of samples."""
        return int(self.time_s.shape[0])

    def signal(self, name: str) -> np.ndarray:
        """Return the measured signal 'displacement', 'force' or 'acceleration'."""
        return {'displacement': self.displacement_m, 'force': self.measured_force_N,
                'acceleration': self.acceleration_m_s2}[name]


@dataclass
class StructureRunData:
    """Sampled signals of one run of a structure test: every rig's, and the computational
    DOFs', one sample per control step, SI units (arrays of shape ``(n,)``).

    Attributes
    ----------
    params : dict
        The run's resolved parameters (with its ``structure``).
    rigs : dict of str to RunData
        Each rig's signals (its reference force, measured force and motion), keyed by rig
        name in the structure's order of its physical DOFs; its ``params`` are the rig's
        (the run's with the rig's section) with ``alpha`` = the rigid computational mass on
        its DOF over its specimen mass.
    time_s : ndarray (n,)
        Sample times [s].
    ground_acceleration_m_s2 : ndarray (n,)
        Ground acceleration [m/s^2].
    computational : dict of str to ndarray (n,)
        The computational DOFs' state as the builder integrated it:
        ``'<dof>/displacement_m'``, ``'<dof>/velocity_m_s'``, ``'<dof>/acceleration_m_s2'``
        (NaN where not recorded: the last sample).
    stable, unstable_at_s, abort_reason, record_name, source, extra
        As :class:`RunData` (``extra['abort_node']``: the node that ended the run,
        ``'<rig>/rig'`` for a rig).
    """

    params: dict[str, Any]
    rigs: dict[str, RunData]
    time_s: np.ndarray
    ground_acceleration_m_s2: np.ndarray
    computational: dict[str, np.ndarray]
    stable: bool = True
    unstable_at_s: float | None = None
    abort_reason: str | None = None
    record_name: str = ''
    source: str = ''
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def n_steps(self) -> int:
        """Number of samples."""
        return int(self.time_s.shape[0])
