"""A structure given as an OpenSeesPy model: building it, checking it, linearizing it (no rclpy).

A structural engineer's model enters as written: a Python file (or a module) with a function
that builds the **whole** structure in OpenSees (nodes, masses, elements, materials, damping),
kept apart from the analysis seft drives (after OpenSees' own split of ``model``,
``analysis`` and ``recorder``). The ``structure`` section of a configuration names it::

    structure:
      opensees:
        model: frame.py            # a file beside the configuration, or 'package.module'
        function: build            # the function that builds the model (default 'build';
                                   # null: the file is a script that builds it)
        arguments: {}              # its keyword arguments (optional)
        dofs:                      # the degrees of freedom seft names: name -> [node, dof]
          floor_1: [12, 1]
          floor_2: [22, 1]
        physical_elements:         # each rig's specimen: the elements it replaces
          lab: [901]
        excitation_dof: 1          # the ground motion's direction (default 1)
        substeps: 1                # OpenSees steps per sample in the test (default 1)
        elements: [111]            # computational elements whose response is recorded (their
                                   # hysteresis in the report; optional)
        prediction: tangent        # the compensators predict the interface force with the
                                   # model's tangent (default), or 'initial': its
                                   # linearization (:mod:`seft_ros.opensees.part`)
        pushover: true             # with 'tangent', push the model over before the test to
                                   # find where its members first yield (default;
                                   # :mod:`seft_ros.opensees.probe`); false: skip it
        step: immediate            # OpenSees steps to the newest sample before the command
                                   # is built (default), or 'deferred': after it, the
                                   # command built from a linear step ahead of the model
      physical: {floor_1: lab}     # the DOF each rig tests

seft's degrees of freedom are the model's DOFs **with mass** (the others are condensed
statically, Guyan reduction); those not named in ``dofs`` are named ``node<n>_dof<d>``. Each
rig tests one DOF, at its **interface node**; its specimen is the elements listed for it in
``physical_elements``: removed from the computational model during the test (with the nodes
only they used), kept in the analytical reference (the whole model).

The linear model seft's compensators and its pre-run guard work with is the model's
linearization by OpenSees itself, at the state the model function leaves it in:
``integrator('GimmeMCK', m, c, k)`` assembles ``M``, ``C`` or ``K`` (``printA('-ret')``,
``constraints('Transformation')``), condensed to the DOFs with mass with the static
(Guyan) transformation ``T = [I; -K_oo^-1 K_om]``: ``K_r = T^T K T`` (exact for static
loads), ``M_r = T^T M T = M_mm`` (exact: the condensed DOFs are massless, lumped masses),
``C_r = T^T C T`` (the massless DOFs' velocities taken as following statically: exact for a
stiffness-proportional damping).

The specimen of each rig is checked against the model: its elements may act on the tested DOF
only (a rig drives one DOF), their stiffness and damping there become the rig's
``stiffness_N_per_m`` and ``damping_N_s_per_m`` unless the rig section gives them, and a rig
section that gives other values is refused; the model's mass at the interface is the
specimen's ``mass_kg`` plus the rigid computational mass ``mu`` that seft's reference force
carries (``- mu a_hat``, paper Eq. 2.5).

References
----------
R. J. Guyan (1965), Reduction of stiffness and mass matrices, AIAA J. 3(2):380.
F. McKenna, M. H. Scott, G. L. Fenves (2010), Nonlinear finite-element analysis software
architecture using object composition, J. Comput. Civ. Eng. 24(1):95-107 (OpenSees).
"""

from dataclasses import dataclass, field, replace
import importlib
import importlib.util
import math
from pathlib import Path
import sys
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_ros.core.structure import (
    ALPHA_DECIMALS,
    NAME_PATTERN,
    Link,
    Structure,
    Substructures,
)
from seft_ros.opensees.loader import captured, last_message, message_lines, opensees

__all__ = ['ModelSpec', 'SECTION_KEYS', 'parse_model_section', 'build_model', 'Linearization',
           'linearize', 'condense', 'model_structure', 'split_model', 'ModelError',
           'remove_specimens', 'interface_group', 'model_name', 'KIND', 'PREDICTIONS', 'STEPS']

#: The key of a ``structure`` section with an OpenSees model (the plug-in's name,
#: :mod:`seft_ros.core.models`).
KIND = 'opensees'
#: The keys of a ``structure.opensees`` section.
SECTION_KEYS = ('model', 'function', 'arguments', 'dofs', 'physical_elements', 'excitation_dof',
                'substeps', 'elements', 'prediction', 'step', 'pushover')
#: How the compensators predict the interface force (``prediction``): with the model's
#: tangent stiffness at the latest sample, or with its initial linearization.
PREDICTIONS = ('tangent', 'initial')
#: When OpenSees steps to a sample (``step``): before the builder builds the command from it
#: (``immediate``), or after, the command built from a linear step of the model's previous
#: sample (``deferred``: the OpenSees step off the command's critical path,
#: :mod:`seft_ros.opensees.part`).
STEPS = ('immediate', 'deferred')
#: Relative tolerance of the specimen checks against the model.
_TOL = 1e-6


class ModelError(ParameterError):
    """The OpenSees model failed to build, to analyse or to step (OpenSees' message kept)."""


