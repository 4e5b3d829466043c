"""The reference-force builder of a structure test (the node's part for a ``structure``).

The ``reference_force_builder`` node runs this when the run has a structure
(:mod:`seft_msgs_py.graph`): it subscribes to the measurement of every rig
(``/<rig>/seft/measurement``) and to the ground motion, integrates the computational degrees
of freedom (:class:`~seft_ros.core.substructure.StructureBuilder`) and publishes the
reference force of each rig it commands on ``/<rig>/seft/reference_force``: every rig for the
central builder, its own rig for a builder in a rig's namespace (``structure_builders:
per_rig``). Before each new force, one instability monitor per commanded rig checks that rig's
measured force.

Lockstep: ``f_r[k]`` of every commanded rig once ``xg''[k .. k+L]`` and the measurement of
sample ``k-1`` of **every** rig are in, so the run equals ``seft simulate`` bit for bit. Real
time: as soon as the measurements of ``k-1`` of the commanded rigs are in; a rig commanded
elsewhere whose measurement has not arrived (across the network) is predicted over the gap
as the whole structure would move (:meth:`~seft_ros.core.substructure.StructureBuilder.step`), and
the gap is recorded in
the timing record's input age. The computational state it used goes to the bag's
``/seft/structure_state`` (``/<rig>/seft/structure_state`` for a builder in a rig's
namespace).
"""

import time

from seft_msgs_py import clock
from seft_msgs_py.convert import STATE_READY, SerializedStamped, status_values
from seft_msgs_py.graph import STRUCTURE_STATE, qualified
from seft_msgs_py.interface import Measurement
from seft_msgs_py.node_support import InputWatchdog, StepTiming
from seft_msgs_py.topics import REFERENCE_FORCE, STATUS, record_topic
from seft_ros.core.monitor import InstabilityMonitor
from seft_ros.core.reference_force import ground_window
from seft_ros.core.substructure import StructureBuilder

__all__ = ['StructureBuilding']


