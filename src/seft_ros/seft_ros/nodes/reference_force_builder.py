"""reference_force_builder node: the reference forces of the rigs it commands.

Every test is a structure (:mod:`seft_msgs_py.graph`); the reference study's test is its
one-rig case (``f_r[k] = -(1+alpha) m xg''[k] - alpha m a_hat[k]``, paper Eq. 2.5). The node
subscribes to the ground acceleration (the ground-motion publisher's record batches) and to
the measurement of every rig (``/seft/measurement`` in the study's test,
``/<rig>/seft/measurement`` in a structure's), integrates the computational degrees of freedom
and publishes the reference force of each rig it commands (``/seft/reference_force``,
``/<rig>/seft/reference_force``): every rig for the central builder, its own rig for a
builder in a rig's namespace (``structure_builders: per_rig``). The numerics are
:class:`~seft_ros.core.reference_force.ReferenceForceBuilder`: each rig's delay compensator
(``predictor``; ``none``: the measured acceleration of the previous step, paper Eq. 5.3) and
the interface force of the computational part. Before each new force, one instability
monitor per commanded rig (``seft_ros.core.monitor``) checks that rig's measured force for a
growing high-frequency oscillation, and one divergence guard its measured displacement and
force against the pre-run reference analysis's peaks (``divergence_factor``); when either
trips, the builder reports 'aborted' and the rigs stop.

Lockstep: ``f_r[k]`` of every commanded rig once ``xg''[k .. k+L]`` (``L`` =
``builder.lookahead_steps``: the hold-consistent compensators and the ground-motion preview
read the record ahead; samples after its end, known from ``n_steps`` or the publisher's
status, are 0) and the measurement of sample ``k-1`` of **every** rig are in (``f_r[0]`` as
soon as ``xg''[0..L]`` are there, the structure at rest), stamped ``t_k``: the run equals
``seft simulate`` bit for bit. Real time: as soon as the measurements of ``k-1`` of the
commanded rigs are in; a ground acceleration that has not arrived is replaced by the latest
one (counted as stale), and a rig commanded elsewhere whose measurement has not arrived
(across the network) is predicted over the gap as the whole structure would move; the gap is
recorded in the timing record's input age. One timing record per step goes to the bag's
``/[<rig>/]seft/timing/reference_force_builder``; the computational state it used to
``/seft/structure_state``, each compensator's online estimates to ``/[<rig>/]seft/estimates``.

Run by hand: ``ros2 run seft_ros reference_force_builder --ros-args --params-file ...``.
"""

import json
import sys
import time

from seft_msgs_py import clock, parameters
from seft_msgs_py.convert import STATE_READY, STATE_RUNNING, SerializedStamped, status_values
from seft_msgs_py.errors import InputError
from seft_msgs_py.graph import SPECIMEN_MODEL, STRUCTURE_STATE, qualified, scoped
from seft_msgs_py.interface import Measurement
from seft_msgs_py.node_support import (
    InputWatchdog,
    SeftNode,
    StepTiming,
    descriptor_of,
    main_for,
)
from seft_msgs_py.topics import REFERENCE_FORCE, STATUS, record_topic
from seft_ros.core.monitor import (
    SPECIMEN_UNJUDGED,
    DivergenceGuard,
    InstabilityMonitor,
    SpecimenCheck,
)
from seft_ros.core.predictors import BackgroundFits
from seft_ros.core.reference_force import ReferenceForceBuilder, ground_window
from seft_ros.core.substructure import SpecimenModel

#: The topic of a rig's specimen model (in its namespace), sent by its builder to the builders
#: of the other rigs every EXCHANGE_EVERY_STEPS steps (``structure_builders: per_rig``).
SPECIMEN_MODEL_TOPIC = SPECIMEN_MODEL

__all__ = ['ReferenceForceBuilderNode', 'main']

#: Rig and controller parameters the compensators model (declared here too if the schema
#: does not list this node for them).
_MODEL_PARAMETERS = ('rig_model', 'tau_s', 'valve_limit_V', 'piston_area_m2',
                     'oil_bulk_modulus_Pa', 'actuator_volume_m3', 'valve_time_constant_s',
                     'valve_flow_gain_m3_per_s_V', 'valve_pressure_coefficient_m3_per_s_Pa',
                     'leakage_coefficient_m3_per_s_Pa', 'io_latency_s', 'anti_alias_cutoff_hz',
                     'accelerometer_range_m_s2')