@dataclass(frozen=True)
class ModelSpec:
    """Where a model comes from and how seft sees it (a checked ``structure.opensees``).

    Attributes
    ----------
    source : str
        An absolute path of a ``.py`` file, or a module name.
    function : str
        The function of `source` that builds the whole structure ('': `source` is a script
        that builds it, run as a whole each time).
    arguments : mapping
        Its keyword arguments.
    dofs : tuple of (str, int, int)
        Every seft DOF as ``(name, node, dof)`` (``dof`` from 1, OpenSees' numbering), in the
        structure's order; after parsing, the DOFs with mass not named are there too.
    physical_elements : mapping of str to tuple of int
        Rig -> the element tags of its specimen.
    excitation_dof : int
        The DOF (from 1) along which the ground moves.
    substeps : int >= 1
        OpenSees steps per sample in the test.
    computational : mapping
        ``damping_matrix_N_s_per_m``, ``stiffness_matrix_N_per_m`` of the computational model
        (specimens removed), condensed to `dofs` (after parsing).
    elements : tuple of int
        Computational elements whose response the test records and the report draws.
    where : str
        The section's name in error messages.
    prediction : str
        One of :data:`PREDICTIONS`.
    step : str
        One of :data:`STEPS`.
    pushover : bool
        With ``prediction: tangent``, whether the part pushes the model over before the
        test (:func:`seft_ros.opensees.probe.probe_yield`).
    """

    source: str
    function: str = 'build'
    arguments: Mapping = field(default_factory=dict)
    dofs: tuple = ()
    physical_elements: Mapping = field(default_factory=dict)
    excitation_dof: int = 1
    substeps: int = 1
    computational: Mapping = field(default_factory=dict)
    elements: tuple = ()
    where: str = 'structure.opensees'
    prediction: str = 'tangent'
    step: str = 'immediate'
    pushover: bool = True

    def interface(self, dof_name: str) -> tuple[int, int]:
        """``(node, dof)`` of a seft DOF (KeyError if none)."""
        for name, node, dof in self.dofs:
            if name == dof_name:
                return node, dof
        raise KeyError(dof_name)

    def to_doc(self) -> dict:
        """The JSON-able form (the ``opensees`` entry of the structure's JSON)."""
        return {'model': self.source, 'function': self.function,
                'arguments': dict(self.arguments),
                'dofs': [[n, int(a), int(b)] for n, a, b in self.dofs],
                'physical_elements': {r: [int(e) for e in v]
                                      for r, v in self.physical_elements.items()},
                'excitation_dof': int(self.excitation_dof), 'substeps': int(self.substeps),
                'elements': [int(e) for e in self.elements],
                'prediction': self.prediction, 'step': self.step, 'pushover': self.pushover,
                'computational': {k: np.asarray(v).tolist()
                                  for k, v in self.computational.items()}}

    @classmethod
    def from_doc(cls, doc: Mapping, *, where: str = 'structure.opensees') -> 'ModelSpec':
        """Read :meth:`to_doc`'s form back.

        Raises
        ------
        ParameterError
            A field missing or of the wrong type.
        """
        try:
            return cls(str(doc['model']), str(doc.get('function', 'build')),
                       MappingProxyType(dict(doc.get('arguments') or {})),
                       tuple((str(n), int(a), int(b)) for n, a, b in doc.get('dofs', ())),
                       MappingProxyType({str(r): tuple(int(e) for e in v) for r, v in
                                         (doc.get('physical_elements') or {}).items()}),
                       int(doc.get('excitation_dof', 1)), int(doc.get('substeps', 1)),
                       MappingProxyType({k: np.asarray(v, dtype=float) for k, v in
                                         (doc.get('computational') or {}).items()}),
                       tuple(int(e) for e in doc.get('elements', ())), where,
                       str(doc.get('prediction', 'tangent')), str(doc.get('step', 'immediate')),
                       bool(doc.get('pushover', True)))
        except (KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f'{where}: expected the model section seft wrote ({exc!r})') \
                from None


