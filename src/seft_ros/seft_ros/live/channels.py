"""What the live view shows of a run: its channels, where each value comes from, its plots.

Imports no rclpy and no Foxglove: the node (:mod:`seft_ros.live.node`) hands it the rows of
the record batches the graph's nodes publish for the recorder
(:class:`seft_msgs_py.signals.RecordStream`), the Foxglove server and the web page take the
channels from it.

**Channels.** Each one is a JSON object per shown sample, ``{"step": k, "t_s": k*dt,
<field>: value, ...}``, on a topic in the namespace of its rig (``/seft/live/...`` for the
study's single rig, ``/<rig>/seft/live/...`` for a rig of a structure, as the graph's own
topics):

====================================  =========================================================
topic                                 fields
====================================  =========================================================
``seft/live/measurement``             ``measured_force_N``, ``displacement_m``,
                                      ``velocity_m_s``, ``acceleration_m_s2`` (the rig's)
``seft/live/reference_force``         ``reference_force_N`` (the builder's f_r of the rig)
``seft/live/valve_command``           ``valve_command_V`` (the force servo controller's)
``seft/live/analytical``              ``displacement_m``, ``acceleration_m_s2``, ``force_N``:
                                      the whole structure's response (one rig, known record)
``seft/live/timing/<node>``           the node's timing record (``signals.TIMING_FIELDS``),
                                      ``missed_deadlines`` and ``stale_inputs`` since the start
                                      and ``loop_latency_max_s`` since the last shown sample
``/seft/live/ground_acceleration``    ``ground_acceleration_m_s2``
``/seft/live/dof/<dof>``              ``displacement_m`` of a DOF of a structure (physical:
                                      the rig's; computational: the builder's integration,
                                      the first rig's builder's with one per rig)
``/seft/live/run``                    the run's state (:mod:`seft_ros.live.view`)
``/seft/live/events``                 the safety events (``foxglove.Log``)
``/seft/live/link``                   per host: round trip p50/p99/max [ms], clock offset
                                      [ms] (a run over several hosts)
====================================  =========================================================

Series of the web page are named ``<topic>.<field>``, Foxglove's message path of the value.

**Decimation.** A sample is shown when its step is a multiple of ``decimation(dt, rate_hz)``
(10 at dt = 2 ms for 50 Hz): every channel shows the same steps, so the reference force,
the measured force and the analytical response of one instant line up; the values are the
recorded ones, unchanged. The timing totals count every sample, shown or not.
"""

from dataclasses import dataclass, field
import json
from typing import Any, Mapping

from seft_msgs_py import signals as sig
from seft_msgs_py.graph import STRUCTURE_STATE, Graph, scoped, split_qualified

__all__ = ['RunChannels', 'Source', 'Plot', 'decimation', 'MEASUREMENT', 'REFERENCE_FORCE',
           'VALVE_COMMAND', 'ANALYTICAL', 'GROUND_ACCELERATION', 'RUN', 'EVENTS', 'LINK',
           'TIMING_TOTALS', 'DISPLAY_RATE_HZ', 'timing_channel', 'dof_channel']

#: Default display rate of the live view [Hz].
DISPLAY_RATE_HZ = 50.0

MEASUREMENT = '/seft/live/measurement'
REFERENCE_FORCE = '/seft/live/reference_force'
VALVE_COMMAND = '/seft/live/valve_command'
ANALYTICAL = '/seft/live/analytical'
GROUND_ACCELERATION = '/seft/live/ground_acceleration'
RUN = '/seft/live/run'
EVENTS = '/seft/live/events'
LINK = '/seft/live/link'
#: The analytical response's fields (``analysis.reference.ReferenceResponse``).
ANALYTICAL_FIELDS = ('displacement_m', 'acceleration_m_s2', 'force_N')
#: Fields a timing channel adds to ``signals.TIMING_FIELDS``.
TIMING_TOTALS = ('missed_deadlines', 'stale_inputs', 'loop_latency_max_s')


