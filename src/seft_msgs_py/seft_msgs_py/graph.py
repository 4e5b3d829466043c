"""The node graph of a run as data: its nodes, their ROS namespaces and their topics.

Imports no rclpy (the bag reader uses it too); ``seft_msgs_py.topics.spec_for`` adds the
message classes and QoS.

**The reference study's test** is one rig in the root namespace: the nodes
``ground_motion_publisher``, ``reference_force_builder``, ``force_servo_controller`` (not with
the delay rig), ``rig`` and ``recorder`` on the topics ``/seft/...`` of
:mod:`seft_msgs_py.signals`, exactly as before structures existed.

**A structure test** (parameter ``structure``, :mod:`seft_ros.core.structure`) has one rig and
one force servo controller per physical degree of freedom, each pair in the ROS namespace named
after its rig (``ros2 run ... --ros-args -r __ns:=/<rig>``; ros2/demos' habit: several
instances of a node are namespaces, not new node names). Their topics are the study's with the
namespace in front (``/<rig>/seft/measurement``, ``/<rig>/seft/reference_force``,
``/<rig>/seft/valve_command``, ``/<rig>/seft/record/rig``, ...). One ground-motion publisher
and one recorder serve the whole test, in the root namespace. The reference-force builder is
either one, in the root namespace, commanding every rig (``structure_builders: central``: one
host, or the computation on a host of its own with the network in the loop), or one per rig,
in the rig's namespace beside its controller (``per_rig``: each lab host closes its rig's loop
itself and integrates a replica of the computational part, the network out of the fast loop).
``/seft/status``, ``/seft/node_parameters``, ``/seft/run_parameters``, the ground motion and
``/clock`` (published by the first rig, the clock master) stay global.

**Node names.** A namespaced node is named ``<rig>/<node>`` in status reports, parameters and
``seft run --nodes`` (its *qualified name*); a node of the root namespace by its own name.

**Who publishes what** (:meth:`Graph.publishers_of`): every topic of the run has its
publishers in the graph (one node for a data topic); a publisher of any other name, or one
more of the same name, is foreign (issue 42: ``seft_msgs_py.node_support`` names it when its
message is not sealed for the run, the runner when it appears). :meth:`Graph.command_topics`
are the topics whose messages end up in a command to a rig (a foreign publisher there ends
the run); on the others (record streams for the bag, ``/clock``, status, parameters) it is a
warning.
"""

from dataclasses import dataclass
import json
import re
from typing import Any, Mapping

from seft_msgs_py import parameters
from seft_msgs_py import signals as sig
from seft_msgs_py.errors import ParameterError

__all__ = ['Graph', 'qualified', 'split_qualified', 'scoped', 'CENTRAL', 'PER_RIG',
           'STRUCTURE_STATE', 'RIG_NODES', 'STRUCTURE_BUILDERS', 'SPECIMEN_MODEL', 'TOOL_NODES',
           'UNKNOWN_NODE']

#: ``structure_builders``: one builder in the root namespace commands every rig.
CENTRAL = 'central'
#: ``structure_builders``: one builder per rig, in the rig's namespace.
PER_RIG = 'per_rig'
STRUCTURE_BUILDERS = (CENTRAL, PER_RIG)
#: The nodes that run once per rig (in its namespace) with the rig's own parameters.
RIG_NODES = parameters.RIG_SCOPED_NODES
_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')

#: The computational DOFs' state as a builder integrated it, per sample (a fields stream:
#: ``name`` = ``<dof>/displacement_m``, ``<dof>/velocity_m_s``, ``<dof>/acceleration_m_s2``).
STRUCTURE_STATE = sig.Signal(
    '/seft/structure_state', 'sensor_msgs/msg/JointState', 'position', 'm, m/s, m/s^2',
    'reference_force_builder',
    "The computational degrees of freedom's displacement, velocity and acceleration at "
    'sample k-1 as the builder used them for f_r[k] (name: <dof>/displacement_m, ...).')