def _int(where: str, key: str, value, low: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ParameterError(f'{where}.{key}: expected an integer >= {low}, got {value!r}')
    return int(value)


def parse_model_section(section, *, where: str = 'structure.opensees',
                        base: Path | None = None) -> ModelSpec:
    """Check a ``structure.opensees`` section's form (not the model: :func:`build_model`).

    Parameters
    ----------
    section : mapping
        The section (module notes).
    where : str
        Its name in error messages (the file and section).
    base : Path, optional
        The configuration's directory: a relative model file is found there.

    Returns
    -------
    ModelSpec
        Named DOFs only (the model adds the others).

    Raises
    ------
    ParameterError
        An unknown key; a missing or unreadable ``model``; a DOF name that is not a ROS name,
        a DOF that is not ``[node, dof]``; physical elements that are not lists of tags.
    """
    if not isinstance(section, Mapping):
        raise ParameterError(f'{where}: expected a mapping ({", ".join(SECTION_KEYS)}), got '
                             f'{section!r}')
    unknown = sorted(set(section) - set(SECTION_KEYS))
    if unknown:
        raise ParameterError(f'{where}.{unknown[0]}: unknown key (expected one of '
                             f'{", ".join(SECTION_KEYS)})')
    model = section.get('model')
    if not isinstance(model, str) or not model.strip():
        raise ParameterError(f'{where}.model: expected a Python file (frame.py) or a module '
                             f"(package.module, or 'package.module:function'), got {model!r}")
    function = section.get('function', 'build')
    if ':' in model and not model.endswith('.py'):
        model, _, function_in = model.partition(':')
        if 'function' in section and section['function'] != function_in:
            raise ParameterError(f'{where}.function: {section["function"]!r} and the model\'s '
                                 f'{function_in!r}: give the function once')
        function = function_in
    if function is None or function == '':
        if not model.endswith('.py'):
            raise ParameterError(f'{where}.function: a module needs the function that builds '
                                 'the model (only a .py file may be run as a script)')
        function = ''                     # the file is a script that builds the model
    elif not isinstance(function, str) or not function.isidentifier():
        raise ParameterError(f'{where}.function: expected a Python function name (or null: '
                             f'the file is a script that builds the model), got {function!r}')
    if model.endswith('.py'):
        path = Path(model)
        if not path.is_absolute():
            path = (base or Path.cwd()) / path
        if not path.is_file():
            raise ParameterError(f'{where}.model: {path}: no such model file')
        source = str(path.resolve())
    else:
        if not all(part.isidentifier() for part in model.split('.')):
            raise ParameterError(f'{where}.model: expected a .py file or a module name, got '
                                 f'{model!r}')
        source = model
    arguments = section.get('arguments', {}) or {}
    if not isinstance(arguments, Mapping) or not all(isinstance(k, str) for k in arguments):
        raise ParameterError(f'{where}.arguments: expected a mapping of keyword arguments, got '
                             f'{arguments!r}')
    dofs_in = section.get('dofs')
    if not isinstance(dofs_in, Mapping) or not dofs_in:
        raise ParameterError(f'{where}.dofs: expected a mapping of DOF names to [node, dof] '
                             f'(at least each physical DOF), got {dofs_in!r}')
    dofs = []
    for name, value in dofs_in.items():
        if not isinstance(name, str) or not NAME_PATTERN.match(name):
            raise ParameterError(f'{where}.dofs: {name!r}: expected a name of letters, digits '
                                 'and underscores that starts with a letter')
        if (not isinstance(value, (list, tuple)) or len(value) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
            raise ParameterError(f'{where}.dofs.{name}: expected [node tag, dof] (integers, '
                                 f'the dof from 1), got {value!r}')
        dofs.append((name, int(value[0]), _int(f'{where}.dofs', name, value[1])))
    seen = {}
    for name, node, dof in dofs:
        if (node, dof) in seen:
            raise ParameterError(f'{where}.dofs: {seen[(node, dof)]} and {name} are both node '
                                 f'{node} dof {dof}')
        seen[(node, dof)] = name
    elements_in = section.get('physical_elements')
    if not isinstance(elements_in, Mapping) or not elements_in:
        raise ParameterError(f'{where}.physical_elements: expected a mapping of each rig to its '
                             f"specimen's element tags ({{lab: [901]}}), got {elements_in!r}")
    elements = {}
    for rig, tags in elements_in.items():
        if isinstance(tags, int) and not isinstance(tags, bool):
            tags = [tags]
        if (not isinstance(tags, (list, tuple)) or not tags
                or not all(isinstance(t, int) and not isinstance(t, bool) for t in tags)):
            raise ParameterError(f'{where}.physical_elements.{rig}: expected a list of element '
                                 f'tags, got {tags!r}')
        elements[str(rig)] = tuple(int(t) for t in tags)
    excitation = _int(where, 'excitation_dof', section.get('excitation_dof', 1))
    substeps = _int(where, 'substeps', section.get('substeps', 1))
    recorded = section.get('elements', [])
    if (not isinstance(recorded, (list, tuple))
            or not all(isinstance(t, int) and not isinstance(t, bool) for t in recorded)):
        raise ParameterError(f'{where}.elements: expected a list of element tags, got '
                             f'{recorded!r}')
    prediction = section.get('prediction', 'tangent')
    if prediction not in PREDICTIONS:
        raise ParameterError(f'{where}.prediction: expected one of {", ".join(PREDICTIONS)}, '
                             f'got {prediction!r}')
    step = section.get('step', 'immediate')
    if step not in STEPS:
        raise ParameterError(f'{where}.step: expected one of {", ".join(STEPS)}, got {step!r}')
    pushover = section.get('pushover', True)
    if not isinstance(pushover, bool):
        raise ParameterError(f'{where}.pushover: expected true or false, got {pushover!r}')
    return ModelSpec(source, function, MappingProxyType(dict(arguments)), tuple(dofs),
                     MappingProxyType(elements), excitation, substeps, MappingProxyType({}),
                     tuple(int(t) for t in recorded), where, prediction, step, pushover)


def _builder(spec: ModelSpec):
    """The model function of `spec` (imported; OpenSeesPy loaded first)."""
    opensees()
    where = f'{spec.where}.model'
    if not spec.function:             # a script: run as a whole, its arguments as globals
        import runpy

        def script(**arguments):
            runpy.run_path(spec.source, init_globals=arguments, run_name='__seft_model__')
        return script
    try:
        if spec.source.endswith('.py'):
            name = 'seft_opensees_model_' + str(abs(hash(spec.source)))
            module = sys.modules.get(name)
            if module is None:
                loader_spec = importlib.util.spec_from_file_location(name, spec.source)
                module = importlib.util.module_from_spec(loader_spec)
                sys.modules[name] = module
                try:
                    loader_spec.loader.exec_module(module)
                except BaseException:
                    sys.modules.pop(name, None)
                    raise
        else:
            module = importlib.import_module(spec.source)
    except ModelError:
        raise
    except (Exception, SystemExit) as exc:    # sys.exit() in the module: not seft's exit
        raise ModelError(f'{where}: {Path(spec.source).name}: importing it raised '
                         f'{_raised(exc)}') from None
    fn = getattr(module, spec.function, None)
    if not callable(fn):
        raise ModelError(f'{spec.where}.function: {Path(spec.source).name} has no function '
                         f'{spec.function!r}')
    return fn


def model_name(source: str, function: str, *, sep: str = ':') -> str:
    """How messages name a model: ``frame.py:build`` (``frame.py: build()`` with
    ``sep=': '``), or ``frame.py`` for a script."""
    base = Path(source).name
    if not function:
        return base
    return f'{base}{sep}{function}' + ('()' if sep != ':' else '')


def build_model(spec: ModelSpec, *, test: bool = False) -> list[str]:
    """Build the model of `spec` in OpenSees (``wipe()`` first: one model per process).

    Parameters
    ----------
    spec : ModelSpec
    test : bool
        Build the computational model of the test: the physical elements removed, with the
        nodes only they used (:func:`remove_specimens`); default the whole structure.

    Returns
    -------
    list of str
        What OpenSees said while the model built (its warnings: a zeroLength element whose
        nodes are apart, say), one line each, whitespace collapsed; empty when it said
        nothing.

    Raises
    ------
    ModelError
        The model function raised (or called sys.exit), or OpenSees refused a command (its
        message kept).
    ParameterError
        A DOF's node missing or its DOF beyond the node's, a physical element missing or not
        connected to its rig's interface node.
    """
    ops = opensees()
    fn = _builder(spec)
    name = model_name(spec.source, spec.function, sep=': ')
    with captured() as log:
        try:
            ops.wipe()
            fn(**dict(spec.arguments))
            error = None
        except (Exception, SystemExit) as exc:  # sys.exit() in the model: not seft's exit
            error = exc
    if error is not None:
        said = last_message(log.text)
        detail = f'OpenSees: {said}' if said and 'See' in str(error) else (
            _raised(error) + (f' (OpenSees: {said})' if said else ''))
        raise ModelError(f'{spec.where}.model: {name} failed: {detail}')
    _check_model(spec, name)
    if test:
        remove_specimens(spec)
    return message_lines(log.text)


def _raised(exc: BaseException) -> str:
    """``Type: message`` of an exception a model raised (a ``SystemExit`` with its code)."""
    said = exc.code if isinstance(exc, SystemExit) else exc
    return f'{type(exc).__name__}: {said}'


def _check_model(spec: ModelSpec, name: str) -> None:
    """The named DOFs and the physical elements exist and make sense."""
    ops = opensees()
    nodes = set(ops.getNodeTags())
    if not nodes:
        raise ModelError(f'{spec.where}.model: {name} built no node')
    for dof_name, node, dof in spec.dofs:
        if node not in nodes:
            raise ParameterError(f'{spec.where}.dofs.{dof_name}: node {node} is not in the model '
                                 f'({len(nodes)} nodes: {_some(sorted(nodes))})')
        ndf = len(ops.nodeDisp(node))
        if dof > ndf:
            raise ParameterError(f'{spec.where}.dofs.{dof_name}: node {node} has {ndf} dofs '
                                 f'(1..{ndf}), no dof {dof}')
    elements = set(ops.getEleTags())
    physical = {t for tags in spec.physical_elements.values() for t in tags}
    for tag in spec.elements:
        if tag not in elements:
            raise ParameterError(f'{spec.where}.elements: element {tag} is not in the model '
                                 f'({len(elements)} elements: {_some(sorted(elements))})')
        if tag in physical:
            raise ParameterError(f'{spec.where}.elements: element {tag} is a physical element '
                                 '(the rig measures the specimen); name computational ones')
    for rig, tags in spec.physical_elements.items():
        for tag in tags:
            if tag not in elements:
                raise ParameterError(f'{spec.where}.physical_elements.{rig}: element {tag} is '
                                     f'not in the model ({len(elements)} elements: '
                                     f'{_some(sorted(elements))})')


def _some(values, n: int = 8) -> str:
    text = ', '.join(str(v) for v in values[:n])
    return text + (', ...' if len(values) > n else '')


def check_connected(spec: ModelSpec, interfaces: Mapping[str, tuple[int, int]]) -> None:
    """Each rig's physical elements reach its interface node through one another.

    Raises
    ------
    ParameterError
        An element of a rig's specimen is not connected to that rig's interface node.
    """
    ops = opensees()
    for rig, tags in spec.physical_elements.items():
        node = interfaces[rig][0]
        nodes_of = {t: set(ops.eleNodes(t)) for t in tags}
        reached, todo = {node}, True
        joined = set()
        while todo:
            todo = False
            for t, ns in nodes_of.items():
                if t not in joined and ns & reached:
                    joined.add(t)
                    reached |= ns
                    todo = True
        tied = set(interface_group(node, interfaces[rig][1])) - {node}
        for t in tags:
            if t not in joined:
                via = sorted(set(ops.eleNodes(t)) & tied)
                hint = (f'; its node {via[0]} is tied to node {node} by an equalDOF: connect '
                        f'the element to node {node} itself (the rig acts there)' if via
                        else ": a specimen acts on its rig's DOF")
                raise ParameterError(
                    f'{spec.where}.physical_elements.{rig}: element {t} (nodes '
                    f'{", ".join(str(n) for n in ops.eleNodes(t))}) is not connected to the '
                    f'interface node {node} of rig {rig}{hint}')


def remove_specimens(spec: ModelSpec) -> list[int]:
    """Remove the physical elements from the model in OpenSees, and the nodes only they used
    (with their constraints), keeping every node of a seft DOF.

    Returns
    -------
    list of int
        The removed nodes.

    Raises
    ------
    ModelError
        OpenSees refused a removal.
    """
    ops = opensees()
    physical = [t for tags in spec.physical_elements.values() for t in tags]
    touched = set()
    for tag in physical:
        touched |= set(ops.eleNodes(tag))
    kept_nodes = {node for _, node, _ in spec.dofs}
    with captured() as log:
        try:
            for tag in physical:
                ops.remove('ele', tag)
            used = set()
            for tag in ops.getEleTags():
                used |= set(ops.eleNodes(tag))
            orphans = sorted(touched - used - kept_nodes)
            fixed = set(ops.getFixedNodes())
            constrained = set(ops.getConstrainedNodes())
            for node in orphans:
                if node in fixed:
                    for dof in range(1, len(ops.nodeDisp(node)) + 1):
                        ops.remove('sp', node, dof)
                if node in constrained:
                    ops.remove('mp', node)
                ops.remove('node', node)
            error = None
        except Exception as exc:
            error = exc
    if error is not None:
        raise ModelError(f'{spec.where}.physical_elements: removing the specimens failed: '
                         f'OpenSees: {last_message(log.text) or error}')
    return orphans


@dataclass(frozen=True)
class Linearization:
    """A model's assembled matrices, in OpenSees' equation numbering.

    Attributes
    ----------
    mass_kg, damping_N_s_per_m, stiffness_N_per_m : ndarray, shape (n_eq, n_eq)
        ``M``, ``C``, ``K`` (``integrator('GimmeMCK', ...)``, ``printA('-ret')``) [SI].
    equations : dict of (int, int) to int
        ``(node, dof)`` -> its equation (constrained DOFs: their retained equation; fixed DOFs
        are absent).
    """

    mass_kg: np.ndarray
    damping_N_s_per_m: np.ndarray
    stiffness_N_per_m: np.ndarray
    equations: dict

    def equation(self, node: int, dof: int) -> int | None:
        """The equation of a node's DOF (None: fixed)."""
        return self.equations.get((node, dof))


def linearize(where: str = 'structure.opensees', *, stiffness_only: bool = False
              ) -> Linearization:
    """The model in OpenSees linearized at its current state (module notes).

    The analysis is wiped before and after (a test sets its own). With `stiffness_only`
    only ``K`` is assembled (``M`` and ``C`` are zeros).

    Raises
    ------
    ModelError
        OpenSees could not assemble the matrices.
    """
    ops = opensees()
    mats = []
    with captured() as log:
        try:
            ops.wipeAnalysis()
            ops.system('FullGeneral')
            ops.numberer('Plain')
            ops.constraints('Transformation')
            ops.algorithm('Linear')
            for factors in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)):
                if stiffness_only and factors[2] == 0.0:
                    continue
                ops.integrator('GimmeMCK', *factors)
                ops.analysis('Transient')
                ops.analyze(1, 0.0)          # the solve may fail (M singular): A is assembled
                a = np.asarray(ops.printA('-ret'), dtype=float)
                n = int(round(math.sqrt(a.size)))
                mats.append(a.reshape(n, n))
            equations = {}
            for node in ops.getNodeTags():
                for dof, eq in enumerate(ops.nodeDOFs(node), start=1):
                    if eq >= 0:
                        equations[(int(node), dof)] = int(eq)
            ops.wipeAnalysis()
            error = None
        except Exception as exc:
            error = exc
    if error is not None or not mats or mats[0].size == 0:
        raise ModelError(f"{where}: OpenSees could not assemble the model's M, C, K "
                         f'(OpenSees: {last_message(log.text) or error})')
    if stiffness_only:
        return Linearization(np.zeros_like(mats[0]), np.zeros_like(mats[0]), mats[0], equations)
    return Linearization(mats[0], mats[1], mats[2], equations)


