"""The live view's state of a run: the shown samples, the run's state and its events.

Imports no rclpy and no Foxglove. The node (:mod:`seft_ros.live.node`) feeds it from its
subscriptions (one thread); the web server (:mod:`seft_ros.live.web`) reads it from another
(:meth:`LiveView.snapshot`, :meth:`LiveView.delta`), and every shown sample also goes to the
sinks (the Foxglove server, :mod:`seft_ros.live.foxglove_sink`) as it comes.

**The run's state** (``/seft/live/run`` and the page's status line), from the nodes'
``/seft/status`` reports: ``waiting`` (no run yet), ``starting`` (the recorder published the
run's parameters), ``running`` (the clock master reported running), then, once every rig has
sent its final report, ``done`` when all ended done, else the state of the first rig that did
not (``aborted`` or ``failed``) with its reason; when the bag closes first (a rig or its link
lost), the state of the final reports that came. Every ``aborted`` or ``failed`` report of any
node is a safety event (a node's interlock, a watchdog, a stopped node, the runner, the
operator's stop), with the node, the reason and the sample time.
"""

import math
import threading
import time
from typing import Any, Callable, Mapping, Protocol, Sequence

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.graph import qualified
from seft_msgs_py.sensor_range import SensorRanges, channel_names
from seft_msgs_py.signals import (
    FINAL_STATES,
    STATE_ABORTED,
    STATE_CLOSED,
    STATE_DONE,
    STATE_FAILED,
    STATE_RUNNING,
    TIMING_FIELDS,
)
from seft_ros.live import channels as ch

__all__ = ['LiveView', 'Sink', 'RunStatus', 'LIVE_NAME']

#: Name of the live view's own reports on /seft/status (the operator's stop).
LIVE_NAME = 'seft_live'
#: Events kept for the page (the oldest are dropped; every one goes to the sinks).
MAX_EVENTS = 50
_MISSED = TIMING_FIELDS.index('missed_deadline')
_STALE = TIMING_FIELDS.index('stale')
_LATENCY = TIMING_FIELDS.index('loop_latency_s')


class Sink(Protocol):
    """Where the shown samples go as they come (the Foxglove server)."""

    def new_run(self, fields: Mapping[str, Sequence[str]]) -> None:
        """A new run: its channels and their numeric fields (``RunChannels.fields``)."""

    def log(self, channel: str, message: dict, log_time_ns: int) -> None:
        """One shown sample, or the run's state, or the link figures."""

    def event(self, level: str, node: str, message: str, log_time_ns: int) -> None:
        """A safety event or a run's start and end (level 'info', 'warning' or 'error')."""


def _finite(value: float):
    value = float(value)
    return value if math.isfinite(value) else None