#: A rig's specimen model as its builder identifies it, sent to the builders of the other rigs
#: (``structure_builders: per_rig``; in the rig's namespace).
SPECIMEN_MODEL = '/seft/specimen_model'
#: seft's tools that publish on ``/seft/status`` beside the graph's nodes, any number of each
#: (a runner per host; ``seft_ros.cli.runner.RUNNER_NAME``, ``seft_ros.live.view.LIVE_NAME``).
TOOL_NODES = ('seft_runner', 'seft_live')
#: The node name the middleware gives a publisher whose node has not announced its name yet
#: (rmw's graph cache, a new process's first tens of ms).
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'


def qualified(node: str, rig: str = '') -> str:
    """The qualified name of `node` in the namespace of `rig` ('' : the root namespace)."""
    return f'{rig}/{node}' if rig else node


def split_qualified(name: str) -> tuple[str, str]:
    """``(rig, node)`` of a qualified node name (rig '' for the root namespace).

    Raises
    ------
    ParameterError
        Not a node of seft, or a namespace that is not a rig name.
    """
    rig, _, node = name.rpartition('/')
    if node not in parameters.NODES or (rig and not _NAME.match(rig)):
        raise ParameterError(f'node {name!r}: expected one of {", ".join(parameters.NODES)}, '
                             'or <rig>/force_servo_controller, <rig>/rig, '
                             '<rig>/reference_force_builder for a rig of a structure')
    return rig, node


def scoped(topic: str, rig: str = '') -> str:
    """A study topic in the namespace of `rig` (``/seft/x`` -> ``/<rig>/seft/x``)."""
    return f'/{rig}{topic}' if rig else topic


def _scoped_signal(signal: sig.Signal, rig: str, publisher: str | None = None) -> sig.Signal:
    return sig.Signal(scoped(signal.name, rig), signal.type_name, signal.field, signal.unit,
                      publisher or qualified(signal.publisher, rig), signal.description)


def _rig_of_topic(topic: str) -> str:
    """The rig of a topic in a rig's namespace (``/<rig>/seft/...``; '' for ``/seft/...``)."""
    head = topic.split('/')[1] if topic.count('/') >= 3 else ''
    return '' if head == 'seft' else head


def _rigs(params: Mapping[str, Any]) -> tuple[tuple[str, ...], dict[str, str]]:
    """The rigs of a run (in the structure's order of its physical DOFs) and their models."""
    text = params.get('structure', 'none')
    if text in (None, '', 'none'):
        return ('',), {'': params.get('rig_model', 'servohydraulic')}
    try:
        doc = json.loads(text)
        dofs = list(doc['dofs'])
        physical = dict(doc['physical'])
        overrides = dict(doc.get('rigs', {}))
    except (TypeError, ValueError, KeyError) as exc:
        raise ParameterError(f'parameter structure: expected the JSON of a structure ({exc})') \
            from None
    rigs = tuple(physical[d] for d in dofs if d in physical)
    models = {r: dict(overrides.get(r, {})).get('rig_model', params.get('rig_model',
                                                                         'servohydraulic'))
              for r in rigs}
    return rigs, models