def decimation(dt: float, rate_hz: float = DISPLAY_RATE_HZ) -> int:
    """Every how many steps a sample is shown: ``max(1, round(1 / (rate_hz dt)))``.

    Parameters
    ----------
    dt : float > 0
        Control period [s].
    rate_hz : float > 0
        Display rate [Hz].
    """
    return max(1, int(round(1.0 / (rate_hz * dt))))


def timing_channel(node: str) -> str:
    """The timing channel of a node (qualified name ``[<rig>/]<node>``)."""
    rig, kind = split_qualified(node)
    return scoped(f'/seft/live/timing/{kind}', rig)


def dof_channel(dof: str) -> str:
    """The displacement channel of a structure's DOF."""
    return f'/seft/live/dof/{dof}'


@dataclass(frozen=True)
class Source:
    """One record stream as the live view reads it.

    Attributes
    ----------
    stream : RecordStream
        The stream (its live topic: ``stream.name``).
    targets : tuple of tuple
        Per column after the step: ``((channel, field), ...)``, the places its value goes
        (empty: not shown). A fields stream (``stream.fields_topic``) names its columns in
        each batch: its targets are found by :meth:`RunChannels.fields_targets`.
    """

    stream: sig.RecordStream
    targets: tuple = ()


@dataclass(frozen=True)
class Plot:
    """A plot of the web page: a title, a unit, and the series drawn in it.

    Attributes
    ----------
    title : str
    unit : str
        Unit of the y axis as drawn.
    scale : float
        Factor from the SI value to the drawn unit (1e-3 for kN, 1e3 for mm and ms).
    series : tuple of (key, label, style)
        Series key (``<channel>.<field>``), legend label, and 'test', 'command' or
        'reference' (the analytical response, drawn dashed, ahead of the test).
    """

    title: str
    unit: str
    scale: float
    series: tuple

    def as_dict(self) -> dict:
        """JSON form for the web page."""
        return {'title': self.title, 'unit': self.unit, 'scale': self.scale,
                'series': [{'key': k, 'label': lb, 'style': st} for k, lb, st in self.series]}