def condense(lin: Linearization, keep, *, where: str = 'structure.opensees'):
    """``M``, ``C``, ``K`` condensed to the equations `keep` (module notes: Guyan).

    Parameters
    ----------
    lin : Linearization
    keep : sequence of int
        The retained equations, in the order of the result.

    Returns
    -------
    tuple of ndarray, each shape (len(keep), len(keep))
        ``M_r``, ``C_r``, ``K_r`` (symmetrized).

    Raises
    ------
    ParameterError
        The condensed DOFs are not held by stiffness (``K_oo`` singular), or a condensed DOF
        has mass.
    """
    keep = list(keep)
    n = lin.stiffness_N_per_m.shape[0]
    other = [i for i in range(n) if i not in set(keep)]
    m, c, k = (0.5 * (a + a.T) for a in (lin.mass_kg, lin.damping_N_s_per_m,
                                          lin.stiffness_N_per_m))
    if not other:
        return (m[np.ix_(keep, keep)], c[np.ix_(keep, keep)], k[np.ix_(keep, keep)])
    k_oo = k[np.ix_(other, other)]
    scale = max(float(np.max(np.abs(k))), 1e-300)
    if np.linalg.cond(k_oo) * 1e-14 > 1.0 or np.max(np.abs(k_oo)) < 1e-12 * scale:
        raise ParameterError(f"{where}: the model's DOFs without mass are not all held by "
                             'stiffness (their stiffness matrix is singular): a node without '
                             'elements, or a mechanism')
    t = np.zeros((n, len(keep)))
    t[keep, range(len(keep))] = 1.0
    t[other, :] = -np.linalg.solve(k_oo, k[np.ix_(other, keep)])
    out = tuple(t.T @ a @ t for a in (m, c, k))
    return tuple(0.5 * (a + a.T) for a in out)


