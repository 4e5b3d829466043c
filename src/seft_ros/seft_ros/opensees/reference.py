"""The analytical reference of a test whose structure is an OpenSees model: OpenSees' own
analysis of the whole structure (no rclpy).

The whole model as its function builds it, specimens included (modelled by their elements,
nonlinear as they are), under the run's record as OpenSees' ``UniformExcitation`` (a
``Path`` series: the record linear between samples), ``Transformation`` constraints,
``Newmark`` average acceleration with ``Newton`` iterations to ``NormDispIncr`` 1e-12 m, at
a step of ``dt / REFERENCE_SUBSTEPS``: independent of seft's integrators (the matrix path's
exact step, the test's one OpenSees step per sample), and of the test's penalty constraint.
Its error is Newmark's at the finer step: a period error of about ``(omega h)^2 / 12``,
``h = dt / 5``: 0.017 % for a 16 Hz mode at 500 Hz.

:func:`seft_ros.analysis.reference.run_reference` calls it (the plug-in's ``reference``,
:mod:`seft_ros.opensees.plugin`) when the run's structure has an ``opensees`` model; it
returns the analysis' ``StructureReference`` with the elements' responses.
"""

import hashlib

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.reference import StructureReference
from seft_ros.core.structure import Substructures
from seft_ros.opensees.loader import captured, last_message, opensees
from seft_ros.opensees.model import KIND, ModelError, ModelSpec, build_model
from seft_ros.opensees.part import element_response

__all__ = ['opensees_reference', 'REFERENCE_SUBSTEPS']

#: OpenSees steps per sample of the reference analysis.
REFERENCE_SUBSTEPS = 5
#: The latest references (a report asks again for the one its comparison computed).
_CACHE: dict = {}
_PATTERN, _SERIES = 2_000_000_021, 2_000_000_022


#: How :func:`opensees_reference` computes (``StructureReference.method``).
METHOD = ("OpenSees' own transient analysis of the whole model (Newmark average acceleration, "
          'Newton to 1e-12 m, dt/{substeps})')