@dataclass
class RunChannels:
    """The channels, sources and plots of one run, from its resolved parameters.

    Parameters
    ----------
    params : mapping
        The run's parameters (``/seft/run_parameters``).
    rate_hz : float > 0
        Display rate [Hz].

    Raises
    ------
    ParameterError
        A ``structure`` that is not a structure's JSON (``Graph.from_parameters``).
    """

    params: Mapping[str, Any]
    rate_hz: float = DISPLAY_RATE_HZ
    graph: Graph = field(init=False)
    dt: float = field(init=False)
    decimation: int = field(init=False)
    #: Structure: DOF -> its rig (physical DOFs only).
    physical: dict = field(init=False)
    #: Structure: the DOFs in order (empty for the study).
    dofs: tuple = field(init=False)
    #: Channel -> its numeric fields (after step and t_s), in order.
    fields: dict = field(init=False)
    sources: tuple = field(init=False)

    def __post_init__(self):
        self.graph = Graph.from_parameters(self.params)
        self.dt = float(self.params['dt'])
        self.decimation = decimation(self.dt, self.rate_hz)
        self.dofs, self.physical = (), {}
        if self.graph.is_structure:
            doc = json.loads(self.params['structure'])
            self.dofs = tuple(doc['dofs'])
            self.physical = {d: r for d, r in dict(doc['physical']).items() if d in self.dofs}
        self.fields = {}
        by_column = {sig.GROUND_ACCELERATION.name: [(GROUND_ACCELERATION,
                                                     'ground_acceleration_m_s2')]}
        for rig in self.graph.rigs:
            by_column[self.graph.reference_force(rig).name] = [
                (scoped(REFERENCE_FORCE, rig), 'reference_force_N')]
            by_column[self.graph.valve_command(rig).name] = [
                (scoped(VALVE_COMMAND, rig), 'valve_command_V')]
            for signal, name in zip(self.graph.sensors(rig), sig.MEASUREMENT_FIELDS):
                by_column[signal.name] = [(scoped(MEASUREMENT, rig), name)]
        for dof, rig in self.physical.items():
            by_column[scoped(sig.DISPLACEMENT.name, rig)].append((dof_channel(dof),
                                                                  'displacement_m'))
        sources = []
        for stream in self.graph.record_streams():
            if stream.timing:
                if not self.realtime:
                    continue              # lockstep: no node times its steps
                channel = timing_channel(stream.node)
                targets = tuple(((channel, f),) for f in sig.TIMING_FIELDS)
            elif stream.fields_topic:
                targets = ()
                if not stream.fields_topic.endswith(STRUCTURE_STATE.name):
                    continue              # the compensator's estimates: not shown
                if stream.node != self.graph.builder_nodes()[0]:
                    continue              # per-rig builders' replicas: the first one's shown
                for dof in self.dofs:
                    if dof not in self.physical:
                        self.fields[dof_channel(dof)] = ['displacement_m']
            else:
                targets = tuple(tuple(by_column.get(c, ())) for c in stream.columns)
            for places in targets:
                for channel, name in places:
                    self.fields.setdefault(channel, [])
                    if name not in self.fields[channel]:
                        self.fields[channel].append(name)
            sources.append(Source(stream, targets))
        for stream in sources:
            if stream.stream.timing:
                self.fields[timing_channel(stream.stream.node)] += list(TIMING_TOTALS)
        self.sources = tuple(sources)

    @property
    def realtime(self) -> bool:
        """Whether the run is in real time (timing channels carry data)."""
        return self.params.get('mode') == 'realtime'

    def fields_targets(self, columns) -> tuple:
        """The targets of a structure-state batch's columns (``<dof>/displacement_m``, ...):
        the computational DOFs' displacements."""
        out = []
        for c in columns:
            dof, _, quantity = c.partition('/')
            shown = quantity == 'displacement_m' and dof in self.dofs \
                and dof not in self.physical
            out.append(((dof_channel(dof), 'displacement_m'),) if shown else ())
        return tuple(out)

    def add_analytical(self, rig: str = '') -> None:
        """Declare the analytical channel of `rig` (one-rig tests with a reference)."""
        self.fields[scoped(ANALYTICAL, rig)] = list(ANALYTICAL_FIELDS)

    def plots(self) -> list[Plot]:
        """The web page's plots: per rig its force, displacement, acceleration and valve
        command (with the analytical response where there is one), a structure's DOF
        displacements, and in real time the rigs' loop latency."""
        out = []
        for rig in self.graph.rigs:
            name = f' ({rig})' if rig else ''
            meas, ana = scoped(MEASUREMENT, rig), scoped(ANALYTICAL, rig)
            has_ana = ana in self.fields
            ref = ((f'{ana}.force_N', 'analytical', 'reference'),) if has_ana else ()
            out.append(Plot(f'Force{name}', 'kN', 1e-3, (
                (f'{scoped(REFERENCE_FORCE, rig)}.reference_force_N', 'reference f_r',
                 'command'),
                (f'{meas}.measured_force_N', 'measured f_m', 'test')) + ref))
            for title, fname, unit, scale in (('Displacement', 'displacement_m', 'mm', 1e3),
                                              ('Acceleration', 'acceleration_m_s2', 'm/s²',
                                               1.0)):
                ref = ((f'{ana}.{fname}', 'analytical', 'reference'),) if has_ana else ()
                out.append(Plot(f'{title}{name}', unit, scale,
                                ((f'{meas}.{fname}', 'test', 'test'),) + ref))
            if self.graph.has_controller(rig):
                out.append(Plot(f'Valve command{name}', 'V', 1.0, (
                    (f'{scoped(VALVE_COMMAND, rig)}.valve_command_V', 'u', 'command'),)))
        if self.dofs:
            out.append(Plot('Displacement of each DOF', 'mm', 1e3, tuple(
                (f'{dof_channel(d)}.displacement_m', d, 'test') for d in self.dofs)))
        if self.realtime:
            out.append(Plot('Loop latency', 'ms', 1e3, tuple(
                (f'{timing_channel(r)}.loop_latency_s', r, 'test')
                for r in self.graph.rig_nodes())))
        return out
