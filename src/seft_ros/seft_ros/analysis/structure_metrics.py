"""A structure test against its analytical reference, per degree of freedom (no rclpy).

The reference is the whole structure
(:func:`~seft_ros.analysis.structure_reference.structure_reference`, ``scipy.signal.lsim`` of Eq.
1 of :mod:`seft_ros.core.structure` from
the recorded record). Per degree of freedom (DOF) the test's displacement, relative
acceleration and floor (absolute) acceleration are compared with the reference's — a
physical DOF's from its rig's sensors, a computational DOF's from the builder's state — and,
at a physical DOF, the interface force (the rig's load cell against the force the reference
specimen carries, ``m_p x'' + c_p x' + k_p x``, paper Eq. 2.4 per rig). Each link of the
structure (a story of a shear building, a bearing) is compared by its deformation (the story
drift); each rig by the RTHS benchmark's criteria J1-J5 (its reference force against its
load cell, its DOF's displacement against the reference's).

Every comparison removes the signal's own lag first, as the single-rig analysis does
(:func:`seft_ros.analysis.metrics.compare_run`).
"""

from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.criteria import evaluation_criteria
from seft_ros.analysis.metrics import (
    MAX_LAG_S,
    SignalComparison,
    estimate_lag,
    json_safe,
    nrms_error,
    peak,
    peak_ratio,
    shift,
)
from seft_ros.analysis.rundata import RunData
from seft_ros.analysis.structure_reference import StructureReference, structure_reference
from seft_ros.analysis.timing import link_summary

__all__ = ['DofComparison', 'LinkComparison', 'StructureComparison', 'compare_structure',
           'structure_summary_entry', 'reference_of', 'dof_signals', 'DOF_SIGNALS']

#: The compared signals of a DOF, in report order (``interface_force`` at physical DOFs).
DOF_SIGNALS = ('displacement', 'acceleration', 'floor_acceleration', 'interface_force')


def _signal(test, reference, dt: float, max_lag_s: float) -> SignalComparison:
    """:class:`SignalComparison` of two signals over the samples finite in both."""
    test = np.asarray(test, dtype=float)
    reference = np.asarray(reference, dtype=float)
    good = np.isfinite(test) & np.isfinite(reference)
    n = int(np.argmin(good)) if not np.all(good) else test.shape[0]
    test, reference = test[:n], reference[:n]
    if n < 2:
        return SignalComparison(math.nan, math.nan, math.nan, math.nan, math.nan, math.nan,
                                math.nan)
    lag = estimate_lag(test, reference, dt, max_lag_s)
    return SignalComparison(
        peak_test=peak(test), peak_reference=peak(reference), lag_s=lag,
        nrms=nrms_error(shift(test, lag, dt), reference),
        peak_ratio=peak_ratio(test, reference), nrms_unshifted=nrms_error(test, reference),
        nrms_common_lag=math.nan)


@dataclass(frozen=True)
class DofComparison:
    """One degree of freedom of a structure test against the reference.

    Attributes
    ----------
    dof : str
        Its name.
    rig : str or None
        The rig that tests it (None: computational).
    displacement, acceleration, floor_acceleration : SignalComparison
        Displacement relative to the ground [m], relative and absolute acceleration [m/s^2].
    interface_force : SignalComparison or None
        Physical DOF: the rig's load-cell force against the reference specimen's force [N].
    """

    dof: str
    rig: str | None
    displacement: SignalComparison
    acceleration: SignalComparison
    floor_acceleration: SignalComparison
    interface_force: SignalComparison | None = None

    def signal(self, name: str) -> SignalComparison | None:
        """The comparison of one of :data:`DOF_SIGNALS`."""
        if name not in DOF_SIGNALS:
            raise ParameterError(f'signal {name!r}: expected one of {", ".join(DOF_SIGNALS)}')
        return getattr(self, name)


@dataclass(frozen=True)
class LinkComparison:
    """The deformation of one link (a story, a bearing) against the reference.

    Attributes
    ----------
    name : str
        ``story_<i>`` of a shear building, ``<dof>-<dof>`` or ``<dof>-ground``.
    drift : SignalComparison
        Its deformation [m] (the story drift: the relative displacement of its ends).
    """

    name: str
    drift: SignalComparison