@dataclass(frozen=True)
class Graph:
    """The nodes and topics of one run (module notes).

    Attributes
    ----------
    rigs : tuple of str
        The rigs, in the structure's order (``('',)``: the study's single rig in the root
        namespace).
    rig_models : mapping of str to str
        Rig -> its ``rig_model``.
    per_rig_builders : bool
        One builder per rig, in its namespace (``structure_builders: per_rig``).
    """

    rigs: tuple
    rig_models: Mapping[str, str]
    per_rig_builders: bool = False

    @classmethod
    def from_parameters(cls, params: Mapping[str, Any]) -> 'Graph':
        """The graph of a run from its parameters (``structure``, ``rig_model``,
        ``structure_builders``).

        Raises
        ------
        ParameterError
            A ``structure`` that is not a structure's JSON, or an unknown
            ``structure_builders``.
        """
        rigs, models = _rigs(params)
        layout = params.get('structure_builders', CENTRAL)
        if layout not in STRUCTURE_BUILDERS:
            raise ParameterError(f'parameter structure_builders={layout!r}: expected one of '
                                 + ', '.join(repr(b) for b in STRUCTURE_BUILDERS))
        return cls(rigs, models, layout == PER_RIG and rigs != ('',))

    @property
    def is_structure(self) -> bool:
        """Whether the run is a structure test (rigs in namespaces)."""
        return self.rigs != ('',)

    @property
    def master(self) -> str:
        """The clock master: the first rig's node (it publishes ``/clock``)."""
        return qualified('rig', self.rigs[0])

    def has_controller(self, rig: str) -> bool:
        """Whether `rig` has a force servo controller
        (:func:`~seft_msgs_py.parameters.graph_nodes`: not
        the delay rig, which takes the reference force)."""
        return 'force_servo_controller' in parameters.graph_nodes(self.rig_models[rig])

    def rig_nodes(self) -> tuple[str, ...]:
        """The rig nodes, in rig order."""
        return tuple(qualified('rig', r) for r in self.rigs)

    def controller_nodes(self) -> tuple[str, ...]:
        """The force servo controllers, in rig order."""
        return tuple(qualified('force_servo_controller', r) for r in self.rigs
                     if self.has_controller(r))

    def builder_nodes(self) -> tuple[str, ...]:
        """The reference-force builders (one, or one per rig)."""
        if self.per_rig_builders:
            return tuple(qualified('reference_force_builder', r) for r in self.rigs)
        return ('reference_force_builder',)

    def nodes(self) -> tuple[str, ...]:
        """The data nodes in start order (the rigs last; the recorder apart)."""
        return (('ground_motion_publisher',) + self.builder_nodes() + self.controller_nodes()
                + self.rig_nodes())

    def builder_of(self, rig: str) -> str:
        """The builder that commands `rig`."""
        return (qualified('reference_force_builder', rig) if self.per_rig_builders
                else 'reference_force_builder')

    def local_rigs(self, builder: str) -> tuple[str, ...]:
        """The rigs `builder` commands."""
        return tuple(r for r in self.rigs if self.builder_of(r) == builder)

    def rig_of(self, node: str) -> str | None:
        """The rig of a namespaced node ('' for the study's rig), None for a global node."""
        rig, kind = split_qualified(node)
        if kind in RIG_NODES or (kind == 'reference_force_builder' and self.per_rig_builders):
            return rig
        return None

    # -- topics -----------------------------------------------------------------------------

    def measurement(self, rig: str) -> sig.Signal:
        """The live measurement topic of `rig`."""
        return _scoped_signal(sig.MEASUREMENT, rig)

    def reference_force(self, rig: str) -> sig.Signal:
        """The reference force of `rig` (published by its builder)."""
        return _scoped_signal(sig.REFERENCE_FORCE, rig, self.builder_of(rig))

    def estimates(self, rig: str) -> sig.Signal:
        """The compensator's online estimates of `rig` (published by its builder)."""
        return _scoped_signal(sig.ESTIMATES, rig, self.builder_of(rig))

    def valve_command(self, rig: str) -> sig.Signal:
        """The valve command of `rig` (published by its controller)."""
        return _scoped_signal(sig.VALVE_COMMAND, rig)

    def sensors(self, rig: str) -> tuple[sig.Signal, ...]:
        """The bag's four sensor topics of `rig`."""
        return tuple(_scoped_signal(s, rig) for s in (sig.MEASURED_FORCE, sig.DISPLACEMENT,
                                                      sig.VELOCITY, sig.ACCELERATION))

    def record_streams(self) -> tuple[sig.RecordStream, ...]:
        """Every record stream of the graph (data first, then timing, then fields)."""
        if not self.is_structure:
            return sig.RECORD_STREAMS
        out = [sig.RecordStream('/seft/record/ground_motion_publisher',
                                'ground_motion_publisher', (sig.GROUND_ACCELERATION.name,))]
        for builder in self.builder_nodes():
            rig = self.rig_of(builder) or ''
            out.append(sig.RecordStream(
                scoped('/seft/record/reference_force_builder', rig), builder,
                tuple(self.reference_force(r).name for r in self.local_rigs(builder))))
        for r in self.rigs:
            out.append(sig.RecordStream(scoped('/seft/record/rig', r), qualified('rig', r),
                                        tuple(s.name for s in self.sensors(r))))
            if self.has_controller(r):
                out.append(sig.RecordStream(
                    scoped('/seft/record/force_servo_controller', r),
                    qualified('force_servo_controller', r), (self.valve_command(r).name,)))
        for node in self.nodes():
            rig, kind = split_qualified(node)
            out.append(sig.RecordStream(scoped(f'/seft/record/{kind}/timing', rig), node,
                                        sig.TIMING_FIELDS, timing=True))
        for builder in self.builder_nodes():
            rig = self.rig_of(builder) or ''
            out.append(sig.RecordStream(
                scoped('/seft/record/reference_force_builder/structure', rig), builder, (),
                fields_topic=scoped(STRUCTURE_STATE.name, rig)))
        for r in self.rigs:
            out.append(sig.RecordStream(
                scoped('/seft/record/reference_force_builder/estimates', r), self.builder_of(r),
                (), fields_topic=self.estimates(r).name))
        return tuple(out)

    def record_streams_of(self, node: str) -> tuple[sig.RecordStream, ...]:
        """The record streams a node publishes (data first, then timing, then fields)."""
        return tuple(r for r in self.record_streams() if r.node == node)

    def timing_topic(self, stream: sig.RecordStream) -> str:
        """The bag topic of a timing stream's rows (``/[<rig>]/seft/timing/<node>``)."""
        rig, kind = split_qualified(stream.node)
        return scoped(f'/seft/timing/{kind}', rig)

    def bag_signals(self) -> tuple[sig.Signal, ...]:
        """What the recorder writes into the bag."""
        if not self.is_structure:
            return sig.BAG_SIGNALS
        out = [sig.GROUND_ACCELERATION]
        for r in self.rigs:
            out.append(self.reference_force(r))
            if self.has_controller(r):
                out.append(self.valve_command(r))
            out.extend(self.sensors(r))
        out += [sig.STATUS, sig.RUN_PARAMETERS, sig.NODE_PARAMETERS]
        for stream in self.record_streams():
            if stream.timing:
                out.append(sig.Signal(self.timing_topic(stream), sig.TIMING_TYPE, 'position',
                                      's', stream.node, sig.timing_signal(
                                          split_qualified(stream.node)[1]).description))
            elif stream.fields_topic.endswith(STRUCTURE_STATE.name):
                out.append(_scoped_signal(STRUCTURE_STATE, self.rig_of(stream.node) or '',
                                          stream.node))
            elif stream.fields_topic:
                out.append(self.estimates(_rig_of_topic(stream.fields_topic)))
        return tuple(out)

    def specimen_model(self, rig: str) -> str:
        """The topic of `rig`'s specimen model (:data:`SPECIMEN_MODEL`, in its namespace)."""
        return scoped(SPECIMEN_MODEL, rig)

    def command_topics(self) -> tuple[str, ...]:
        """The topics whose messages end up in a command to a rig: each rig's measurement,
        reference force, valve command and (per-rig builders) specimen model, and the ground
        motion's record batches that the builders read."""
        out = [self.record_streams_of('ground_motion_publisher')[0].name]
        for r in self.rigs:
            out += [self.measurement(r).name, self.reference_force(r).name]
            if self.has_controller(r):
                out.append(self.valve_command(r).name)
            if self.per_rig_builders:
                out.append(self.specimen_model(r))
        return tuple(out)

    def publishers_of(self, topic: str) -> tuple[str, ...]:
        """The nodes of the run that publish `topic` (qualified names, one entry per
        publisher; ``()`` for a topic of no node of the graph).

        ``/seft/status`` and ``/seft/node_parameters``: every node and the recorder (the
        status also :data:`TOOL_NODES`, which :meth:`foreign_publishers` allows any number
        of); ``/clock``: the clock master; ``/seft/run_parameters``: the recorder."""
        for r in self.rigs:
            if topic == self.measurement(r).name:
                return (qualified('rig', r),)
            if topic == self.reference_force(r).name:
                return (self.builder_of(r),)
            if topic == self.valve_command(r).name:
                return (qualified('force_servo_controller', r),) if self.has_controller(r) \
                    else ()
            if topic == self.specimen_model(r):
                return (self.builder_of(r),) if self.per_rig_builders else ()
        for stream in self.record_streams():
            if topic == stream.name:
                return (stream.node,)
        if topic == sig.CLOCK.name:
            return (self.master,)
        if topic in (sig.STATUS.name, sig.NODE_PARAMETERS.name):
            return self.nodes() + ('recorder',)
        if topic == sig.RUN_PARAMETERS.name:
            return ('recorder',)
        return ()

    def foreign_publishers(self, topic: str, found) -> list[str]:
        """The publishers of `topic` that are not the run's, named.

        Parameters
        ----------
        topic : str
        found : iterable of (node name, namespace, gid)
            The publishers the middleware knows of (``get_publishers_info_by_topic``: its
            ``node_name``, ``node_namespace``, ``endpoint_gid``).

        Returns
        -------
        list of str
            One entry per foreign publisher: ``"'<qualified name>' (gid <hex>)"`` (a node
            that has not announced its name yet, :data:`UNKNOWN_NODE`: by its gid alone, where
            there are more of them than publishers of the run not seen by name);
            where more publishers bear a name of the run than it has (a sender that took a
            node's name), every one of that name, with how many the run has: there is no
            telling which is the run's.
        """
        expected: dict[str, int] = {}
        for name in self.publishers_of(topic):
            expected[name] = expected.get(name, 0) + 1
        by_name: dict[str, list[str]] = {}
        unnamed = []
        for node, namespace, gid in found:
            if node == UNKNOWN_NODE:
                unnamed.append(bytes(gid).hex()[:24])
                continue
            name = qualified(node, str(namespace).strip('/'))
            by_name.setdefault(name, []).append(bytes(gid).hex()[:24])
        # a publisher whose node has not announced its name may be one of the run's not yet
        # seen by name: as many are taken for those, the others are foreign
        missing = sum(max(0, n - len(by_name.get(name, ()))) for name, n in expected.items())
        out = [f'a node not named yet (gid {g}: a process outside the run)'
               for g in unnamed[missing:]]
        for name, gids in sorted(by_name.items()):
            allowed = expected.get(name, 0)
            if topic == sig.STATUS.name and name in TOOL_NODES:
                continue
            if len(gids) > allowed and allowed:
                out.append(f"{len(gids)} publishers named '{name}' (gid {', '.join(gids)}; "
                           f'the run has {allowed})')
            elif len(gids) > allowed:
                out += [f"'{name}' (gid {g})" for g in gids]
        return out

    def complete_step_topics(self) -> tuple[str, ...]:
        """The bag topics that make a step complete (every sample signal of every rig)."""
        out = [sig.GROUND_ACCELERATION.name]
        for r in self.rigs:
            out += [s.name for s in self.sensors(r)] + [self.reference_force(r).name]
            if self.has_controller(r):
                out.append(self.valve_command(r).name)
        return tuple(out)