def _mass_dofs(lin: Linearization, spec: ModelSpec):
    """The seft DOFs of the model: the named ones, then the other equations with mass
    (``node<n>_dof<d>``), and their equations."""
    mass = np.diag(lin.mass_kg)
    scale = max(float(np.max(np.abs(mass))), 1e-300)
    dofs, eqs = [], []
    for name, node, dof in spec.dofs:
        eq = lin.equation(node, dof)
        if eq is None:
            raise ParameterError(f'{spec.where}.dofs.{name}: node {node} dof {dof} is fixed')
        if mass[eq] <= 1e-12 * scale:
            raise ParameterError(f'{spec.where}.dofs.{name}: node {node} dof {dof} has no mass: '
                                 "seft's DOFs are the model's DOFs with mass (the others are "
                                 'condensed)')
        if eq in eqs:
            other = dofs[eqs.index(eq)][0]
            raise ParameterError(f'{spec.where}.dofs.{name}: node {node} dof {dof} is '
                                 f'constrained to {other} (one equation): name one of them')
        dofs.append((name, node, dof))
        eqs.append(eq)
    first = {}
    for (node, dof), eq in sorted(lin.equations.items()):
        first.setdefault(eq, (node, dof))
    for eq in range(mass.shape[0]):
        if mass[eq] > 1e-12 * scale and eq not in eqs:
            node, dof = first[eq]
            dofs.append((f'node{node}_dof{dof}', node, dof))
            eqs.append(eq)
    return tuple(dofs), eqs