#: Real time: the interpreter's thread switch interval [s] (sys.setswitchinterval): the
#: threads of the compensators' fit worker (:class:`~seft_ros.core.predictors.BackgroundFits`:
#: arguments out, results in) hold the step for at most this long (the default 5 ms would).
FIT_SWITCH_INTERVAL_S = 2e-4


class ReferenceForceBuilderNode(SeftNode):
    """Shell around :class:`~seft_ros.core.reference_force.ReferenceForceBuilder`."""

    def __init__(self):
        super().__init__('reference_force_builder')
        p = self.params
        for name in _MODEL_PARAMETERS:
            if name not in p:
                spec = parameters.spec(name)
                value = self.declare_parameter(name, spec.default, descriptor_of(spec)).value
                p[name] = parameters.validate_value(name, value)
        graph = self.graph
        self.local = graph.local_rigs(self.seft_name)
        self.builder = ReferenceForceBuilder.from_parameters(p, local=self.local)
        prepare = getattr(self.builder.state, 'prepare', None)
        if prepare is not None:          # an OpenSees model: built before the first step
            prepare()
        self.rig_index = {r: i for i, r in enumerate(self.builder.rig_names)}
        self.local_index = [self.rig_index[r] for r in self.local]
        # record length: n_steps, or as the ground-motion publisher reports it
        self.n_total = int(p['n_steps']) or None
        # the samples after a record cut short (the publisher's status; None until it says)
        self.following = None
        self.dt = float(p['dt'])
        self.monitors = [InstabilityMonitor.from_parameters(self.builder.setup.rig_params[r])
                         for r in self.local]
        # each commanded rig's measured displacement and force against the pre-run
        # prediction of their peaks (divergence_factor): the range check's reference analysis
        # of the record the ground-motion publisher plays, as seft simulate makes it
        predicted, self._guard_note = None, ''
        if float(p.get('divergence_factor', 0.0) or 0.0) > 0:
            from seft_ros.analysis.range_check import divergence_prediction
            predicted, self._guard_note = divergence_prediction(p)
            if self._guard_note:
                self.get_logger().warning(self._guard_note)
        self.divergence_guards = [
            DivergenceGuard.from_parameters(self.builder.setup.rig_params[r], predicted, rig=r)
            for r in self.local]
        # each commanded rig's specimen against its compensator's model (specimen_check)
        self.checks = [SpecimenCheck.from_parameters(p, rig=r)
                       for r, p in zip(self.local, self.builder.rig_params)]
        self.check_abort = [p.get('specimen_check', 'warn') == 'abort'
                            for p in self.builder.rig_params]
        self.ground = {}
        #: sample -> the set of rigs whose measurement of it has arrived
        self.arrived: dict[int, set] = {}
        self.latest: dict[int, dict[int, Measurement]] = {}     # sample -> local rig -> meas
        self.next_step = 0          # step of the next reference forces to publish
        spec = self.scoped_spec(REFERENCE_FORCE, self.local[0])
        self.force_topics = [self.scoped_spec(REFERENCE_FORCE, r).name for r in self.local]
        self.pubs = [self.create_publisher(spec.msg_type, name, spec.qos)
                     for name in self.force_topics]
        self.out_msg = self.sealed_writer(SerializedStamped.scalar(spec, self.seal.frame_id))
        self.batch = self.record_stream()
        streams = graph.record_streams_of(self.seft_name)
        self.state_batch = None
        if self.builder.state_names:
            stream = next(r for r in streams if r.fields_topic.endswith(STRUCTURE_STATE.name))
            self.state_batch = self.record_stream(stream, self.builder.state_names)
        # each compensator's online estimates in effect for each f_r[k] (as seft simulate)
        self.estimates_batches = []
        for r, law in zip(self.local, self.builder.laws):
            names = getattr(law.predictor, 'ESTIMATES', None)
            batch = None
            if names is not None and getattr(law.predictor, 'estimates', None) is not None:
                topic = graph.estimates(r).name
                stream = next(s for s in streams if s.fields_topic == topic)
                batch = self.record_stream(stream, tuple(names))
            self.estimates_batches.append(batch)
        ground = graph.record_streams()[0] if graph.is_structure else next(
            s for s in graph.record_streams() if s.node == 'ground_motion_publisher')
        gspec = record_topic(ground)
        ground_sub = self.create_subscription(
            gspec.msg_type, gspec.name,
            self.guard(lambda msg: self._on_ground_batch(ground, msg)), gspec.qos,
            event_callbacks=self.publisher_watch(gspec.name))
        subs = [self.measurement_subscription(
            lambda k, values, r=r: self._on_measurement(r, k, values), rig=r)
            for r in self.builder.rig_names]
        self.create_subscription(STATUS.msg_type, STATUS.name, self.guard(self._on_status),
                                 STATUS.qos)
        # the builders of one test (one per rig) exchange their rigs' specimen models
        self.model_pubs = {}
        if self.builder.remote_rigs:
            from sensor_msgs.msg import JointState

            from seft_msgs_py.topics import DATA_QOS
            self._joint_state = JointState
            for r in self.local:
                self.model_pubs[r] = self.create_publisher(
                    JointState, scoped(SPECIMEN_MODEL_TOPIC, r), DATA_QOS)
            for r in self.builder.remote_rigs:
                self.create_subscription(
                    JointState, scoped(SPECIMEN_MODEL_TOPIC, r),
                    self.guard(lambda msg, r=r: self._on_model(r, msg)), DATA_QOS,
                    event_callbacks=self.publisher_watch(scoped(SPECIMEN_MODEL_TOPIC, r)))
        if self.realtime:
            # the compensators' refits (tens of ms) off the step, in a worker process started
            # now (its imports before the run); the executor's own threads (sending the
            # arguments, receiving the results) give the step the GIL back within the switch
            # interval
            self.fits = None
            if self.builder.refits():
                self.fits = BackgroundFits()
                self.fits.start()
                self.builder.run_fits_in_background(self.fits)
                sys.setswitchinterval(FIT_SWITCH_INTERVAL_S)
            self.watch_inputs(subs + [ground_sub], self.pubs)
            self.timing = StepTiming(self)
            self.latest_ground = (-1, 0.0)
            # every rig's measurement is watched: a rig commanded elsewhere (its lab, its link)
            # silent for longer than the watchdog is lost, and its motion is not predicted on
            # without end (the limit must exceed the link's delay: watchdog_timeout_s)
            self.watchdog = InputWatchdog(self, tuple(f'{qualified("measurement", r)}'
                                                      for r in self.builder.rig_names))
        self.publish_parameters()
        names = sorted({law.predictor.name for law in self.builder.laws})
        if graph.is_structure:
            self.report(STATE_READY, f'predictor {", ".join(names)} for '
                        f'{", ".join(self.local)}', rigs=','.join(self.local))
        else:
            self.report(STATE_READY, f'predictor {names[0]}')

    def destroy_node(self):
        """The fits' worker process ends with the node (after the fit it is making)."""
        fits = getattr(self, 'fits', None)
        if fits is not None:
            fits.shutdown()
        return super().destroy_node()

    # -- inputs -----------------------------------------------------------------------------

    def _on_ground_batch(self, stream, msg) -> None:
        """The ground-motion publisher's batch: ``xg''[k]`` of every row, in order (a batch
        without the run's seal: dropped, and the run aborted naming its publisher)."""
        if not self.batch_sealed(stream, msg):
            self.foreign_input(stream.name, msg.layout.dim[0].label if msg.layout.dim else '',
                               True)
            return
        try:
            stream.columns_of(msg)
        except ValueError as exc:
            raise InputError(str(exc)) from None
        data = msg.data
        for i in range(0, len(data), 2):
            k = int(data[i])
            self.ground[k] = data[i + 1]
            if self.realtime and k > self.latest_ground[0]:
                self.latest_ground = (k, data[i + 1])
        if not self.realtime or self.next_step == 0:
            self._advance()

    def _on_measurement(self, rig: str, k: int, values: tuple) -> None:
        force, x, v, a = values
        m = Measurement(k, k * self.dt, x, v, a, force)
        r = self.rig_index[rig]
        self.builder.observe(r, m)
        if rig in self.local:
            for warning in self.builder.range_warnings():
                self.get_logger().warning(warning)
                self.report(STATE_RUNNING, warning, warning=warning, step=k)
            if self._guard_note:                    # the divergence guard off: said once
                self.report(STATE_RUNNING, self._guard_note, warning=self._guard_note, step=k)
                self._guard_note = ''
        if k >= self.next_step - 1:                 # (a late one of a step already built)
            self.arrived.setdefault(k, set()).add(r)
        if self.realtime:
            self.watchdog.feed(qualified('measurement', rig), k)
        if rig in self.local:
            self.latest.setdefault(k, {})[r] = m
            if self.realtime:
                self.watchdog.arm()
        self._advance()

    def final_counts(self) -> dict:
        """The node's counts (:meth:`seft_msgs_py.node_support.SeftNode.final_counts`),
        each commanded rig's samples at a sensor's range (``sensor_range``: the JSON of
        :meth:`~seft_ros.core.reference_force.ReferenceForceBuilder.range_counts`) and its
        specimen check's identified stiffness over the declared one (``specimen_ratios``,
        JSON) and what its computational part found (``part_findings``, JSON of
        :meth:`~seft_ros.core.reference_force.ReferenceForceBuilder.part_findings`: an OpenSees
        part's pushover)."""
        counts = super().final_counts()
        counts['part_findings'] = json.dumps(self.builder.part_findings(), sort_keys=True)
        counts['sensor_range'] = json.dumps(self.builder.range_counts(), sort_keys=True)
        # each commanded rig's identified specimen stiffness over the declared one
        counts['specimen_ratios'] = json.dumps(
            {r: c.stiffness_ratio for r, c in zip(self.local, self.checks) if c is not None},
            sort_keys=True)
        return counts

    def _on_model(self, rig: str, msg) -> None:
        """Another builder's model of its rig (``name``: m, c, k; stamp: the step it was
        sent after); one without the run's seal is dropped and the run aborted."""
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        topic = self.graph.specimen_model(rig)
        if not self.seal.frame_ok(msg.header.frame_id, topic, stamp_ns, list(msg.position)):
            self.foreign_input(topic, msg.header.frame_id, True)
            return
        values = dict(zip(msg.name, msg.position))
        step = int(round(stamp_ns / self.dt_ns))
        self.builder.receive_models(step, rig, SpecimenModel(
            values['mass_kg'], values['damping_N_s_per_m'], values['stiffness_N_per_m']))
        self._advance()

    def _publish_models(self) -> None:
        """Send the local rigs' models of the latest step to the other builders."""
        step, models = self.builder.outbox
        stamp_ns = step * self.dt_ns
        for r, model in models.items():
            msg = self._joint_state()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
            msg.name = ['mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m']
            msg.position = [model.mass_kg, model.damping_N_s_per_m, model.stiffness_N_per_m]
            msg.header.frame_id = self.seal.frame_id_of(self.graph.specimen_model(r), stamp_ns,
                                                        msg.position)
            self.model_pubs[r].publish(msg)

    def _on_status(self, msg) -> None:
        if not self.status_of_run(msg):
            return              # another run's (SeftNode._on_any_status counts it)
        if msg.name == 'ground_motion_publisher' and (self.n_total is None
                                                      or self.following is None):
            values = status_values(msg)
            n, following = values.get('n_steps'), values.get('following')
            if n is not None:
                self.n_total = self.n_total or int(n)
                self.following = [float(v) for v in json.loads(following or '[]')]
                self._advance()

    # -- stepping ---------------------------------------------------------------------------

    def _ground_ready(self, k: int) -> bool:
        """Whether ``xg''[k..k+L]`` are all there (or known to lie after the record)."""
        for j in range(k, k + self.builder.lookahead_steps + 1):
            if j not in self.ground and (self.n_total is None or j < self.n_total):
                return False
            if self.n_total is not None and j >= self.n_total and self.following is None:
                return False                  # what follows the record: not said yet
        return True

    def _inputs_ready(self, k: int) -> bool:
        """Lockstep: every rig's sample k-1; real time: the commanded rigs'."""
        if k == 0:
            return True
        got = self.arrived.get(k - 1, ())
        need = self.local_index if self.realtime else range(len(self.builder.rig_names))
        if not all(r in got for r in need):
            return False
        due = self.builder.models_due(k)        # lockstep: the other labs' models too
        return self.realtime or due is None or self.builder.has_models(due)

    ground_stale = False

    def _ground_at(self, j: int) -> float:
        """xg''[j], or the latest ground acceleration received if it has not arrived."""
        value = self.ground.get(j)
        if value is None:
            if self.n_total is not None and j >= self.n_total:
                following = self.following or ()
                return following[j - self.n_total] if j - self.n_total < len(following) else 0.0
            self.ground_stale = True
            return self.latest_ground[1]
        return value

    def _advance(self) -> None:
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
            # f_r[0] is built before the rigs' clock starts: no timing record of it
            timed = self.timing is not None and k > 0
            start, jitter = self.timing.start() if timed else (0.0, 0.0)
            if k > 0 and self._monitors_trip(k):
                return
            self.ground_stale = False
            look = self.builder.lookahead_steps
            n_total = self.n_total if self.n_total is not None else k + look + 1
            lookup = self._ground_at if self.realtime else self.ground.__getitem__
            forces = self.builder.step(ground_window(lookup, k, look, n_total,
                                                     self.following or ()))
            if self.model_pubs and self.builder.outbox is not None \
                    and self.builder.outbox[0] == k:
                self._publish_models()
            stamp = k * self.dt_ns
            for pub, topic, force in zip(self.pubs, self.force_topics, forces):
                pub.publish(self.out_msg(topic, stamp, (force,)))
            self.batch.add(k, *forces)
            for batch, est in zip(self.estimates_batches, self.builder.estimates()):
                if batch is not None:
                    batch.add(k, *est.values())
            lag = self.builder.state_lag_steps
            if self.state_batch is not None and k > lag:
                self.state_batch.add(k - 1 - lag, *self.builder.computational_state)
            if self.realtime and self.ground_lost(k):
                return
            self.ground.pop(k - 1, None)
            self.arrived.pop(k - 1, None)
            self.latest.pop(k - 1, None)
            self.next_step = k + 1
            if timed:
                now_ns = clock.now_ns()
                oldest = k - 1 - self.builder.window_steps
                age = (now_ns - self.sample_time_ns(oldest)) * 1e-9
                late_ns = now_ns - self.sample_time_ns(k)
                if late_ns > 0:          # the controller extrapolated it meanwhile
                    self.builder.reference_late(k, late_ns * 1e-9)
                self.timing.publish(stamp, jitter, time.monotonic() - start, age, late_ns > 0,
                                    self.ground_stale)
            # the computational part's work that this step's commands did not need (an
            # OpenSees model stepped after them: step deferred); off the loop's timing
            self.builder.advance()

    def _monitors_trip(self, k: int) -> bool:
        """Each commanded rig's instability monitor, divergence guard and specimen check on
        its sample k-1 (True: aborted)."""
        latest = self.latest.get(k - 1, {})
        for i, (r, monitor) in enumerate(zip(self.local_index, self.monitors)):
            m = latest.get(r)
            if m is None:
                continue
            reason = monitor.update(m.force_N, self.builder.last_ground_forces_N[i], m.time_s)
            guard = self.divergence_guards[i]
            if not reason and guard is not None:
                reason = guard.update(m)
            check = self.checks[i]
            if not reason and check is not None:
                finding = check.update(m)
                if (finding and self.check_abort[i]
                        and not finding.startswith(SPECIMEN_UNJUDGED)):
                    reason = finding
                elif finding:
                    name = self.local[i]
                    warning = f'{name}: {finding}' if name else finding
                    self.get_logger().warning(warning)
                    self.report(STATE_RUNNING, warning, warning=warning, step=k)
            if reason:
                name = self.local[i]
                self.abort_run(f'{name}: {reason}' if name else reason, k)
                return True
        return False

    _ground_missing = 0

    def ground_lost(self, k: int) -> bool:
        """Real time: end the run when the record's samples have not come for longer than
        ``watchdog_timeout_s`` (each step meanwhile built with the latest one): the
        ground-motion publisher, or the link to its host, is lost (True: aborted)."""
        self._ground_missing = self._ground_missing + 1 if self.ground_stale else 0
        if self._ground_missing * self.dt <= float(self.params['watchdog_timeout_s']):
            return False
        self.abort_run(f'watchdog: no ground motion for {1e3 * self._ground_missing * self.dt:.0f}'
                       f' ms (limit {1e3 * float(self.params["watchdog_timeout_s"]):g} ms; '
                       'the ground-motion publisher or its link lost)', k)
        return True


def main(args=None) -> int:
    """Entry point of ``ros2 run seft_ros reference_force_builder``."""
    return main_for(ReferenceForceBuilderNode, 'reference_force_builder', args)


if __name__ == '__main__':
    sys.exit(main())