@dataclass(frozen=True)
class StructureComparison:
    """A structure test against its reference (module notes).

    Attributes
    ----------
    dofs : tuple of DofComparison
        In the structure's DOF order.
    links : tuple of LinkComparison
    criteria : dict of str to Criteria
        Per rig, the RTHS benchmark's J1-J5.
    reference : StructureReference
        The reference over the run's samples.
    n_steps : int
        The samples compared.
    """

    dofs: tuple
    links: tuple
    criteria: dict
    reference: StructureReference
    n_steps: int

    def dof(self, name: str) -> DofComparison:
        """The comparison of DOF `name` (KeyError if none)."""
        for d in self.dofs:
            if d.dof == name:
                return d
        raise KeyError(name)

    @property
    def worst_displacement_nrms(self) -> float:
        """The largest displacement NRMS over the DOFs (a fraction; NaN if none)."""
        values = [d.displacement.nrms for d in self.dofs if math.isfinite(d.displacement.nrms)]
        return max(values) if values else math.nan


def reference_of(run: RunData) -> StructureReference:
    """The whole structure's reference of a run, from its parameters and its record.

    Raises
    ------
    ParameterError
        The run's ``structure`` is missing or invalid.
    """
    from seft_ros.core.structure import test_setup as structure_setup
    setup = structure_setup(run.params)
    sub = setup.substructures
    if sub.structure.opensees is not None:
        # hook (issue 32): an OpenSees model's reference is OpenSees' own analysis of it
        from seft_ros.opensees.reference import opensees_reference
        return opensees_reference(sub, float(run.params['dt']), run.ground_acceleration_m_s2)
    specimens = list(zip(sub.specimen_mass_kg, sub.specimen_damping_N_s_per_m,
                         sub.specimen_stiffness_N_per_m))
    return structure_reference(sub.structure, specimens, float(run.params['dt']),
                               run.ground_acceleration_m_s2)


def dof_signals(run: RunData) -> dict[str, dict[str, np.ndarray]]:
    """The test's signals per DOF: ``{dof: {'displacement', 'velocity', 'acceleration',
    'floor_acceleration', ['interface_force']}}``, arrays of shape (n,) (a computational DOF's
    last sample is NaN: the builder's state of sample k comes with the force of k+1).

    Raises
    ------
    ParameterError
        The run has no structure, or a DOF's signals are missing.
    """
    from seft_ros.core.structure import Structure
    structure = Structure.from_json(run.params['structure'])
    ag = np.asarray(run.ground_acceleration_m_s2, dtype=float)
    out = {}
    for i, dof in enumerate(structure.dofs):
        iota = float(structure.influence[i])
        if dof in structure.physical:
            rig = run.rigs[structure.physical[dof]]
            x, v, a = rig.displacement_m, rig.velocity_m_s, rig.acceleration_m_s2
            extra = {'interface_force': np.asarray(rig.measured_force_N, dtype=float)}
        else:
            try:
                x, v, a = (run.computational[f'{dof}/{q}'] for q in (
                    'displacement_m', 'velocity_m_s', 'acceleration_m_s2'))
            except KeyError:
                raise ParameterError(f'computational dof {dof!r}: its state is not in the '
                                     'run') from None
            extra = {}
        a = np.asarray(a, dtype=float)
        out[dof] = {'displacement': np.asarray(x, dtype=float),
                    'velocity': np.asarray(v, dtype=float), 'acceleration': a,
                    'floor_acceleration': a + iota * ag, **extra}
    return out


def compare_structure(run: RunData, reference: StructureReference | None = None, *,
                      max_lag_s: float = MAX_LAG_S) -> StructureComparison:
    """Compare a structure test with the whole structure's reference (module notes).

    Parameters
    ----------
    run : RunData
        The run (n samples; an aborted run is compared over the samples it has).
    reference : StructureReference, optional
        Default: :func:`reference_of` the run.
    max_lag_s : float >= 0
        Bound of the lag search [s].

    Returns
    -------
    StructureComparison

    Raises
    ------
    ParameterError
        A run without a structure, or a reference shorter than the run.
    """
    from seft_ros.core.structure import Structure
    structure = Structure.from_json(run.params['structure'])
    if reference is None:
        reference = reference_of(run)
    n = run.n_steps
    if reference.time_s.shape[0] < n:
        raise ParameterError(f'reference has {reference.time_s.shape[0]} samples, the run {n}; '
                             'expected at least as many as the run')
    dt = float(run.params['dt'])
    test = dof_signals(run)
    refs = {'displacement': reference.displacement_m, 'acceleration':
            reference.acceleration_m_s2, 'floor_acceleration':
            reference.absolute_acceleration_m_s2}
    dofs = []
    physical_order = list(structure.physical_index)
    for i, dof in enumerate(structure.dofs):
        signals = {name: _signal(test[dof][name][:n], refs[name][:n, i], dt, max_lag_s)
                   for name in refs}
        rig = structure.physical.get(dof)
        force = None
        if rig is not None:
            j = physical_order.index(i)
            force = _signal(test[dof]['interface_force'][:n],
                            reference.interface_force_N[:n, j], dt, max_lag_s)
        dofs.append(DofComparison(dof, rig, interface_force=force, **signals))
    links = []
    for link in structure.links:
        x_i = test[structure.dofs[link.i]]['displacement'][:n]
        r_i = reference.displacement_m[:n, link.i]
        x_j = (test[structure.dofs[link.j]]['displacement'][:n] if link.j is not None
               else np.zeros(n))
        r_j = reference.displacement_m[:n, link.j] if link.j is not None else np.zeros(n)
        links.append(LinkComparison(link.name, _signal(x_i - x_j, r_i - r_j, dt, max_lag_s)))
    criteria = {}
    for j, i in enumerate(physical_order):
        rig_name = structure.physical[structure.dofs[i]]
        rig = run.rigs[rig_name]
        criteria[rig_name] = evaluation_criteria(
            target_force=np.asarray(rig.reference_force_N, dtype=float)[:n],
            measured_force=np.asarray(rig.measured_force_N, dtype=float)[:n],
            displacement=np.asarray(rig.displacement_m, dtype=float)[:n],
            reference_displacement=reference.displacement_m[:n, i], dt=dt)
    return StructureComparison(tuple(dofs), tuple(links), criteria, reference, n)


