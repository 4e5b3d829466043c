"""The recorded signals of one substructure EFT run, whatever produced them (bag or simulate).

Every test is a structure (:mod:`seft_ros.core.structure`): one or more rigs, each testing a
physical degree of freedom (DOF), and possibly computational DOFs integrated by the
reference-force builder. The reference study's test is the one-rig case: one physical DOF
carrying a rigid computational mass ``alpha m``, its rig in the root namespace (rig name
``''``). A run is a :class:`RunData` holding one :class:`RigData` per rig; a run of one rig
also reads as that rig (``run.displacement_m`` is its rig's), so the study's analysis is the
general one with one rig.
"""

from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

__all__ = ['RunData', 'RigData', 'SIGNALS', 'RIG_SIGNALS', 'rig_label', 'only_rig',
           'RECORDING_CUT_SHORT']

#: The ends of a recording that holds less than its run (``extra['recording']['end']``,
#: ``seft_ros.analysis.bag.recording_end``): never closed, stopped before the run ended, or
#: its file cut or damaged after the recording.
RECORDING_CUT_SHORT = ('crashed', 'stopped', 'damaged')

#: Signals compared against the reference analysis, in report order.
SIGNALS = ('displacement', 'force', 'acceleration')
#: The per-sample signals of a rig (attributes of :class:`RigData`), in bag order.
RIG_SIGNALS = ('reference_force_N', 'measured_force_N', 'displacement_m', 'velocity_m_s',
               'acceleration_m_s2', 'valve_command_V')


def rig_label(name: str) -> str:
    """How a rig is named to the user: its name, ``'rig'`` for the study's rig (``''``, the
    root namespace)."""
    return name or 'rig'


def only_rig(rigs: Mapping[str, Any], what: str, hint: str) -> Any:
    """The value of the only rig of `rigs` (a run's rigs, a comparison's).

    Raises
    ------
    AttributeError
        Several rigs: ``'a <what> of 2 rigs (pier_a, pier_b) has no single rig: <hint>'``.
    """
    if len(rigs) != 1:
        names = ', '.join(rig_label(r) for r in rigs)
        raise AttributeError(f'a {what} of {len(rigs)} rigs ({names}) has no single rig: '
                             f'{hint}')
    return next(iter(rigs.values()))


@dataclass
class RigData:
    """Sampled signals of one rig of a run, one sample per control step, SI units.

    All arrays have shape ``(n,)``, n the run's completed steps (:attr:`RunData.n_steps`).

    Attributes
    ----------
    params : dict
        The rig's resolved parameters (the run's, updated by the rig's section of the
        structure), with ``alpha`` = the rigid computational mass on its DOF over its specimen
        mass.
    reference_force_N : ndarray (n,)
        Reference force f_r commanded at each step [N] (paper Eq. 5.3; Eq. 2 of
        :mod:`seft_ros.core.structure`).
    measured_force_N : ndarray (n,)
        Load-cell force [N].
    displacement_m, velocity_m_s, acceleration_m_s2 : ndarray (n,)
        Measured specimen response [m], [m/s], [m/s^2] (relative to the ground).
    valve_command_V : ndarray (n,) or None
        Servo-valve command [V] (None for the 'delay' rig).
    estimates : dict of str to ndarray (n,), or None
        The rig's compensator's online estimates in effect for each sample's reference
        force, keyed by the compensator's ``ESTIMATES`` names (units in the name, e.g.
        ``mass_kg``, ``tau_s``; ATS ``a0`` [-], ``a1`` [s], ``a2`` [s^2]); None for a
        compensator without estimates.
    extra : dict
        Further data of the rig from its source (a bag: ``'rig_final'``, the rig's final
        status).
    """

    params: dict[str, Any]
    reference_force_N: np.ndarray
    measured_force_N: np.ndarray
    displacement_m: np.ndarray
    velocity_m_s: np.ndarray
    acceleration_m_s2: np.ndarray
    valve_command_V: np.ndarray | None = None
    estimates: dict[str, np.ndarray] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def signal(self, name: str) -> np.ndarray:
        """Return the measured signal 'displacement', 'force' or 'acceleration'."""
        return {'displacement': self.displacement_m, 'force': self.measured_force_N,
                'acceleration': self.acceleration_m_s2}[name]


def _single_rig(name: str):
    """A property of a one-rig run that reads its rig's attribute `name`."""
    def get(self):
        return getattr(self.rig, name)

    def set_(self, value):
        setattr(self.rig, name, value)
    return property(get, set_, doc=f"The rig's ``{name}`` (a run of one rig only; "
                    '``run.rigs[name]`` otherwise).')