class StructureBuilding:
    """The structure part of the builder node (a mixin of
    :class:`~seft_ros.nodes.reference_force_builder.ReferenceForceBuilderNode`, which calls
    ``_init_structure`` once its parameters are declared)."""

    def _init_structure(self) -> None:
        p = self.params
        graph = self.graph
        self.local = graph.local_rigs(self.seft_name)
        self.builder = StructureBuilder.from_parameters(p, local=self.local)
        self.rig_index = {r: i for i, r in enumerate(self.builder.rig_names)}
        self.local_index = [self.rig_index[r] for r in self.local]
        self.n_total = int(p['n_steps']) or None
        self.dt = float(p['dt'])
        self.monitors = [InstabilityMonitor.from_parameters(self.builder.setup.rig_params[r])
                         for r in self.local]
        self.ground = {}
        #: sample -> the set of rigs whose measurement of it has arrived
        self.arrived: dict[int, set] = {}
        self.latest: dict[int, dict[int, Measurement]] = {}     # sample -> local rig -> meas
        self.next_step = 0
        spec = self.scoped_spec(REFERENCE_FORCE, self.local[0])
        self.pubs = [self.create_publisher(spec.msg_type, self.scoped_spec(REFERENCE_FORCE, r)
                                           .name, spec.qos) for r in self.local]
        self.out_msg = SerializedStamped.scalar(spec)
        self.batch = self.record_stream()
        self.state_batch = None
        if self.builder.state_names:
            stream = next(r for r in graph.record_streams_of(self.seft_name)
                          if r.fields_topic.endswith(STRUCTURE_STATE.name))
            self.state_batch = self.record_stream(stream, self.builder.state_names)
        ground = graph.record_streams()[0]
        gspec = record_topic(ground)
        ground_sub = self.create_subscription(
            gspec.msg_type, gspec.name,
            self.guard(lambda msg: self._on_ground_batch_s(ground, msg)), gspec.qos)
        subs = [self.measurement_subscription(
            lambda k, values, r=r: self._on_measurement_s(r, k, values), rig=r)
            for r in self.builder.rig_names]
        self.create_subscription(STATUS.msg_type, STATUS.name, self.guard(self._on_status_s),
                                 STATUS.qos)
        if self.realtime:
            self.watch_inputs(subs + [ground_sub], self.pubs)
            self.timing = StepTiming(self)
            self.latest_ground = (-1, 0.0)
            # every rig's measurement is watched: a rig commanded elsewhere (its lab, its link)
            # silent for longer than the watchdog is lost, and its motion is not predicted on
            # without end (the limit must exceed the link's delay: watchdog_timeout_s)
            self.watchdog = InputWatchdog(self, tuple(f'{qualified("measurement", r)}'
                                                      for r in self.builder.rig_names))
        self.publish_parameters()
        self.report(STATE_READY, f'predictor {self.builder.predictor} for '
                    f'{", ".join(self.local)}', rigs=','.join(self.local))

    # -- inputs -----------------------------------------------------------------------------

    def _on_ground_batch_s(self, stream, msg) -> None:
        stream.columns_of(msg)
        data = msg.data
        for i in range(0, len(data), 2):
            k = int(data[i])
            self.ground[k] = data[i + 1]
            if self.realtime and k > self.latest_ground[0]:
                self.latest_ground = (k, data[i + 1])
        if not self.realtime or self.next_step == 0:
            self._advance_s()

    def _on_measurement_s(self, rig: str, k: int, values: tuple) -> None:
        force, x, v, a = values
        m = Measurement(k, k * self.dt, x, v, a, force)
        r = self.rig_index[rig]
        self.builder.observe(r, m)
        if k >= self.next_step - 1:                 # (a late one of a step already built)
            self.arrived.setdefault(k, set()).add(r)
        if self.realtime:
            self.watchdog.feed(qualified('measurement', rig), k)
        if rig in self.local:
            self.latest.setdefault(k, {})[r] = m
            if self.realtime:
                self.watchdog.arm()
        self._advance_s()

    def _on_status_s(self, msg) -> None:
        if msg.name == 'ground_motion_publisher' and self.n_total is None:
            n = status_values(msg).get('n_steps')
            if n is not None:
                self.n_total = int(n)
                self._advance_s()

    # -- stepping ---------------------------------------------------------------------------

    def _ground_ready(self, k: int) -> bool:
        for j in range(k, k + self.builder.lookahead_steps + 1):
            if j not in self.ground and (self.n_total is None or j < self.n_total):
                return False
        return True

    def _inputs_ready(self, k: int) -> bool:
        """Lockstep: every rig's sample k-1; real time: the commanded rigs'."""
        if k == 0:
            return True
        got = self.arrived.get(k - 1, ())
        need = self.local_index if self.realtime else range(len(self.builder.rig_names))
        return all(r in got for r in need)

    def _ground_at(self, j: int) -> float:
        value = self.ground.get(j)
        if value is None:
            if self.n_total is not None and j >= self.n_total:
                return 0.0
            self.ground_stale = True
            return self.latest_ground[1]
        return value

    def _advance_s(self) -> None:
        """Publish every reference force whose inputs are in, in step order."""
        while not self.done:
            k = self.next_step
            if self.n_total is not None and k >= self.n_total:
                return
            if not self._inputs_ready(k):
                return
            if not self.realtime and not self._ground_ready(k):
                return
            if self.realtime and k == 0 and not self._ground_ready(k):
                return
            start, jitter = self.timing.start() if self.timing is not None else (0.0, 0.0)
            if k > 0 and self._monitors_trip(k):
                return
            self.ground_stale = False
            look = self.builder.lookahead_steps
            n_total = self.n_total if self.n_total is not None else k + look + 1
            lookup = self._ground_at if self.realtime else self.ground.__getitem__
            forces = self.builder.step(ground_window(lookup, k, look, n_total))
            stamp = k * self.dt_ns
            for pub, force in zip(self.pubs, forces):
                pub.publish(self.out_msg(stamp, (force,)))
            self.batch.add(k, *forces)
            if self.state_batch is not None and k > 0:
                self.state_batch.add(k - 1, *self.builder.computational_state)
            if self.realtime and self.ground_lost(k):
                return
            self.ground.pop(k - 1, None)
            self.arrived.pop(k - 1, None)
            self.latest.pop(k - 1, None)
            self.next_step = k + 1
            if self.timing is not None:
                now_ns = clock.now_ns()
                oldest = k - 1 - self.builder.window_steps
                age = (now_ns - self.sample_time_ns(oldest)) * 1e-9
                self.timing.publish(stamp, jitter, time.monotonic() - start, age,
                                    now_ns > self.sample_time_ns(k), self.ground_stale)

    def _monitors_trip(self, k: int) -> bool:
        """Each commanded rig's instability monitor on its sample k-1 (True: aborted)."""
        latest = self.latest.get(k - 1, {})
        for i, (r, monitor) in enumerate(zip(self.local_index, self.monitors)):
            m = latest.get(r)
            if m is None:
                continue
            reason = monitor.update(m.force_N, self.builder.last_ground_forces_N[i], m.time_s)
            if reason:
                self.abort_run(f'{self.local[i] or "rig"}: {reason}', k)
                return True
        return False