def _signal_entry(c: SignalComparison | None) -> dict[str, Any] | None:
    if c is None:
        return None
    return {'nrms': c.nrms, 'peak_ratio': c.peak_ratio, 'lag_s': c.lag_s,
            'peak_test': c.peak_test, 'peak_reference': c.peak_reference,
            'nrms_unshifted': c.nrms_unshifted}


def structure_summary_entry(run: RunData,
                            comparison: StructureComparison) -> dict[str, Any]:
    """A structure run and its comparison as a JSON-safe dict (``summary.json``).

    Returns
    -------
    dict
        ``{'structure': {'dofs', 'physical', 'builders'}, 'predictor', 'record', 'stable',
        'unstable_at_s', 'abort_reason', 'abort_node', 'mode', 'wall_s', 'n_steps',
        'nrms': {'displacement'}, 'dofs': {dof: {'rig', 'displacement', 'acceleration',
        'floor_acceleration', 'interface_force'}}, 'links': {name: {...}}, 'rigs': {rig:
        {'rig_model', 'criteria': {'J1', ..., 'J5'}}}}`` (and ``'timing'`` of a real-time
        run, ``'bag_lost_messages'`` of a bag the recorder closed). Each signal: ``nrms``
        (after removing its own lag, a fraction), ``peak_ratio``, ``lag_s`` [s],
        ``peak_test`` and ``peak_reference`` (SI), ``nrms_unshifted``; ``interface_force``
        is None at a computational DOF; ``nrms.displacement`` is the largest over the DOFs.
        NaN and inf are None.
    """
    from seft_msgs_py.graph import Graph
    from seft_ros.core.structure import Structure
    params = run.params
    structure = Structure.from_json(params['structure'])
    graph = Graph.from_parameters(params)
    entry = {
        'structure': {'dofs': list(structure.dofs), 'physical': dict(structure.physical),
                      'builders': params.get('structure_builders', 'central')},
        'predictor': params.get('predictor'),
        'record': run.record_name or params.get('record', ''),
        'stable': bool(run.stable),
        'unstable_at_s': run.unstable_at_s,
        'abort_reason': run.abort_reason,
        'abort_node': run.extra.get('abort_node'),
        'mode': params.get('mode', 'lockstep'),
        'wall_s': run.extra.get('wall_s'),
        'n_steps': comparison.n_steps,
        'nrms': {'displacement': comparison.worst_displacement_nrms},
        'dofs': {d.dof: {'rig': d.rig, **{name: _signal_entry(d.signal(name))
                                           for name in DOF_SIGNALS}}
                 for d in comparison.dofs},
        'links': {lk.name: _signal_entry(lk.drift) for lk in comparison.links},
        'rigs': {r: {'rig_model': graph.rig_models[r],
                     'criteria': comparison.criteria[r].as_dict()} for r in graph.rigs},
    }
    if run.extra.get('timing') is not None:
        entry['timing'] = run.extra['timing']
    if run.extra.get('bag_lost_messages') is not None:
        entry['bag_lost_messages'] = int(run.extra['bag_lost_messages'])
    link = link_summary(run.extra.get('link'), run.extra.get('timing'))
    if link is not None:
        entry['link'] = link
    if run.extra.get('parameter_mismatches'):
        entry['parameter_mismatches'] = list(run.extra['parameter_mismatches'])
    if structure.opensees is not None:
        # hook (issue 32): an OpenSees model's step times and overruns
        from seft_ros.opensees.report import opensees_entry
        entry['opensees'] = opensees_entry(run)
    return json_safe(entry)
