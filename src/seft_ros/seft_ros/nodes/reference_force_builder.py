"""reference_force_builder node: f_r[k] = -(1+alpha) m xg''[k] - alpha m a_hat[k].

Subscribes to the ground acceleration (the ground-motion publisher's record batches) and to
the rig's measurement; when the measurement of step k has arrived and ``xg''[k+1 .. k+1+L]``
have arrived (``L`` = ``builder.lookahead_steps``: the hold-consistent predictors and the
ground-motion preview read the record ahead; samples after its end, known from ``n_steps``
or the publisher's status, are 0) it publishes ``f_r[k+1]`` stamped ``t_k+1`` (``f_r[0]``
as soon as ``xg''[0..L]`` are there, the specimen at rest). ``a_hat`` comes from the
``predictor`` (``none``: the measured acceleration of the previous step, paper Eq. 5.3).
Before each new reference force, the online instability monitor
(``seft_ros.core.monitor``) checks the measurement for a growing high-frequency oscillation;
when it trips, the builder reports 'aborted' instead and the rig stops. The numerics are
``seft_ros.core.reference_force``.

Real-time mode: the builder works in parallel with the force loop. As soon as the measurement
of step k is complete it publishes ``f_r[k+1]`` (needed at ``t_k+1``); a ground acceleration
that has not arrived is replaced by the latest one it has (counted as stale), and nothing
waits. One timing record per step goes to the bag's ``/seft/timing/reference_force_builder``
(through its record stream, as its reference forces do).

Run by hand: ``ros2 run seft_ros reference_force_builder --ros-args --params-file ...``.
"""

import sys
import time

from seft_msgs_py import clock, parameters
from seft_msgs_py.convert import (
    STATE_READY,
    SerializedStamped,
    status_values,
)
from seft_msgs_py.errors import InputError
from seft_msgs_py.interface import Measurement
from seft_msgs_py.node_support import (
    InputWatchdog,
    SeftNode,
    StepTiming,
    descriptor_of,
    main_for,
)
from seft_msgs_py.signals import record_streams_of
from seft_msgs_py.topics import REFERENCE_FORCE, STATUS, record_topic
from seft_ros.core.monitor import InstabilityMonitor
from seft_ros.core.reference_force import ReferenceForceBuilder, ground_window
from seft_ros.nodes.structure_builder import StructureBuilding

__all__ = ['ReferenceForceBuilderNode', 'main']

#: Rig and controller parameters the compensators model (declared here too if the schema
#: does not list this node for them).
_MODEL_PARAMETERS = ('rig_model', 'tau_s', 'valve_limit_V', 'piston_area_m2',
                     'oil_bulk_modulus_Pa', 'actuator_volume_m3', 'valve_time_constant_s',
                     'valve_flow_gain_m3_per_s_V', 'valve_pressure_coefficient_m3_per_s_Pa',
                     'leakage_coefficient_m3_per_s_Pa', 'io_latency_s', 'anti_alias_cutoff_hz',
                     'accelerometer_range_m_s2')