def opensees_reference(sub: Substructures, dt: float, ground_acceleration_m_s2, *,
                       substeps: int = REFERENCE_SUBSTEPS, elements=None) -> StructureReference:
    """OpenSees' analysis of the whole structure under a sampled ground acceleration.

    Parameters
    ----------
    sub : Substructures
        The split structure of a run (``sub.structure.model`` set; the specimens' masses
        for the interface forces).
    dt : float > 0
        Sample period [s].
    ground_acceleration_m_s2 : array_like (n,)
        xg'' at ``k dt`` [m/s^2], finite.
    substeps : int >= 1
        OpenSees steps per sample.
    elements : sequence of int, optional
        Elements whose response to record (a yielding member's hysteresis; default the
        model's ``elements``).

    Returns
    -------
    seft_ros.analysis.reference.StructureReference

    Raises
    ------
    ParameterError
        A structure without a model, a bad dt or record.
    ModelError
        The model does not build, or OpenSees fails to converge (the time is given).
    """
    s = sub.structure
    if s.model_kind != KIND:
        raise ParameterError('OpenSees reference: the structure has no OpenSees model')
    if not (isinstance(dt, (int, float)) and dt > 0):
        raise ParameterError(f'dt={dt!r}: expected a float > 0')
    ag = np.asarray(ground_acceleration_m_s2, dtype=float)
    if ag.ndim != 1 or not np.all(np.isfinite(ag)):
        raise ParameterError('ground_acceleration_m_s2: expected a finite 1-D array')
    spec = ModelSpec.from_doc(s.model)
    elements = [int(e) for e in (elements if elements is not None else spec.elements)]
    key = (s.to_json(), float(dt), hashlib.sha1(ag.tobytes()).hexdigest(), int(substeps),
           tuple(elements), tuple(sub.specimen_mass_kg))
    if key in _CACHE:
        return _CACHE[key]
    build_model(spec)
    ops = opensees()
    n, n_dof = ag.shape[0], s.n
    nodes = [(node, dof) for _, node, dof in spec.dofs]
    x, v, a = (np.zeros((n, n_dof)) for _ in range(3))
    forces = np.zeros((n, len(s.physical_index)))
    physical = []
    for j, i in enumerate(s.physical_index):
        rig = s.physical[s.dofs[i]]
        node, dof = nodes[i]
        for tag in spec.physical_elements[rig]:
            ele_nodes = list(ops.eleNodes(tag))
            if node in ele_nodes:
                offset = sum(len(ops.nodeDisp(nd)) for nd in ele_nodes[:ele_nodes.index(node)])
                physical.append((j, tag, offset + dof - 1))
    ele_f = {e: [] for e in elements}
    ele_d = {e: [] for e in elements}
    h = dt / int(substeps)
    with captured() as log:
        try:
            ops.wipeAnalysis()
            ops.setTime(0.0)          # the record from 0 (after a gravity analysis, say)
            # the last sample once more: a series ends there, and rounding of the time may step
            # just past it
            ops.timeSeries('Path', _SERIES, '-dt', float(dt), '-values', *ag.tolist(),
                           *ag[-1:].tolist())
            ops.pattern('UniformExcitation', _PATTERN, spec.excitation_dof, '-accel', _SERIES)
            ops.constraints('Transformation')
            ops.numberer('RCM')
            ops.system('BandGeneral')
            ops.test('NormDispIncr', 1e-12, 50)
            ops.algorithm('Newton')
            ops.integrator('Newmark', 0.5, 0.25)
            ops.analysis('Transient')
            # at rest under xg''(0): every DOF with mass accelerates by -xg''(0) relative to
            # the ground (Newmark's average acceleration keeps an inconsistent start's error)
            for node in ops.getNodeTags():
                mass = ops.nodeMass(node)
                d = spec.excitation_dof
                if len(mass) >= d and mass[d - 1] > 0.0:
                    ops.setNodeAccel(node, d, -float(ag[0]) if n else 0.0, '-commit')
            failed = None
            for k in range(n):
                if k > 0:
                    for _ in range(int(substeps)):
                        if ops.analyze(1, h) != 0:
                            failed = k
                            break
                    if failed is not None:
                        break
                for i, (node, dof) in enumerate(nodes):
                    x[k, i] = ops.nodeDisp(node, dof)
                    v[k, i] = ops.nodeVel(node, dof)
                    a[k, i] = ops.nodeAccel(node, dof)
                for j, tag, index in physical:
                    forces[k, j] += ops.eleForce(tag)[index]
                for e in elements:
                    force, deformation = element_response(ops, e)
                    ele_f[e].append(force)
                    ele_d[e].append(deformation)
            error = None
        except Exception as exc:
            error = exc
            failed = None
    if error is not None:
        raise ModelError(f'{spec.where}: the OpenSees reference failed: OpenSees: '
                         f'{last_message(log.text) or error}')
    if failed is not None:
        raise ModelError(f'{spec.where}: the OpenSees reference did not converge at '
                         f't = {failed * dt:.4f} s (OpenSees: {last_message(log.text)})')
    absolute = a + ag[:, None] * s.influence[None, :]
    restoring = forces.copy()
    for j, i in enumerate(s.physical_index):
        forces[:, j] += sub.specimen_mass_kg[j] * a[:, i]
    out = StructureReference(
        time_s=np.arange(n) * dt, dofs=s.dofs, rigs=s.rig_names,
        physical_index=s.physical_index, influence=s.influence, links=s.links,
        displacement_m=x, velocity_m_s=v, acceleration_m_s2=a,
        absolute_acceleration_m_s2=absolute, interface_force_N=forces,
        restoring_force_N=restoring, method=METHOD.format(substeps=int(substeps)),
        element_forces={e: np.array(f) for e, f in ele_f.items()},
        element_deformations={e: np.array(d) for e, d in ele_d.items()})
    while len(_CACHE) >= 2:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = out
    return out