class RunStatus:
    """The state of one run from the nodes' status reports (module notes).

    Parameters
    ----------
    rigs : sequence of str
        The rig nodes (qualified names); the first is the clock master.
    mode : str
        'lockstep' or 'realtime'.
    """

    def __init__(self, rigs: Sequence[str] = (), mode: str = ''):
        self.rigs = tuple(rigs)
        self.mode = mode
        self.state = 'starting' if self.rigs else 'waiting'
        self.step = 0
        self.n_steps = 0
        self.time_s = 0.0
        self.reason = ''
        self.finals: dict[str, tuple[str, str]] = {}
        self.events: list[dict] = []
        self.closed = False
        self.lost = None
        self.missed: dict[str, int] = {}
        self.stale: dict[str, int] = {}
        self.link: dict[str, dict] = {}
        self.stopped_by = ''
        #: rig -> channel -> the samples read at the sensor's range so far (issue 39)
        self.at_range: dict[str, dict[str, int]] = {}

    def update(self, name: str, message: str, values: Mapping[str, str]) -> list[dict]:
        """Take one status report; return the events it makes (possibly none)."""
        state = values.get('state')
        events = []
        if name in self.rigs:
            if 'n_steps' in values and int(values['n_steps']) > 0:
                self.n_steps = int(values['n_steps'])
            if 'step' in values:
                self.step = max(self.step, int(values['step']))
            if 'time_s' in values:
                self.time_s = max(self.time_s, float(values['time_s']))
        if name == (self.rigs[0] if self.rigs else None) and state == STATE_RUNNING \
                and self.state == 'starting':
            self.state = 'running'
            events.append(self._event('info', name, f'run started ({self.mode}, '
                                      f'{self.n_steps} steps)'))
        if state in FINAL_STATES:
            for key, into in (('missed_deadlines', self.missed), ('stale', self.stale)):
                if key in values:
                    into[name] = int(values[key])
            if state != STATE_DONE:
                events.append(self._event('error', name, f'{state}: {message}'))
            if name in self.rigs and name not in self.finals:
                self.finals[name] = (state, message)
                if set(self.rigs) <= set(self.finals):
                    ended = [f for f in (self.finals[r] for r in self.rigs)
                             if f[0] != STATE_DONE]
                    self.state, self.reason = ended[0] if ended else (STATE_DONE, '')
                    events.append(self._event(
                        'info' if not ended else 'error', name,
                        f'run {self.state}' + (f': {self.reason}' if self.reason else '')))
        if values.get('warning') and state not in FINAL_STATES:
            # what a builder says during the run: a sensor at its range, a specimen that is
            # not the declared one
            events.append(self._event('warning', name, values['warning']))
        if state in (STATE_ABORTED, STATE_FAILED) and values.get('stopped_by') == 'operator':
            self.stopped_by = message
        if name == 'recorder' and state == STATE_CLOSED:
            self.closed = True
            self.lost = int(values['lost']) if 'lost' in values else None
            if self.state in ('starting', 'running'):
                # the bag closed without some rig's final report (a rig or its link lost):
                # the end is what the reports that came say
                missing = [r for r in self.rigs if r not in self.finals]
                ended = [f for f in self.finals.values() if f[0] != STATE_DONE]
                self.state, self.reason = ended[0] if ended else (
                    STATE_ABORTED, 'the bag closed without the final report of '
                    + ', '.join(missing))
                events.append(self._event('error', name, f'run {self.state}: {self.reason}'))
        return events

    def _event(self, level: str, node: str, message: str) -> dict:
        event = {'level': level, 'node': node, 'message': message,
                 't_s': round(self.time_s, 6)}
        self.events = (self.events + [event])[-MAX_EVENTS:]
        return event

    def as_dict(self) -> dict:
        """JSON form (``/seft/live/run``, the page's status line)."""
        return {'state': self.state, 'step': self.step, 'n_steps': self.n_steps,
                't_s': round(self.time_s, 6), 'mode': self.mode, 'reason': self.reason,
                'bag_closed': self.closed, 'lost': self.lost,
                'missed_deadlines': dict(self.missed), 'stale_inputs': dict(self.stale),
                'link': dict(self.link), 'stopped_by': self.stopped_by,
                'at_range': {r: dict(c) for r, c in self.at_range.items()}}