def model_structure(section: Mapping, *, rigs: Mapping | None = None,
                    where: str = 'structure', base: Path | None = None) -> Structure:
    """A :class:`~seft_ros.core.structure.Structure` from a ``structure`` section with an
    ``opensees`` model (module notes): the whole model's linearization, condensed.

    Parameters
    ----------
    section : mapping
        The ``structure`` section: ``opensees`` and ``physical``.
    rigs : mapping, optional
        The ``rigs`` section (rig -> parameter overrides); each rig's ``stiffness_N_per_m``
        and ``damping_N_s_per_m`` default to its specimen's in the model.
    where : str
        The section's name in error messages.
    base : Path, optional
        The configuration's directory.

    Returns
    -------
    Structure
        Its ``opensees`` holds the :class:`ModelSpec` (with every DOF and the computational
        model's condensed ``C`` and ``K``) as :meth:`ModelSpec.to_doc`.

    Raises
    ------
    ParameterError, ModelError
        The section, the model or a rig (module notes; one line naming the field).
    """
    allowed = {'opensees', 'physical'}
    unknown = sorted(set(section) - allowed)
    if unknown:
        raise ParameterError(f'{where}.{unknown[0]}: not with an OpenSees model (the model '
                             'gives the masses, stiffness and damping; expected opensees and '
                             'physical)')
    spec = parse_model_section(section['opensees'], where=f'{where}.opensees', base=base)
    physical = section.get('physical')
    names = [d for d, _, _ in spec.dofs]
    if not isinstance(physical, Mapping) or not physical:
        raise ParameterError(f'{where}.physical: expected a mapping of at least one dof to the '
                             f'rig that tests it ({{{names[0]}: <rig name>}}), got {physical!r}')
    for dof, rig in physical.items():
        if dof not in names:
            raise ParameterError(f'{where}.physical: {dof!r} is not a dof of '
                                 f'{where}.opensees.dofs ({", ".join(names)})')
        if not isinstance(rig, str) or not NAME_PATTERN.match(rig):
            raise ParameterError(f'{where}.physical.{dof}: expected a rig name of letters, '
                                 f'digits and underscores that starts with a letter, got '
                                 f'{rig!r}')
    used = list(physical.values())
    for rig in used:
        if used.count(rig) > 1:
            raise ParameterError(f'{where}.physical: rig {rig!r} tests two dofs; a rig tests '
                                 'one dof')
    for rig in spec.physical_elements:
        if rig not in used:
            # (the physical key's name alone: `where` starts with the file, which the
            # message's head names already; a new user read it pasted mid-sentence)
            raise ParameterError(f'{spec.where}.physical_elements.{rig}: no dof of '
                                 f'{where.rsplit(": ", 1)[-1]}.physical names this rig '
                                 f'(rigs: {", ".join(used)})')
    for rig in used:
        if rig not in spec.physical_elements:
            raise ParameterError(f'{spec.where}.physical_elements: no elements for rig {rig!r} '
                                 '(its specimen: the elements it replaces in the model)')
    interfaces = {rig: spec.interface(dof) for dof, rig in physical.items()}
    # the whole structure
    build_model(spec)
    check_connected(spec, interfaces)
    _check_interfaces(spec, interfaces)
    whole = linearize(spec.where)
    for rig, (node, dof) in interfaces.items():
        if whole.equation(node, dof) is None:
            raise ParameterError(f'{where}.physical: rig {rig} tests node {node} dof {dof}, '
                                 'which the model fixes')
    dofs, eqs = _mass_dofs(whole, spec)
    _check_excitation(spec, dofs)
    m, c, k = condense(whole, eqs, where=spec.where)
    # the computational part: the specimens removed
    build_model(spec, test=True)
    comp = linearize(spec.where)
    comp_eqs = []
    for name, node, dof in dofs:
        eq = comp.equation(node, dof)
        if eq is None:                  # pragma: no cover - removal keeps the DOFs' nodes
            raise ParameterError(f'{spec.where}.dofs.{name}: node {node} lost by the removal')
        comp_eqs.append(eq)
    comp_mass = np.diag(comp.mass_kg)
    extra = [eq for eq in range(comp_mass.shape[0]) if comp_mass[eq] > 0 and eq not in comp_eqs]
    if extra:
        raise ParameterError(f'{spec.where}.physical_elements: the computational model has mass '
                             'where the whole structure has none (a specimen element with mass '
                             'on a node of its own?)')
    _, c_c, k_c = condense(comp, comp_eqs, where=spec.where)
    _check_elements_mass(whole, spec)
    names = tuple(d for d, _, _ in dofs)
    influence = np.array([1.0 if d == spec.excitation_dof else 0.0 for _, _, d in dofs])
    rig_values = {}
    rigs = {} if rigs is None else rigs
    if not isinstance(rigs, Mapping):
        raise ParameterError(f'rigs: expected a mapping of rig names to their parameters, '
                             f'got {rigs!r}')
    for rig, values in rigs.items():
        if rig not in used:
            raise ParameterError(f'rigs.{rig}: no dof of {where}.physical names this rig '
                                 f'(rigs: {", ".join(used)})')
        if not isinstance(values, Mapping):
            raise ParameterError(f'rigs.{rig}: expected a mapping of parameters, got {values!r}')
    ordered = {d: physical[d] for d in names if d in physical}
    for dof, rig in ordered.items():
        i = names.index(dof)
        spec_k = float(k[i, i] - k_c[i, i])
        spec_c = float(c[i, i] - c_c[i, i])
        values = {'stiffness_N_per_m': spec_k, 'damping_N_s_per_m': max(spec_c, 0.0)}
        values.update(rigs.get(rig, {}))
        rig_values[rig] = MappingProxyType(values)
    n_named = len(spec.dofs)
    spec = replace(spec, dofs=dofs, computational=MappingProxyType(
        {'damping_matrix_N_s_per_m': c_c, 'stiffness_matrix_N_per_m': k_c}))
    w = np.linalg.eigvalsh(k)
    if w.min() <= 1e-9 * max(abs(w.max()), 1e-300):
        raise ParameterError(f"{spec.where}: the whole model's condensed stiffness is not "
                             f'positive definite (smallest eigenvalue {w.min():.6g}): it must '
                             'stand on the ground')
    lateral = [i for i, (_, _, d) in enumerate(dofs[:n_named]) if d == spec.excitation_dof]
    links = tuple(Link(i, j, f'{names[i]}-{names[j]}' if j is not None else f'{names[i]}-ground')
                  for j, i in zip([None] + lateral[:-1], lateral))
    return Structure(names, m, c, k, influence, MappingProxyType(ordered),
                     MappingProxyType(rig_values), links, KIND, model_kind=KIND,
                     model=MappingProxyType(spec.to_doc()))