class ReferenceForceBuilderNode(StructureBuilding, SeftNode):
    """Shell around :class:`~seft_ros.core.reference_force.ReferenceForceBuilder` (a structure's:
    :class:`~seft_ros.nodes.structure_builder.StructureBuilding`)."""

    def __init__(self):
        super().__init__('reference_force_builder')
        p = self.params
        for name in _MODEL_PARAMETERS:
            if name not in p:
                spec = parameters.spec(name)
                value = self.declare_parameter(name, spec.default, descriptor_of(spec)).value
                p[name] = parameters.validate_value(name, value)
        if self.graph.is_structure:
            self._init_structure()
            return
        self.builder = ReferenceForceBuilder.from_parameters(p)
        # record length: n_steps, or as the ground-motion publisher reports it
        self.n_total = int(p['n_steps']) or None
        self.monitor = InstabilityMonitor.from_parameters(p)
        self.dt = float(p['dt'])
        self.ground = {}
        self.measurements = {}
        self.next_step = 0          # step of the next reference force to publish
        self.pub = self.create_publisher(REFERENCE_FORCE.msg_type, REFERENCE_FORCE.name,
                                         REFERENCE_FORCE.qos)
        self.out_msg = SerializedStamped.scalar(REFERENCE_FORCE)
        self.batch = self.record_stream()
        # an adaptive compensator's estimates in effect for each f_r[k] (as seft simulate)
        self.estimates = getattr(self.builder.predictor, 'estimates', None)
        self.estimates_batch = None
        if self.estimates is not None:
            names = tuple(self.builder.predictor.ESTIMATES)
            self.estimates_batch = self.record_stream(
                next(r for r in record_streams_of(self.seft_name) if r.fields_topic), names)
        ground = record_streams_of('ground_motion_publisher')[0]
        spec = record_topic(ground)
        ground_sub = self.create_subscription(
            spec.msg_type, spec.name, self.guard(lambda msg: self._on_ground_batch(ground, msg)),
            spec.qos)
        measurement = self.measurement_subscription(self._on_measurement)
        self.create_subscription(STATUS.msg_type, STATUS.name, self.guard(self._on_status),
                                 STATUS.qos)
        if self.realtime:
            self.watch_inputs([measurement, ground_sub], [self.pub])
            self.timing = StepTiming(self)
            self.latest_ground = (-1, 0.0)
            self.ground_stale = False
            self.watchdog = InputWatchdog(self, ('measurement',))
        self.publish_parameters()
        self.report(STATE_READY, f'predictor {self.builder.predictor.name}')

    def _on_ground_batch(self, stream, msg) -> None:
        """The ground-motion publisher's batch: ``xg''[k]`` of every row, in order."""
        try:
            stream.columns_of(msg)
        except ValueError as exc:
            raise InputError(str(exc)) from None
        data = msg.data
        for i in range(0, len(data), 2):
            self._on_ground(int(data[i]), data[i + 1])

    def _on_ground(self, k: int, value: float) -> None:
        self.ground[k] = value
        if self.realtime:
            if k > self.latest_ground[0]:
                self.latest_ground = (k, value)
            if self.next_step == 0:
                self._advance()
            return
        self._advance()

    def _on_measurement(self, k: int, values: tuple) -> None:
        force, x, v, a = values
        self.measurements[k] = Measurement(k, k * self.dt, x, v, a, force)
        if self.realtime:
            self.watchdog.feed('measurement', k)
            self.watchdog.arm()
            self._advance_realtime()
        else:
            self._advance()

    def _ground_or_latest(self, j: int) -> float:
        """xg''[j], or the latest ground acceleration received if it has not arrived."""
        value = self.ground.get(j)
        if value is None:
            if self.n_total is not None and j >= self.n_total:
                return 0.0
            self.ground_stale = True
            return self.latest_ground[1]
        return value

    def _publish_force(self, k: int, ground, latest: Measurement | None) -> None:
        """Build f_r[k] from ``ground(j)`` (xg''[j]) and the measurement of k-1; publish it."""
        look = self.builder.lookahead_steps
        n_total = self.n_total if self.n_total is not None else k + look + 1
        force = self.builder.step(ground_window(ground, k, look, n_total), latest)
        self.ground.pop(k, None)
        self.pub.publish(self.out_msg(k * self.dt_ns, (force,)))
        self.batch.add(k, force)
        if self.estimates_batch is not None:
            self.estimates_batch.add(k, *self.estimates().values())
        self.next_step += 1

    def _monitor_trips(self, latest: Measurement, k: int) -> bool:
        """The instability monitor on sample k-1; on a trip the run is aborted (True)."""
        reason = self.monitor.update(latest.force_N, self.builder.last_ground_force_N,
                                     latest.time_s)
        if reason:
            self.abort_run(reason, k)
        return bool(reason)

    def _advance_realtime(self) -> None:
        """f_r[k+1] for every complete measurement k, in order, with the latest inputs."""
        while self.next_step - 1 in self.measurements and not self.done:
            start, jitter = self.timing.start()
            k = self.next_step
            latest = self.measurements.pop(k - 1)
            if self._monitor_trips(latest, k):
                return
            if self.n_total is not None and k >= self.n_total:
                return
            self.ground_stale = False
            self._publish_force(k, self._ground_or_latest, latest)
            if self.ground_lost(k):
                return
            now_ns = clock.now_ns()
            age = (now_ns - self.sample_time_ns(k - 1)) * 1e-9
            missed = now_ns > self.sample_time_ns(k)
            self.timing.publish(k * self.dt_ns, jitter, time.monotonic() - start, age,
                                missed, self.ground_stale)

    def ground_lost(self, k: int) -> bool:
        """Real time: end the run when the record's samples have not come for longer than
        ``watchdog_timeout_s`` (each step meanwhile built with the latest one): the
        ground-motion publisher, or the link to its host, is lost (True: aborted)."""
        self._ground_missing = self._ground_missing + 1 if self.ground_stale else 0
        if self._ground_missing * self.dt <= float(self.params['watchdog_timeout_s']):
            return False
        self.abort_run(f'watchdog: no ground motion for {1e3 * self._ground_missing * self.dt:.0f}'
                       f' ms (limit {1e3 * float(self.params["watchdog_timeout_s"]):.0f} ms; '
                       'the ground-motion publisher or its link lost)', k)
        return True

    _ground_missing = 0

    def _ground_ready(self, k: int) -> bool:
        """Whether ``xg''[k..k+L]`` are all there (or known to lie after the record)."""
        for j in range(k, k + self.builder.lookahead_steps + 1):
            if j not in self.ground and (self.n_total is None or j < self.n_total):
                return False
        return True

    def _advance(self) -> None:
        """Publish every reference force whose inputs are all there, in step order."""
        while True:
            k = self.next_step
            if self.realtime and k > 0:
                return                    # real time: _advance_realtime from here on
            if k not in self.ground or not self._ground_ready(k):
                return
            if k == 0:
                latest = None
            elif k - 1 in self.measurements:
                latest = self.measurements.pop(k - 1)
                if self._monitor_trips(latest, k):
                    return
            else:
                return
            self._publish_force(k, self.ground.__getitem__, latest)

    def _on_status(self, msg) -> None:
        if msg.name == 'ground_motion_publisher' and self.n_total is None:
            n = status_values(msg).get('n_steps')
            if n is not None:
                self.n_total = int(n)
                self._advance()


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros reference_force_builder``."""
    return main_for(ReferenceForceBuilderNode, 'reference_force_builder', args)


if __name__ == '__main__':
    sys.exit(main())