class LiveView:
    """The shown samples, the analytical reference and the state of the current run.

    Parameters
    ----------
    rate_hz : float > 0
        Display rate [Hz] (:func:`~seft_ros.live.channels.decimation`).
    sinks : sequence of Sink
        Receive every shown sample, state and event as they come.
    reference : callable(params) -> dict or None, optional
        The analytical response of a run ahead of it: ``{field: array (n,)}`` with the
        fields of ``channels.ANALYTICAL_FIELDS`` [SI units] at every step, or None where
        it cannot be computed (:func:`seft_ros.live.reference.analytical`).
    stop_enabled : bool
        The page offers the operator's stop (``seft run --live-stop``).
    """

    def __init__(self, rate_hz: float = ch.DISPLAY_RATE_HZ, sinks: Sequence[Sink] = (),
                 reference: Callable[[Mapping[str, Any]], dict | None] | None = None,
                 stop_enabled: bool = False):
        self.rate_hz = rate_hz
        self.sinks = list(sinks)
        self.reference_of = reference
        self.params: dict = {}
        self.stop_enabled = stop_enabled
        self.lock = threading.Lock()
        self.run: ch.RunChannels | None = None
        self.run_id = 0
        self.run_key = None
        self.info: dict = {}
        self.status = RunStatus()
        self.status_version = 0
        self.series: dict[str, tuple[list, list]] = {}
        self.reference: dict[str, list] = {}
        self.sources: dict = {}
        self.totals: dict[str, list] = {}
        self.ranges: dict[str, tuple] = {}
        self.base_ns = time.time_ns()
        self.latest_step = 0

    # -- the node's side ------------------------------------------------------------------

    def new_run(self, params: Mapping[str, Any]) -> bool:
        """A run's parameters (``/seft/run_parameters``); True when it is a new run (its bag
        path differs from the current one's), which then replaces the current run. Its
        analytical reference comes after, from :meth:`add_reference` (the node subscribes to
        the run's batches first: a lockstep run may be over in a second).

        Raises
        ------
        ParameterError
            Parameters whose graph cannot be made (``channels.RunChannels``).
        """
        key = (params.get('bag_path'), params.get('alpha'), params.get('predictor'))
        if key == self.run_key:
            return False
        run = ch.RunChannels(params, self.rate_hz)
        with self.lock:
            self.run, self.run_key, self.params = run, key, dict(params)
            self.run_id += 1
            self.base_ns = time.time_ns()
            self.latest_step = 0
            self.series = {f'{c}.{f}': ([], []) for c, fields in run.fields.items()
                           for f in fields}
            self.sources = {s.stream.name: s for s in run.sources}
            self.totals = {ch.timing_channel(s.stream.node): [0, 0, 0.0]
                           for s in run.sources if s.stream.timing}
            self.ranges = _rig_ranges(run, params)
            self.reference = {}
            self.status = RunStatus(run.graph.rig_nodes(), str(params.get('mode', '')))
            self.info = {
                'label': _label(params), 'mode': params.get('mode'),
                'dt': run.dt, 'decimation': run.decimation, 'rate_hz': self.rate_hz,
                'rigs': [r for r in run.graph.rigs], 'dofs': list(run.dofs),
                'bag_path': params.get('bag_path'), 'alpha': params.get('alpha'),
                'predictor': params.get('predictor'), 'rig_model': params.get('rig_model'),
                'record': str(params.get('record'))}
            self.status_version += 1
        for sink in self.sinks:
            sink.new_run(run.fields)
        self._emit_state()
        return True

    def add_reference(self) -> bool:
        """Compute the current run's analytical reference (``reference`` of the
        constructor) and show it: the pages get it with a new ``hello``, the sinks a new
        channel. True if there is one."""
        run = self.run
        if run is None or self.reference_of is None:
            return False
        reference = self.reference_of(self.params)
        if reference is None:
            return False
        d = run.decimation
        shown = {f'{ch.ANALYTICAL}.{f}': [_finite(v) for v in reference[f][::d]]
                 for f in ch.ANALYTICAL_FIELDS}
        with self.lock:
            if run is not self.run:
                return False
            run.add_analytical()
            self.reference = shown
            self.status.n_steps = self.status.n_steps or len(
                reference[ch.ANALYTICAL_FIELDS[0]])
            self.run_id += 1                     # the pages take it with a new hello
            self.status_version += 1
        for sink in self.sinks:
            sink.new_run(run.fields)
        return True

    def on_batch(self, stream: str, columns: Sequence[str], data: Sequence[float]) -> None:
        """The rows of one record batch (``data``: step then the columns, row-major): the
        shown ones go to the series and the sinks; a timing batch adds every row to its
        totals."""
        run = self.run
        source = self.sources.get(stream)
        if run is None or source is None:
            return
        targets = (run.fields_targets(columns) if source.stream.fields_topic
                   else source.targets)
        width = 1 + len(columns)
        decim, dt = run.decimation, run.dt
        timing = ch.timing_channel(source.stream.node) if source.stream.timing else None
        totals = self.totals.get(timing)
        ranges = self.ranges.get(stream)
        counted = {}
        shown = []
        for i in range(0, len(data) - width + 1, width):
            step = int(data[i])
            if ranges is not None:
                flags = ranges[1].flags_of(*data[i + 1:i + 5])
                for c in channel_names(flags):
                    counted[c] = counted.get(c, 0) + 1
            if totals is not None:
                totals[0] += int(data[i + 1 + _MISSED])
                totals[1] += int(data[i + 1 + _STALE])
                latency = data[i + 1 + _LATENCY]
                if latency == latency:           # not nan
                    totals[2] = max(totals[2], float(latency))
            if step % decim:
                continue
            messages: dict[str, dict] = {}
            for j, places in enumerate(targets):
                for channel, name in places:
                    msg = messages.setdefault(channel, {'step': step,
                                                        't_s': round(step * dt, 9)})
                    msg[name] = _finite(data[i + 1 + j])
            if totals is not None and timing in messages:
                messages[timing].update(missed_deadlines=totals[0], stale_inputs=totals[1],
                                        loop_latency_max_s=totals[2])
                totals[2] = 0.0
            shown.append((step, messages))
        if counted:
            with self.lock:
                if run is not self.run:
                    return
                rig = self.status.at_range.setdefault(ranges[0], {})
                for c, n in counted.items():
                    rig[c] = rig.get(c, 0) + n
                self.status_version += 1
            self._emit_state()
        if not shown:
            return
        with self.lock:
            if run is not self.run:
                return
            for step, messages in shown:
                self.latest_step = max(self.latest_step, step)
                for channel, msg in messages.items():
                    for name, value in msg.items():
                        series = self.series.get(f'{channel}.{name}')
                        if series is not None:
                            series[0].append(step)
                            series[1].append(value)
        for step, messages in shown:
            log_time = self.base_ns + int(round(step * dt * 1e9))
            for channel, msg in messages.items():
                for sink in self.sinks:
                    sink.log(channel, msg, log_time)
                if self.reference and channel == ch.MEASUREMENT:
                    k = step // decim
                    values = {f: self.reference[f'{ch.ANALYTICAL}.{f}'][k]
                              for f in ch.ANALYTICAL_FIELDS
                              if k < len(self.reference[f'{ch.ANALYTICAL}.{f}'])}
                    if values:
                        for sink in self.sinks:
                            sink.log(ch.ANALYTICAL, {'step': step, 't_s': msg['t_s'],
                                                     **values}, log_time)

    def on_status(self, name: str, message: str, values: Mapping[str, str]) -> None:
        """One ``/seft/status`` report."""
        with self.lock:
            before = self.status.as_dict()
            events = self.status.update(name, message, values)
            changed = events or self.status.as_dict() != before
            if changed:
                self.status_version += 1
        for event in events:
            for sink in self.sinks:
                sink.event(event['level'], event['node'], event['message'], self._now_ns())
        if changed:
            self._emit_state()

    def on_link(self, doc: Mapping[str, Any]) -> None:
        """The runners' link figures (``/seft/link``, JSON): per host its round trip p50,
        p99 and max [ms] and its clock offset [ms]."""
        links = {}
        for peer, link in dict(doc.get('links') or {}).items():
            rtt = dict(link.get('round_trip_ms') or {})
            links[str(peer)] = {
                'round_trip_p50_ms': _finite(rtt.get('p50', math.nan)),
                'round_trip_p99_ms': _finite(rtt.get('p99', math.nan)),
                'round_trip_max_ms': _finite(rtt.get('max', math.nan)),
                'offset_ms': _finite(link.get('offset_ms', math.nan))}
        with self.lock:
            self.status.link = links
            self.status_version += 1
        for peer, figures in links.items():
            for sink in self.sinks:
                sink.log(ch.LINK, {'host': peer, 'reference': str(doc.get('reference', '')),
                                   **figures}, self._now_ns())
        self._emit_state()

    def _now_ns(self) -> int:
        """The log time of a report: the run's start plus the latest shown sample time."""
        dt = self.run.dt if self.run else 0.0
        return self.base_ns + int(round(self.latest_step * dt * 1e9))

    def _emit_state(self) -> None:
        state = dict(self.status.as_dict(), label=self.info.get('label', ''))
        for sink in self.sinks:
            sink.log(ch.RUN, state, self._now_ns())

    # -- the web server's side ------------------------------------------------------------

    def snapshot(self) -> tuple[dict, tuple]:
        """Everything a new page needs (``type: hello``) and its cursor for :meth:`delta`."""
        with self.lock:
            run = self.run
            msg = {'type': 'hello', 'run_id': self.run_id, 'run': dict(self.info),
                   'plots': [p.as_dict() for p in run.plots()] if run else [],
                   'reference': {k: list(v) for k, v in self.reference.items()},
                   'series': {k: [list(s), list(v)] for k, (s, v) in self.series.items()},
                   'status': self.status.as_dict(), 'events': list(self.status.events),
                   'stop': self.stop_enabled}
            cursor = (self.run_id, {k: len(s) for k, (s, _) in self.series.items()},
                      self.status_version)
        return msg, cursor

    def delta(self, cursor: tuple) -> tuple[dict | None, tuple]:
        """What is new since `cursor`: ``type: data`` with the new points per series and
        the status if it changed, a ``hello`` if a new run began, or None (nothing new)."""
        run_id, lengths, version = cursor
        if run_id != self.run_id:
            return self.snapshot()
        with self.lock:
            new = {}
            for key, (steps, values) in self.series.items():
                n = lengths.get(key, 0)
                if len(steps) > n:
                    new[key] = [steps[n:], values[n:]]
                    lengths = dict(lengths, **{key: len(steps)})
            changed = self.status_version != version
            msg = {'type': 'data', 'run_id': self.run_id, 'series': new}
            if changed:
                msg.update(status=self.status.as_dict(), events=list(self.status.events))
            cursor = (self.run_id, lengths, self.status_version)
        return (msg if new or changed else None), cursor


def _rig_ranges(run: ch.RunChannels, params: Mapping[str, Any]) -> dict[str, tuple]:
    """The record stream of each rig's sensors (``[step, force, displacement, velocity,
    acceleration]`` rows) -> ``(rig, its SensorRanges)``, for the rigs with a range."""
    from seft_ros.core.structure import is_study, test_setup
    try:
        rig_params = ({'': params} if is_study(params) else test_setup(params).rig_params)
    except ParameterError:
        return {}
    out = {}
    for rig in run.graph.rigs:
        ranges = SensorRanges.from_parameters(rig_params.get(rig, params))
        stream = next((s.stream for s in run.sources
                       if s.stream.node == qualified('rig', rig) and not s.stream.timing
                       and not s.stream.fields_topic), None)
        if ranges.limited and stream is not None and len(stream.columns) == 4:
            out[stream.name] = (rig, ranges)
    return out


def _label(params: Mapping[str, Any]) -> str:
    """A run's short name (as seft run's directory names)."""
    if params.get('structure', 'none') not in ('none', '', None):
        return f'structure, {params.get("predictor")}'
    return f'alpha {params.get("alpha")}, {params.get("rig_model")}, {params.get("predictor")}'