def _check_interfaces(spec: ModelSpec, interfaces: Mapping[str, tuple[int, int]]) -> None:
    """An interface DOF constrained to another node's (the constrained side of an
    ``equalDOF``) is refused: the rig tests the retained node's DOF, and the nodes tied to it
    in that direction move with it (:func:`interface_group`)."""
    ops = opensees()
    constrained = set(ops.getConstrainedNodes())
    for rig, (node, dof) in interfaces.items():
        if node in constrained and dof in ops.getConstrainedDOFs(node):
            retained = [r for r in ops.getRetainedNodes() if node in ops.getConstrainedNodes(r)]
            raise ParameterError(
                f'{spec.where}.dofs: rig {rig} tests node {node} dof {dof}, which a multi-point '
                f'constraint ties to node {", ".join(str(r) for r in retained) or "?"}: name '
                'the retained node (the nodes tied to it move with it)')


def interface_group(node: int, dof: int) -> list[int]:
    """The interface node and the nodes an ``equalDOF`` ties to it in `dof` (they move with
    it: their forces in that direction act on the interface), in the model in OpenSees."""
    ops = opensees()
    group = [node]
    if node in set(ops.getRetainedNodes()):
        for c in ops.getConstrainedNodes(node):
            if dof in ops.getConstrainedDOFs(c) and c not in group:
                group.append(int(c))
    return group


def _check_excitation(spec: ModelSpec, dofs) -> None:
    """Refuse an ``excitation_dof`` in which no DOF of the model has mass (the ground
    motion would load nothing), with the model in OpenSees."""
    directions = sorted({d for _, _, d in dofs})
    if spec.excitation_dof in directions:
        return
    ops = opensees()
    ndf = max(len(ops.nodeDisp(node)) for node in ops.getNodeTags())
    raise ParameterError(f'{spec.where}.excitation_dof: {spec.excitation_dof}: no DOF with mass '
                         f'in that direction (the model has ndf {ndf}; masses in dof '
                         f'{", ".join(str(d) for d in directions)})')