@dataclass
class RunData:
    """Sampled signals of one run: every rig's and the computational DOFs', SI units.

    All arrays have shape ``(n,)`` where n is the number of steps that were completed (an
    aborted run is shorter than its record). Sample k is at ``time_s[k] = k*dt``.

    A run of one rig reads as that rig: ``run.displacement_m``, ``run.reference_force_N``,
    ``run.valve_command_V``, ``run.estimates``, ``run.signal(...)`` are its rig's
    (:attr:`rig`); with several rigs they raise ``AttributeError`` naming the rigs, and
    :meth:`rig_view` gives one rig as a run of its own.

    Attributes
    ----------
    params : dict
        The run's resolved parameters (schema of ``seft_msgs_py.parameters``): ``alpha``,
        ``dt``, ``mass_kg``, ``rig_model``, ``predictor``, ``record``, ``structure``
        ('none' for the study's test), ...
    time_s : ndarray (n,)
        Sample times [s].
    ground_acceleration_m_s2 : ndarray (n,)
        Ground acceleration xg'' after scaling and resampling [m/s^2].
    rigs : dict of str to RigData
        Each rig's signals, keyed by rig name in the structure's order of its physical DOFs
        (``''``: the study's single rig in the root namespace).
    computational : dict of str to ndarray (n,)
        The computational DOFs' state as the builder integrated it:
        ``'<dof>/displacement_m'``, ``'<dof>/velocity_m_s'``, ``'<dof>/acceleration_m_s2'``
        (NaN where not recorded: the last sample); empty without computational DOFs.
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
        Further data of the source. ``'abort_node'``: the node that ended the run
        (``'<rig>/rig'`` for a rig of a structure). A run read from a bag
        (``analysis.bag.read_run``) has ``'counts'`` (messages per topic), ``'node_params'``
        (``{node: {parameter: value}}`` as each node published them), ``'param_sources'``
        (``{parameter: node, 'run_parameters' or 'default'}``),
        ``'parameter_mismatches'`` (one line per shared parameter on which the nodes
        disagreed), ``'recording'`` (how the recording ended, ``analysis.bag.recording_end``),
        ``'rig_final'`` and ``'rig_finals'`` (the rigs' final status reports),
        ``'node_statuses'``, ``'recovered'`` and, where the bag has them, ``'gaps'``,
        ``'duplicates'``, ``'estimates_missing_steps'``, ``'timing'``, ``'link'`` (the
        whole list: ``analysis.bag.read_run``).
    """

    params: dict[str, Any]
    time_s: np.ndarray
    ground_acceleration_m_s2: np.ndarray
    rigs: dict[str, RigData]
    computational: dict[str, np.ndarray] = field(default_factory=dict)
    stable: bool = True
    unstable_at_s: float | None = None
    abort_reason: str | None = None
    record_name: str = ''
    source: str = ''
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def one_rig(cls, *, params: dict[str, Any], time_s, ground_acceleration_m_s2,
                reference_force_N, measured_force_N, displacement_m, velocity_m_s,
                acceleration_m_s2, valve_command_V=None, estimates=None, rig: str = '',
                rig_extra: dict[str, Any] | None = None, **run) -> 'RunData':
        """A run of one rig from its signals (the study's test: `rig` ``''``).

        The rig's parameters are the run's. Keyword arguments: the signals of
        :class:`RigData` and the run's fields (``stable``, ``abort_reason``, ...).
        """
        data = RigData(params, reference_force_N, measured_force_N, displacement_m,
                       velocity_m_s, acceleration_m_s2, valve_command_V, estimates,
                       dict(rig_extra or {}))
        return cls(params=params, time_s=time_s,
                   ground_acceleration_m_s2=ground_acceleration_m_s2, rigs={rig: data}, **run)

    @property
    def recording_cut_short(self) -> bool:
        """The run did not complete in its bag because its recording ended there
        (:data:`RECORDING_CUT_SHORT`: the recorder killed or stopped, the file cut), not
        because a node aborted it: the test may have gone on; a cut, not an abort (a new
        user's recovered cut recording read 'aborted'; session 36). Set by the bag's reader
        (``extra['cut_short']``)."""
        return not self.stable and bool(self.extra.get('cut_short'))

    @property
    def n_steps(self) -> int:
        """Number of samples."""
        return int(self.time_s.shape[0])

    @property
    def rig_names(self) -> tuple[str, ...]:
        """The rigs, in the structure's order."""
        return tuple(self.rigs)

    @property
    def is_study(self) -> bool:
        """Whether the run is the reference study's test (no ``structure`` parameter: one
        rig in the root namespace, only a rigid mass computational)."""
        return self.params.get('structure', 'none') in ('none', '', None)

    @property
    def rig(self) -> RigData:
        """The run's only rig.

        Raises
        ------
        AttributeError
            The run has several rigs (the message names them).
        """
        return only_rig(self.rigs, 'run', 'use run.rigs[name] or run.rig_view(name)')

    reference_force_N = _single_rig('reference_force_N')
    measured_force_N = _single_rig('measured_force_N')
    displacement_m = _single_rig('displacement_m')
    velocity_m_s = _single_rig('velocity_m_s')
    acceleration_m_s2 = _single_rig('acceleration_m_s2')
    valve_command_V = _single_rig('valve_command_V')
    estimates = _single_rig('estimates')

    def signal(self, name: str) -> np.ndarray:
        """Return the measured signal 'displacement', 'force' or 'acceleration' of the
        run's only rig."""
        return self.rig.signal(name)

    def rig_view(self, name: str) -> 'RunData':
        """One rig as a run of its own: its signals, its parameters as the run's, no
        computational DOFs, the run's time, record and outcome (arrays shared).

        Raises
        ------
        KeyError
            No such rig.
        """
        data = self.rigs[name]
        return replace(self, params=data.params, rigs={name: data}, computational={})