def _check_elements_mass(lin: Linearization, spec: ModelSpec) -> None:
    """The ground motion is applied as nodal forces from the nodal masses: refuse a model
    whose elements carry mass of their own."""
    ops = opensees()
    nodal = 0.0
    for node in ops.getNodeTags():
        mass = ops.nodeMass(node) if hasattr(ops, 'nodeMass') else []
        if len(mass) >= spec.excitation_dof:
            nodal += float(mass[spec.excitation_dof - 1])
    iota = np.zeros(lin.mass_kg.shape[0])
    for (node, dof), eq in lin.equations.items():
        if dof == spec.excitation_dof:
            iota[eq] = 1.0
    total = float(iota @ lin.mass_kg @ iota)
    if abs(total - nodal) > 1e-6 * max(abs(total), 1e-300):
        raise ParameterError(f'{spec.where}.model: the elements carry mass ({total - nodal:.6g} '
                             'kg along the excitation beside the nodal masses): give the masses '
                             'as nodal masses (ops.mass) so that the ground motion loads them')


def split_model(structure: Structure, specimens: Mapping[str, Mapping[str, Any]], *,
                where: str = 'structure') -> Substructures:
    """:func:`~seft_ros.core.structure.split` for a structure from an OpenSees model.

    The computational part is the model without the specimens (its condensed ``C_c``,
    ``K_c``); ``M_c`` is ``M`` with the rigid mass ``mu_p = M_pp - m_p`` at each physical DOF.

    Raises
    ------
    ParameterError
        A rig without parameters; a physical DOF coupled by mass to another DOF or lighter
        than its specimen; the specimen's elements acting on other DOFs than their rig's;
        a rig's ``stiffness_N_per_m`` or ``damping_N_s_per_m`` that is not its elements'
        (both values given).
    """
    spec = ModelSpec.from_doc(structure.model, where=f'{where}.opensees')
    k_c = np.asarray(spec.computational['stiffness_matrix_N_per_m'], dtype=float)
    c_c = np.asarray(spec.computational['damping_matrix_N_s_per_m'], dtype=float)
    mass, stiff, damp = structure.mass_kg, structure.stiffness_N_per_m, \
        structure.damping_N_s_per_m
    idx = structure.physical_index
    m, c, k = np.zeros(len(idx)), np.zeros(len(idx)), np.zeros(len(idx))
    dk, dc = stiff - k_c, damp - c_c
    kscale = float(np.max(np.abs(stiff)))
    cscale = max(float(np.max(np.abs(damp))), 1e-300)
    for j, i in enumerate(idx):
        dof = structure.dofs[i]
        rig = structure.physical[dof]
        if rig not in specimens:
            raise ParameterError(f'{where}.physical.{dof}: rig {rig!r} has no parameters')
        p = specimens[rig]
        m[j], c[j], k[j] = (float(p['mass_kg']), float(p['damping_N_s_per_m']),
                            float(p['stiffness_N_per_m']))
        others = [o for o in range(structure.n) if o != i and mass[i, o] != 0.0]
        if others:
            raise ParameterError(f'{where}: physical dof {dof!r} is coupled by mass to '
                                 f'{structure.dofs[others[0]]!r}; a physical dof needs a '
                                 'lumped mass')
        if mass[i, i] < m[j] * (1.0 - 1e-9):
            raise ParameterError(
                f"{where}.opensees: the model's mass at physical dof {dof!r} is "
                f"{float(mass[i, i])!r} kg, less than rig {rig}'s specimen mass_kg="
                f"{float(m[j])!r}: the mass at the interface node is the specimen's plus the "
                'computational mass it carries')
        node, d = spec.interface(dof)
        where_el = f'{where}.opensees.physical_elements.{rig}'
        if abs(dk[i, i] - k[j]) > _TOL * max(abs(k[j]), abs(dk[i, i])):
            raise ParameterError(
                f"{where_el}: the specimen's elements give node {node} dof {d} a stiffness of "
                f"{dk[i, i]:.6g} N/m, but rig {rig}'s stiffness_N_per_m={k[j]:.6g}: the model "
                "and the rig disagree (leave it out of the rig section to take the model's)")
        if abs(dc[i, i] - c[j]) > _TOL * max(abs(c[j]), abs(dc[i, i]), 1e-9 * cscale):
            raise ParameterError(
                f"{where_el}: the specimen's elements give node {node} dof {d} a damping of "
                f"{dc[i, i]:.6g} N s/m, but rig {rig}'s damping_N_s_per_m={c[j]:.6g}: the model "
                "and the rig disagree (leave it out of the rig section to take the model's)")
    for name, delta, scale, unit in (('stiffness', dk, kscale, 'N/m'),
                                     ('damping', dc, cscale, 'N s/m')):
        rest = delta.copy()
        for i in idx:
            rest[i, i] = 0.0
        if np.max(np.abs(rest)) > _TOL * scale:
            a, b = np.unravel_index(int(np.argmax(np.abs(rest))), rest.shape)
            at = (f'at {structure.dofs[a]}, which no rig tests' if a == b else
                  f'between {structure.dofs[a]} and {structure.dofs[b]}')
            raise ParameterError(
                f'{where}.opensees.physical_elements: the specimens act on other dofs than '
                f"their rigs' ({name} {rest[a, b]:.6g} {unit} {at}): a rig drives one dof, so "
                'its specimen must act on that dof only (e.g. a zeroLength or twoNodeLink '
                'element in that direction, not a story between two floors)')
    rigid = np.array([max(mass[i, i] - m[j], 0.0) for j, i in enumerate(idx)])
    alpha = np.round(rigid / m, ALPHA_DECIMALS)
    mc = mass.copy()
    for j, i in enumerate(idx):
        mc[i, i] = rigid[j]
    return Substructures(structure, m, c, k, rigid, alpha, mc, c_c.copy(), k_c.copy())
