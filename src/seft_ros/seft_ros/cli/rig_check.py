"""``seft rig-check``: run the rest of the graph against a rig node and check the rig contract.

The DDS shell of :mod:`seft_ros.core.rig_check`: it runs short real-time tests with the
ground-motion publisher, the reference-force builder, the force servo controller (valve rigs)
and the recorder of seft against the rig node that ``rig_command`` starts (any program that
takes ``--ros-args --params-file FILE`` and talks DDS; default: seft's own rig node), listens
to the rig's measurement, ``/clock`` and status as they arrive, injects the faults, reads the
bags back and hands the arrays to the checks.

The runs (:data:`RUNS`), each a graph of its own, bounded in time and force:

``step``
    at rest, then the static reference force ``amplitude_N``, then at rest again; a rig
    behind the UDP bridge meets a second sender at rest after the force (:class:`_SecondSender`:
    a start flag of its own session and 0 V commands to the lab's controller, which must
    refuse them);
``abort``, ``stopped_controller``, ``watchdog``
    a sine of ``amplitude_N``; two cycles and 45 degrees into it (a cycle or two later if
    the checker heard that sample late: ``CheckProfile.fault_steps``), ``seft rig-check``
    publishes an abort on /seft/status, stops the node that commands the rig with SIGTERM (it
    reports itself aborted), or freezes it with SIGSTOP (silent: the rig's watchdog must
    notice).

The reference force reaches the rig through seft's own graph: a record of ground
acceleration ``-f_r / m`` played with ``alpha = 0`` and no compensation gives the reference
force ``f_r`` (paper Eq. 2.5); the instability monitor is off, and the rig's force and stroke
limits are tightened to :data:`FORCE_LIMIT_FACTOR` times the amplitude and
:data:`STROKE_LIMIT_FACTOR` times its static displacement (at least :data:`MIN_STROKE_M`).
"""

from dataclasses import dataclass, field
import json
import math
import os
from pathlib import Path
import shlex
import signal
import sys
import time
from types import SimpleNamespace
from typing import Callable, Mapping, Sequence

import numpy as np

from seft_msgs_py import clock, rig_contract
from seft_msgs_py.convert import STATE_RUNNING, stamp_to_ns, status_values
from seft_msgs_py.errors import InputError, SeftError
from seft_msgs_py.graph import Graph, qualified, scoped
from seft_msgs_py.scheduling import set_fifo
from seft_msgs_py.signals import (
    ACCELERATION,
    DISPLACEMENT,
    FINAL_STATES,
    MEASURED_FORCE,
    MEASUREMENT_FIELDS,
    VELOCITY,
)
from seft_ros.core import rig_check as rc
from seft_ros.core.monitor import monitor_cutoff_hz

__all__ = ['RUNS', 'RigCheckReport', 'run_rig_check', 'rig_command_factory',
           'fault_rig_command', 'structure_rigs', 'check_parameters', 'write_force_record',
           'evaluate', 'main_lines', 'FORCE_LIMIT_FACTOR', 'STROKE_LIMIT_FACTOR',
           'MIN_STROKE_M']

#: The runs of a rig check, in order.
RUNS = ('step', 'abort', 'stopped_controller', 'watchdog')
#: The rig's force limit during the check: this times the amplitude (or its own, if lower).
FORCE_LIMIT_FACTOR = 5.0
#: The rig's stroke limit during the check: this times the static displacement F / k of the
#: amplitude (or its own, if lower), and at least :data:`MIN_STROKE_M`.
STROKE_LIMIT_FACTOR = 10.0
#: Least stroke limit during the check [m].
MIN_STROKE_M = 0.001


@dataclass
class RigCheckReport:
    """What ``seft rig-check`` found.

    Attributes
    ----------
    results : list of CheckResult
        One per check, in :data:`~seft_ros.core.rig_check.CHECKS` order.
    wall_s : float
        How long the check took [s].
    out_dir : Path
        Where the runs' bags and logs and ``rig_check.json`` are.
    injected_fault : str or None
        The fault injected into seft's rig node (``--inject``).
    """

    results: list
    wall_s: float
    out_dir: Path
    injected_fault: str | None = None

    @property
    def passed(self) -> bool:
        """Every check passed."""
        return all(r.passed for r in self.results)


def rig_command_factory(command: str | None) -> Callable[[Path], list[str]] | None:
    """The argv that starts the rig for a parameter file (``GraphRunner.run``'s `commands`).

    `command` is a shell-like command line; ``{params}`` in it is replaced by the parameter
    file, else ``--ros-args --params-file FILE`` is appended. None or '': seft's rig node.

    Raises
    ------
    InputError
        The command line cannot be split (unbalanced quotes) or is empty.
    """
    if not command:
        return None
    try:
        words = shlex.split(command)
    except ValueError as exc:
        raise InputError(f'--rig-command {command!r}: {exc}') from None
    if not words:
        raise InputError(f'--rig-command {command!r}: expected a command line')

    def argv(params_file: Path) -> list[str]:
        if any('{params}' in w for w in words):
            return [w.replace('{params}', str(params_file)) for w in words]
        return words + ['--ros-args', '--params-file', str(params_file)]
    return argv


def write_force_record(path: Path, reference_N: np.ndarray, dt: float, mass_kg: float) -> Path:
    """Write the ground acceleration ``-f_r / m`` [m/s^2] that makes the reference force
    `reference_N` [N] with alpha 0 (paper Eq. 2.5) as a two-column CSV record (time [s],
    acceleration [m/s^2])."""
    t = np.arange(len(reference_N)) * dt
    rows = '\n'.join(f'{float(ti)!r},{float(-fi / mass_kg)!r}'
                     for ti, fi in zip(t, reference_N))
    path.write_text('time_s,acceleration_m_s2\n' + rows + '\n')
    return path


def check_parameters(base: Mapping, profile: rc.CheckProfile, record: Path, n_steps: int
                     ) -> dict:
    """The parameters of one rig-check run: `base` (the user's configuration) in real time,
    alpha 0, no compensation, the monitor off, the record played as it is, and the rig's
    limits tightened (module notes); a rig of a structure stays the one rig of its one-DOF
    structure (:func:`structure_rigs`)."""
    p = dict(base)
    structure = p.get('structure', 'none') if Graph.from_parameters(p).is_structure else 'none'
    force_limit = min(float(p['force_limit_N']), FORCE_LIMIT_FACTOR * profile.amplitude_N)
    static = profile.amplitude_N / float(p['stiffness_N_per_m'])
    stroke = min(float(p['stroke_limit_m']), max(STROKE_LIMIT_FACTOR * static, MIN_STROKE_M))
    p.update(mode='realtime', alpha=0.0, predictor='none', excitation='none',
             record=str(record), amplitude_N=0.0, scale_factor=1.0, time_scale=1.0,
             duration_s=0.0, n_steps=int(n_steps), monitor_threshold=0.0,
             force_limit_N=force_limit, stroke_limit_m=stroke, structure=structure,
             network_delay_s=0.0)
    return p


def structure_rigs(params: Mapping, rig_name: str | None = None) -> list[tuple[str, dict]]:
    """The rigs a rig check of a test checks, each with the parameters of its check.

    The study's test: its one rig, ``('', params)``. A structure test: each rig (or
    `rig_name` alone), in its namespace, with its own parameters (the test's updated by its
    section of ``rigs``, :func:`~seft_ros.core.structure.rig_parameters`) and, as its
    ``structure``, a structure of its one DOF whose mass, damping and stiffness are its
    specimen's: the graph is the structure test's for that rig (its namespace, its topics,
    its qualified name; the reference force is its effective force, paper Eq. 2.5 with
    alpha 0), and nothing waits for the other rigs. ``alpha`` is set to the computational
    mass on the rig's DOF over its specimen's (``M[p, p] / m_p - 1``): what the rig's
    acceleration weighs in its reference force (the ``sensor noise`` check).

    Raises
    ------
    InputError
        `rig_name` given for a test without a structure, or not one of its rigs.
    ParameterError
        A rig's section the schema refuses.
    """
    graph = Graph.from_parameters(params)
    if not graph.is_structure:
        if rig_name:
            raise InputError(f'--rig-name {rig_name}: the configuration has no structure (its '
                             'one rig runs in the root namespace)')
        return [('', dict(params))]
    from seft_ros.core.structure import Structure, rig_parameters
    structure = Structure.from_json(params['structure'])
    rigs = structure.rig_names
    if rig_name and rig_name not in rigs:
        raise InputError(f'--rig-name {rig_name}: expected one of {", ".join(rigs)}')
    out = []
    for rig in rigs if not rig_name else (rig_name,):
        p = rig_parameters(params, structure, rig)
        i = structure.dofs.index(structure.dof_of_rig(rig))
        m, c, k = (float(p[n]) for n in ('mass_kg', 'damping_N_s_per_m', 'stiffness_N_per_m'))
        one = Structure((structure.dofs[i],), np.array([[m]]), np.array([[c]]),
                        np.array([[k]]), np.ones(1), {structure.dofs[i]: rig}, {rig: {}})
        p.update(structure=one.to_json(), structure_builders='central',
                 alpha=max(float(structure.mass_kg[i, i]) / m - 1.0, 0.0))
        out.append((rig, p))
    return out


class _SecondSender:
    """A second sender on the checker's host: a start flag of a session of its own to the
    lab's controller, then 0 V commands every period (harmless if a controller took them: a
    closed valve, no force), :data:`SENDS` datagrams in all from a thread; what the
    controller sends it back is kept (``second sender`` check).

    Parameters
    ----------
    params : mapping
        The run's parameters (``udp_controller_address``, ``dt``, the command kind, the
        key of ``message_auth: hmac``).

    Raises
    ------
    ParameterError
        A bad controller address or key file (the rig node refuses them too).
    """

    SENDS = 10
    #: A start is sent only while the live run has at least this long to go by the rig's
    #: clock [s]: after the run's end a controller is free, and taking a start is right.
    END_GUARD_S = 0.1

    def __init__(self, params: Mapping):
        import random
        import socket

        from seft_msgs_py.provenance import key_of
        from seft_plant_sim import udp_layout as ul
        from seft_plant_sim.udp_bridge import resolve_address
        self.ul = ul
        self.to = resolve_address(params['udp_controller_address'])
        self.key = key_of(params)
        self.dt = float(params['dt'])
        self.dt_ns = int(round(self.dt * 1e9))
        self.wire_kind = (ul.COMMAND_VALVE if rig_contract.command_kind(params)
                          == rig_contract.COMMAND_KINDS[0] else ul.COMMAND_FORCE)
        self.session = random.SystemRandom().randrange(1, 2 ** 32)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(self.to)           # its own address, on the route to the controller
        self.sock.setblocking(False)
        host, port = self.sock.getsockname()[:2]
        self.address = f'{host}:{port}'
        self.sent, self.sequence = 0, 0
        self.t_s: float | None = None
        #: The live run's end on the rig's clock [s].
        self.end_s = int(params['n_steps']) * self.dt
        #: How far the rig's clock had run past `t_s` when each start was due [s]; the
        #: starts not sent (too near the run's end).
        self.lag_s = 0.0
        self.withheld = 0
        self.thread = None

    def _send(self, kind: int, flags: int, value: float = 0.0, sample: int = -1) -> None:
        self.sequence += 1
        data = self.ul.encode(self.ul.ToController(
            kind, flags, self.session, self.sequence, sample, sample, value, self.dt_ns,
            1000, self.wire_kind), self.key)
        try:
            self.sock.send(data)
            self.sent += 1
        except OSError:
            pass

    def fire(self, t_s: float, sent_s: float) -> None:
        """Send the start, then the 0 V commands every period, from a thread (`t_s`: the
        sample the checker heard [s of the run]; `sent_s`: when the rig sent it [s, system
        clock]). Each only while the live run has :attr:`END_GUARD_S` to go by the rig's
        clock: a checker that heard the sample late (a loaded host: 0.75 s late, and the
        controller, rightly, took the start after the run's end) withholds the rest."""
        import threading
        self.t_s = t_s

        def live() -> bool:
            self.lag_s = clock.system_ns() * 1e-9 - sent_s
            return t_s + self.lag_s < self.end_s - self.END_GUARD_S

        def run():
            for j in range(self.SENDS):
                if j:
                    time.sleep(self.dt)
                if not live():
                    self.withheld = self.SENDS - j
                    return
                if j == 0:
                    self._send(self.ul.KIND_HEARTBEAT, self.ul.FLAG_START)
                else:
                    self._send(self.ul.KIND_COMMAND, self.ul.FLAG_START, 0.0, j - 1)
        self.thread = threading.Thread(target=run, name='second_sender', daemon=True)
        self.thread.start()

    def result(self) -> dict | None:
        """What it sent and heard (``check_second_sender``'s `trial`), None if it never
        sent; ends its own session if the controller took it, and closes."""
        if self.thread is not None:
            self.thread.join(timeout=2)
        heard = []
        while True:
            try:
                data = self.sock.recv(4096)
            except OSError:
                break
            try:
                d = self.ul.decode_to_pc(data, self.key)
            except self.ul.DatagramError:
                heard.append((-1, 'unreadable'))
                continue
            heard.append((d.session, self.ul.STATE_NAMES.get(d.state, str(d.state))))
        sent = self.sent
        if any(session == self.session for session, _ in heard):
            for _ in range(3):
                self._send(self.ul.KIND_HEARTBEAT, self.ul.FLAG_END)
        self.sock.close()
        if self.t_s is None:
            return None
        return {'from': self.address, 'session': self.session, 't_s': self.t_s,
                'sent': sent, 'heard': heard, 'lag_s': self.lag_s, 'withheld': self.withheld}


class _Tap:
    """The checker's own ears on the graph: every measurement of the rig (when the rig sent
    it, stamp, fields, whether it carries the run's seal), /clock, the rig's status; and the
    fault, fired from the measurement callback when the fault's sample arrives."""

    def __init__(self, runner, graph: Graph):
        from rclpy.serialization import deserialize_message

        from seft_msgs_py.topics import CLOCK, MEASUREMENT, STATUS
        self.runner = runner
        self.rig = graph.rigs[0]
        self.rig_node = graph.rig_nodes()[0]
        self.topic = graph.measurement(graph.rigs[0]).name
        self._deserialize = deserialize_message
        self._msg_type = MEASUREMENT.msg_type
        self._status_topic = STATUS.name
        self.dt_ns = 1
        self.reset()
        node = runner.node
        node.create_subscription(MEASUREMENT.msg_type, graph.measurement(graph.rigs[0]).name,
                                 self._on_measurement, MEASUREMENT.qos, raw=True)
        node.create_subscription(CLOCK.msg_type, CLOCK.name, self._on_clock, CLOCK.qos,
                                 raw=True)
        node.create_subscription(STATUS.msg_type, STATUS.name, self._on_status, STATUS.qos)

    def reset(self, dt_ns: int = 1, fault: Callable[[float, float], None] | None = None,
              fault_steps: Sequence[int] = ()) -> None:
        """Begin a run: samples of `dt_ns` [ns]; ``fault(t_s, sent_s)`` (the sample's time in
        the run, the system time the rig sent it [s]) is fired at the first of
        `fault_steps` (its chances, in order) whose sample the checker hears within
        :data:`LATE_FAULT_S` of its sending (at the last chance whatever its lateness: the run
        is then run again, :func:`_disturbed`)."""
        self.dt_ns = dt_ns
        self.steps, self.stamps, self.arrivals, self.values = [], [], [], []
        self.received: list[float] = []
        self.handled: list[float] = []
        self.names: tuple | None = None
        self.clock_ns: list[int] = []
        self.fault, self.fault_steps, self.fault_ns = fault, list(fault_steps), None
        #: The chance the fault was injected at (its sample) [-], None before.
        self.fault_step: int | None = None
        self.stopped_pid: int | None = None
        #: This run began here [ns, system clock]: what was sent before is an earlier run's.
        self.since_ns = clock.system_ns()
        #: Messages of an earlier run taken during this one (dropped).
        self.stale = 0
        #: The run's seal (from the runner's parameters of the run, at the first sample),
        #: the messages without it and the first one's frame id.
        self.seal = None
        self.unsealed, self.unsealed_frame = 0, ''
        #: Status reports without the run's seal heard during this run (another run's).
        self.foreign_statuses = 0
        #: The rig's own reports among them (a rig of contract 2.0 does not seal its
        #: reports): their values with ``hardware_id``, for the contract's line.
        self.rig_unsealed: list[dict] = []

    def _earlier(self, info: dict) -> bool:
        """Whether a message was sent before this run began (by the rig of an earlier run or
        attempt: a reader matched late takes its history at once, and what the middleware
        holds is taken in the next spin, which may be this run's); counted in ``stale``."""
        if info['source_timestamp'] < self.since_ns:
            self.stale += 1
            return True
        return False

    def _on_measurement(self, raw: bytes, info: dict) -> None:
        if self._earlier(info):
            return
        msg = self._deserialize(raw, self._msg_type)
        stamp = stamp_to_ns(msg.header.stamp)
        k = int(round(stamp / self.dt_ns))
        self.steps.append(k)
        self.stamps.append(stamp)
        # when the rig's middleware sent it (its system clock, [s]): a sample the checker
        # hears late (discovered after the rig started, delivered from the history) keeps it
        self.arrivals.append(info['source_timestamp'] * 1e-9)
        self.received.append(info['received_timestamp'] * 1e-9)
        self.handled.append(clock.system_ns() * 1e-9)
        if self.seal is None:
            from seft_msgs_py.provenance import RunSeal
            self.seal = RunSeal.from_parameters(getattr(self.runner, 'run_params', {}))
        if not self.seal.frame_ok(msg.header.frame_id, self.topic, stamp, tuple(msg.position)):
            self.unsealed += 1
            self.unsealed_frame = self.unsealed_frame or msg.header.frame_id
        names = tuple(msg.name)
        if self.names is None:
            self.names = names
        elif names != self.names:
            self.names = tuple('' for _ in names)      # messages disagree: a failed check
        self.values.append(list(msg.position))
        if self.fault is not None and self.fault_ns is None and k >= self.fault_steps[0]:
            # heard late (a checker that discovered the rig late takes its first samples
            # at once): the next chance, a whole cycle later, heard live
            later = [s for s in self.fault_steps if s > k]
            if later and self.handled[-1] - self.arrivals[-1] > LATE_FAULT_S:
                self.fault_steps = later
                return
            self.fault_ns = clock.now_ns()
            self.fault_step = self.fault_steps[0]
            self.fault(k * self.dt_ns * 1e-9, self.arrivals[-1])

    def _on_clock(self, raw: bytes, info: dict) -> None:
        if self._earlier(info):
            return
        from seft_msgs_py.convert import clock_ns_from_raw
        self.clock_ns.append(clock_ns_from_raw(raw))

    def _on_status(self, msg) -> None:
        # the run's reports only (the runner's seal of the run): a stray rig's final report
        # (another run on the domain) must not wake the frozen node; counted
        seal = getattr(self.runner, 'seal', None)
        if seal is not None and not seal.status_ok(msg, self._status_topic):
            self.foreign_statuses += 1
            if msg.name == self.rig_node:
                self.rig_unsealed.append({**status_values(msg), 'message': msg.message,
                                          'hardware_id': msg.hardware_id})
            return
        # a node frozen by the watchdog run goes on once the rig has ended the run: it
        # hears the rig's final report and ends as after any run
        if (self.stopped_pid is not None and msg.name == self.rig_node
                and status_values(msg).get('state') in FINAL_STATES):
            try:
                os.kill(self.stopped_pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
            self.stopped_pid = None


@dataclass
class _Run:
    """What one run left: the live tap's data, the bag, the rig's reports, the error."""

    name: str
    params: dict
    steps: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    stamps: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    arrivals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    names: tuple = ()
    values: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    fault_ns: int | None = None
    #: The sample the fault was injected at (one of ``CheckProfile.fault_steps``; None: the
    #: profile's first chance).
    fault_step: int | None = None
    clock_ns: list = field(default_factory=list)
    statuses: list = field(default_factory=list)
    bag: object = None
    bag_closed: bool = False
    error: str | None = None
    #: The rig's namespace ('' for the study's single rig).
    rig: str = ''
    #: Live measurements without the run's seal, the first one's frame id, the seal in words.
    unsealed: int = 0
    unsealed_frame: str = ''
    seal_text: str = ''
    #: The second sender's trial (``check_second_sender``; a UDP bridge's step run).
    second_sender: dict | None = None
    #: The rig's status reports without the run's seal (the graph dropped them), their
    #: values with ``hardware_id`` (:attr:`_Tap.rig_unsealed`).
    rig_unsealed: list = field(default_factory=list)

    @property
    def rig_node(self) -> str:
        """The rig's qualified node name."""
        return qualified('rig', self.rig)

    def sensor_topics(self) -> tuple[str, ...]:
        """The bag's topics of the four fields, in the contract's order."""
        return tuple(scoped(t, self.rig) for t in _SENSOR_TOPICS)

    def rig_reports(self) -> list[dict]:
        return [s for s in self.statuses if s['name'] == self.rig_node]

    def final(self) -> dict | None:
        found = [s for s in self.rig_reports() if s.get('state') in FINAL_STATES]
        return found[-1] if found else None

    def unsealed_final(self) -> dict | None:
        """The rig's last final report without the run's seal, None if none."""
        found = [s for s in self.rig_unsealed if s.get('state') in FINAL_STATES]
        return found[-1] if found else None

    def ready(self) -> dict | None:
        return next((s for s in self.rig_reports() if s.get('state') == 'ready'
                     and rig_contract.CONTRACT_KEY in s), None)

    def t0_ns(self) -> int | None:
        return next((int(s['t0_ns']) for s in self.rig_reports()
                     if s.get('state') == STATE_RUNNING and 't0_ns' in s), None)

    def fault_step_of(self, profile: rc.CheckProfile) -> int:
        """The sample of this run's fault [-]: the chance it was injected at, else the
        profile's first."""
        return profile.fault_step if self.fault_step is None else self.fault_step

    def ended_before_fault(self, profile: rc.CheckProfile) -> str | None:
        """How the rig ended a fault run before its fault's sample (its final report), or
        None."""
        final = self.final() or {}
        if self.name == 'step' or self.fault_ns is not None or not final:
            return None
        try:
            end = float(final.get('abort_at_s', final.get('time_s', 'inf')))
        except ValueError:
            return None
        if end < profile.fault_step * profile.dt:
            return (f"the rig ended the run {final.get('state')} at t = {end:.3f} s, before "
                    f"its fault at {profile.fault_step * profile.dt:.3f} s "
                    f"({final.get('message', '')})")
        return None

    def fault_late_s(self, profile: rc.CheckProfile) -> float | None:
        """How late the fault came after its sample's instant ``t0 + k dt`` (``k``:
        :meth:`fault_step_of`) [s]
        (inf: never, though the rig ran past it; None: no fault run, no t0, or the rig
        ended before the fault's sample)."""
        t0 = self.t0_ns()
        if self.name == 'step' or t0 is None or self.ended_before_fault(profile):
            return None
        if self.fault_ns is None:
            return math.inf
        return (self.fault_ns - t0) * 1e-9 - self.fault_step_of(profile) * profile.dt

    def sample_count(self) -> int:
        """How many samples the rig published (its final report; else the last step the
        checker heard, + 1)."""
        final = self.final() or {}
        try:
            return int(final['published'])
        except (KeyError, ValueError):
            return int(self.steps.max()) + 1 if self.steps.size else 0

    def record(self, n: int) -> np.ndarray:
        """The bag's sensor rows of steps 0 .. n-1, shape (n, 4) in the contract's field
        order (NaN where the bag lacks a sample)."""
        out = np.full((n, len(MEASUREMENT_FIELDS)), np.nan)
        if self.bag is None:
            return out
        for i, topic in enumerate(self.sensor_topics()):
            for k, value in self.bag.samples.get(topic, {}).items():
                if 0 <= k < n:
                    out[k, i] = value
        return out

    def fields(self, n: int, record: np.ndarray | None = None) -> list[np.ndarray] | None:
        """The four fields by step 0 .. n-1 (the contract's order), as the graph had them:
        the live measurement the checker heard (its columns by the message's names when they
        are the contract's in another order), a sample it missed from the bag's record
        (`record`, default :meth:`record`), one neither has interpolated; None if there is
        none at all."""
        out = np.full((n, len(MEASUREMENT_FIELDS)), np.nan)
        if self.values.ndim == 2 and self.values.shape[1] == len(MEASUREMENT_FIELDS):
            names = tuple(self.names)
            cols = ([names.index(f) for f in MEASUREMENT_FIELDS]
                    if sorted(names) == sorted(MEASUREMENT_FIELDS) else list(range(4)))
            k = self.steps
            inside = np.flatnonzero((k >= 0) & (k < n))
            _, first = np.unique(k[inside], return_index=True)    # the first of a repeat
            rows = inside[first]
            out[k[rows]] = self.values[rows][:, cols]
        missing = np.isnan(out)
        if missing.any():
            rec = self.record(n) if record is None else record
            out[missing] = rec[missing]
        for i in range(out.shape[1]):
            ok = np.isfinite(out[:, i])
            if not ok.any():
                return None
            if not ok.all():
                out[:, i] = np.interp(np.arange(n), np.flatnonzero(ok), out[ok, i])
        return [out[:, i] for i in range(out.shape[1])]

    def command(self, topic: str, n: int) -> np.ndarray:
        s = self.bag.samples.get(topic, {}) if self.bag is not None else {}
        return np.array([s.get(k, np.nan) for k in range(n)])


#: The bag's topics of the four fields, in the contract's order.
_SENSOR_TOPICS = (MEASURED_FORCE.name, DISPLACEMENT.name, VELOCITY.name, ACCELERATION.name)


#: The checker's SCHED_FIFO priority above the graph's ``realtime_priority`` (the rig's is +3):
#: it times the rig's samples and injects the faults, so the graph must not starve it (on two
#: cores a real-time graph under SCHED_FIFO delayed a checker at the normal priority by
#: seconds, and it heard the rig's samples in bursts).
CHECKER_PRIORITY_OFFSET = 4


def _above_the_graph(base: int, progress: Callable[[str], None]) -> None:
    """Run this process under SCHED_FIFO above the graph's nodes, where it may."""
    if base <= 0:
        return
    priority = min(99, base + CHECKER_PRIORITY_OFFSET)
    try:
        # the nodes it starts must not inherit it (they take their own priorities)
        set_fifo(priority, reset_on_fork=True)
    except (OSError, AttributeError) as exc:
        progress(f'note: SCHED_FIFO {priority} refused ({exc}): the checker keeps the normal '
                 'scheduler; its timing of the rig may suffer under load')


def _fault_of(name: str, runner, command_node: str, tap: _Tap) -> Callable[[float, float], None]:
    """The fault of a run (module notes)."""
    def abort(t_s, sent_s):
        runner._publish_abort('seft rig-check: abort (the safe-state check)')

    def signal_node(sig):
        def send(t_s, sent_s):
            proc = runner.procs.get(command_node)
            if proc is not None and proc.poll() is None:
                if sig == signal.SIGSTOP:
                    tap.stopped_pid = proc.pid
                os.kill(proc.pid, sig)
        return send
    return {'abort': abort, 'stopped_controller': signal_node(signal.SIGTERM),
            'watchdog': signal_node(signal.SIGSTOP)}[name]


def _expected_error(name: str, command_node: str, message: str) -> bool:
    """The runner's error that the fault itself causes (a node stopped on purpose)."""
    return name != 'step' and f'node {command_node} ' in message


#: A fault run whose fault came more than this after its sample (the checker discovered the
#: rig late and heard its first samples in a burst) is run again [s].
LATE_FAULT_S = 0.05
#: How many times a run is run again when it says nothing of the rig (:func:`_disturbed`).
FAULT_RETRIES = 2
#: A run that ended early (before its fault; the step run aborted) with more than this
#: fraction of its samples taken with a stale command says nothing of the rig: the graph
#: fell behind it (seft's graph alone on a slow 2-core VM: 4.6 %) [-].
STALE_FRACTION = 0.1


def _disturbed(run: '_Run', profile: rc.CheckProfile) -> str | None:
    """Why a run says nothing of the rig, or None: the checker heard the rig too late to time
    the fault, heard less than half of the step run's samples or none of its /clock messages
    (a slow discovery), one of seft's own nodes lost an input before the fault, the rig
    lost its commands in the step run (a watchdog: this machine stalled the graph; a rig that
    never gets its commands fails the second time too), or the run ended early with more
    than :data:`STALE_FRACTION` of its samples on a stale command (the graph fell behind)."""
    if run.rig_unsealed and run.final() is None:
        return None         # a rig of contract 2.0: the graph dropped its reports, each time
    late = run.fault_late_s(profile)
    if late is not None and late > LATE_FAULT_S:
        return f'the checker heard the rig {late:.2f} s late: the fault came late'
    trial = run.second_sender or {}
    if any(session == trial.get('session') for session, _ in trial.get('heard', ())):
        return None         # the controller took the second sender: its fault, not a stall
    withheld = rc.start_withheld(trial)
    if withheld:
        return withheld
    final = run.final() or {}
    published = int(final.get('published', 0) or 0)
    if run.name == 'step' and published and run.steps.size < published // 2:
        return (f'the checker heard {run.steps.size} of the {published} samples (it '
                'discovered the rig late)')
    if run.name == 'step' and run.steps.size and not run.clock_ns:
        # /clock is volatile (a sample is for the readers matched when it is sent) and the
        # rig starts without waiting for the checker's reader: on a busy host it matched
        # after the 2 s run (a rig that never publishes /clock fails the third time too)
        return ('the checker heard the samples but none of the /clock messages (it '
                "discovered the rig's /clock late)")
    if run.name == 'step' and str(final.get('message', '')).startswith(
            rig_contract.WATCHDOG_REASON):
        return f'the rig lost its commands ({final["message"]}): the graph stalled'
    stale = int(final.get('stale', 0) or 0)
    early = (run.ended_before_fault(profile) if run.name != 'step'
             else final.get('state') == 'aborted')
    if early and published and stale > STALE_FRACTION * published:
        # a loop that waits for its commands is not the loop designed: on the slow VMs of
        # 2026-11-30 the bridge's runs took 2.5-91 % of their samples with a stale command,
        # and some ran away before their fault (a force limit at 0.74 s, 451 of 497 stale)
        return (f'the graph fell behind the rig ({stale} of its {published} samples with a '
                f"stale command) and the run ended early ({final.get('message', '')})")
    before = run.fault_ns is None
    for s in run.statuses:
        if (s['name'] not in (run.rig_node, 'seft_runner') and s.get('state') == 'aborted'
                and str(s.get('message', '')).startswith(rig_contract.WATCHDOG_REASON)
                and (before or run.name == 'step')):
            return f'{s["name"]} lost an input ({s["message"]}): the graph stalled'
    return None


def _one_run(name: str, run_dir: Path, *, params: Mapping, profile: rc.CheckProfile, runner,
             tap: '_Tap', fault, commands, command_node: str,
             progress: Callable[[str], None]) -> '_Run':
    """One run of the check: the graph against the rig, the tap listening, the bag read."""
    reference = profile.step_reference() if name == 'step' else profile.sine_reference()
    run_dir.mkdir(parents=True)
    record = write_force_record(run_dir / 'force_record.csv', reference, profile.dt,
                                float(params['mass_kg']))
    p = check_parameters(params, profile, record, len(reference))
    run = _Run(name, p, rig=tap.rig)
    sender, fault_steps = None, profile.fault_steps
    if name == 'step' and p.get('rig_interface') == 'udp_bridge':
        sender = _SecondSender(p)
        fault, fault_steps = sender.fire, (profile.second_sender_step,)
    tap.reset(int(round(profile.dt * 1e9)), fault, fault_steps)
    progress(f'[{name}] {len(reference)} samples of {1e3 * profile.dt:g} ms, amplitude '
             f'{profile.amplitude_N:g} N')
    try:
        runner.run(p, run_dir, label=f'[{name}] ', commands=commands)
    except SeftError as exc:
        if not _expected_error(name, command_node, str(exc)):
            run.error = str(exc)
            progress(f'[{name}] {exc}')
    run.statuses = [dict(s) for s in runner.statuses]
    run.steps, run.stamps = np.array(tap.steps, int), np.array(tap.stamps, int)
    run.arrivals, run.names = np.array(tap.arrivals), tap.names or ()
    run.values = (np.array(tap.values, dtype=float) if tap.values
                  else np.zeros((0, len(MEASUREMENT_FIELDS))))
    run.fault_ns = tap.fault_ns
    run.fault_step = tap.fault_step if name != 'step' else None
    run.clock_ns = list(tap.clock_ns)
    run.unsealed, run.unsealed_frame = tap.unsealed, tap.unsealed_frame
    run.seal_text = tap.seal.describe() if tap.seal is not None else ''
    run.rig_unsealed = list(tap.rig_unsealed)
    if sender is not None:
        run.second_sender = sender.result()
    # what the checker heard (steps, stamps [ns], when the rig sent each, when the checker's
    # middleware received it and when the checker took it [s, system clock], values; the
    # fault's system time [ns], -1 if none; how many messages of an earlier run it dropped)
    np.savez(run_dir / 'live.npz', steps=run.steps, stamps_ns=run.stamps,
             arrival_s=run.arrivals, received_s=np.array(tap.received),
             handled_s=np.array(tap.handled), values=run.values,
             fault_ns=-1 if run.fault_ns is None else run.fault_ns, stale=tap.stale)
    _read_bag(run, run_dir / 'bag')
    return run


def fault_rig_command(name: str, params: Mapping) -> Callable[[Path], list[str]]:
    """The argv that starts seft's rig node with the fault `name` injected
    (``seft_plant_sim.fault_rig``; forked like seft's own nodes).

    Raises
    ------
    ParameterError
        An unknown fault, or a rig node that cannot take it (a UDP bridge: its controller
        injects it).
    """
    from seft_plant_sim.faults import check_supported, fault
    from seft_ros.cli.runner import FAULT_RIG_MODULE
    check_supported(fault(name), params)

    def argv(params_file: Path) -> list[str]:
        return [sys.executable, '-m', FAULT_RIG_MODULE, name, '--ros-args', '--params-file',
                str(params_file)]
    return argv


def run_rig_check(*, params: Mapping, out_dir: Path, profile: rc.CheckProfile,
                  rig_command: str | None = None, inject: str | None = None,
                  runs: Sequence[str] = RUNS, domain_id: int | None = None,
                  progress: Callable[[str], None] = print) -> RigCheckReport:
    """Check a rig node against the rig contract.

    Parameters
    ----------
    params : mapping
        The resolved parameters of the test (the rig's, the specimen's, ``dt``, ...).
    out_dir : Path
        A new directory: a folder per run (bag, logs, parameter file) and ``rig_check.json``.
    profile : CheckProfile
        The reference forces (amplitude [N], durations [s], sine [Hz]).
    rig_command : str, optional
        How to start the rig node (:func:`rig_command_factory`); default seft's rig node
        with ``params['rig_model']``.
    inject : str, optional
        A fault of :data:`seft_plant_sim.faults.FAULTS` to inject into seft's rig node
        (:func:`fault_rig_command`; not with `rig_command`).
    runs : sequence of str
        Which of :data:`RUNS` to run (the checks of the others are not measured).
    domain_id : int, optional
        ROS domain (default as ``seft run``).
    progress : callable(str)
        Receives progress lines.

    Returns
    -------
    RigCheckReport

    Raises
    ------
    InputError
        An unknown run name, a bad ``rig_command``, or both it and `inject`.
    ParameterError
        A fault `inject` the rig node cannot take.
    SeftError
        No ROS domain could be claimed (as ``seft run``).
    """
    from seft_ros.cli.api import open_runner
    unknown = [r for r in runs if r not in RUNS]
    if unknown or not runs:
        raise InputError(f'--runs {",".join(runs)}: expected some of {", ".join(RUNS)}')
    if inject and rig_command:
        raise InputError("--inject and --rig-command: the fault goes into seft's own rig "
                         'node; give one of them')
    argv = fault_rig_command(inject, params) if inject else rig_command_factory(rig_command)
    if inject:
        from seft_plant_sim.faults import FAULTS
        progress(f'fault injected into the rig node: {inject} ({FAULTS[inject].description})')
    t_start = time.monotonic()
    graph = Graph.from_parameters(params)
    rig = graph.rigs[0]
    kind = rig_contract.command_kind(params)
    command_node = (graph.controller_nodes()[0] if kind == rig_contract.COMMAND_KINDS[0]
                    else graph.builder_of(rig))
    runner, claim = open_runner(domain_id=domain_id, progress=progress)
    _above_the_graph(int(params.get('realtime_priority', 0)), progress)
    done: dict[str, _Run] = {}
    try:
        tap = _Tap(runner, graph)
        for name in [r for r in RUNS if r in runs]:
            for attempt in range(1 + FAULT_RETRIES):
                run_dir = out_dir / (name if attempt == 0 else f'{name}-{attempt + 1}')
                run = _one_run(name, run_dir, params=params, profile=profile, runner=runner,
                               tap=tap, fault=None if name == 'step' else _fault_of(
                                   name, runner, command_node, tap),
                               commands={graph.rig_nodes()[0]: argv} if argv else None,
                               command_node=command_node, progress=progress)
                why = _disturbed(run, profile)
                if why is None:
                    break
                progress(f'[{name}] {why}; once more')
            done[name] = run
            # (a rig that refused the run before its first sample, saying why, ends it
            # without an error: the runner's watch takes its final report)
            if name == 'step' and (run.error is not None or run.sample_count() == 0):
                progress('the step run failed: the other runs are not run')
                break
    finally:
        runner.close()
        claim.close()
    results = evaluate(done, params=params, profile=profile, command_kind=kind)
    report = RigCheckReport(results, time.monotonic() - t_start, out_dir, inject)
    (out_dir / 'rig_check.json').write_text(json.dumps({
        'contract': rig_contract.CONTRACT, 'passed': report.passed, 'injected_fault': inject,
        'wall_s': report.wall_s, 'amplitude_N': profile.amplitude_N,
        'checks': [{'name': r.name, 'passed': r.passed, 'measured': r.measured,
                    'values': r.values} for r in results],
        'errors': {n: r.error for n, r in done.items() if r.error}},
        indent=1, default=_json_default))
    return report


def _json_default(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return None if not math.isfinite(value) else float(value)
    return str(value)


def _structure_bag(path: Path, run: _Run) -> SimpleNamespace:
    """The bag of a structure rig's run as the checks read a bag (``samples`` of the rig's
    four sensor topics and command topic by step, ``node_params``, ``statuses``), from
    :func:`~seft_ros.analysis.bag.read_run`."""
    from seft_ros.analysis.bag import read_run
    data = read_run(path)
    r = data.rigs[run.rig]
    series = [r.measured_force_N, r.displacement_m, r.velocity_m_s, r.acceleration_m_s2]
    topics = list(run.sensor_topics())
    kind = rig_contract.command_kind(run.params)
    series.append(r.valve_command_V if kind == rig_contract.COMMAND_KINDS[0]
                  else r.reference_force_N)
    topics.append(scoped(rig_contract.command_signal(kind).name, run.rig))
    return SimpleNamespace(
        samples={t: dict(enumerate(np.asarray(s, dtype=float).tolist()))
                 for t, s in zip(topics, series) if s is not None},
        node_params=data.extra.get('node_params', {}),
        statuses=data.extra.get('node_statuses', []))


def _read_bag(run: _Run, bag: Path) -> None:
    from seft_ros.analysis.bag import read_signals
    run.bag_closed = (bag / 'metadata.yaml').is_file()
    if not bag.exists():
        return
    try:
        run.bag = _structure_bag(bag, run) if run.rig else read_signals(bag)
    except SeftError as exc:
        run.error = run.error or f'bag: {exc}'
        return
    closed = any(s['name'] == 'recorder' and s.get('state') == 'closed'
                 for s in run.bag.statuses)
    run.bag_closed = run.bag_closed and closed
    # the bag holds every report, also those this checker missed
    if not run.final():
        run.statuses = run.bag.statuses


def _cut_short(step: _Run, n: int, needed: int, command_kind: str) -> str | None:
    """Why the step run says nothing of the signals: the rig ended it before the static
    force had held (`needed` samples of `n`), or None."""
    count = step.sample_count()
    if count >= needed:
        return None
    final = step.final() or {}
    why = (f"the rig ended the step run {final.get('state', '')} after {count} of {n} "
           f"samples, before the static force held ({final.get('message', 'no final report')})")
    if command_kind == rig_contract.COMMAND_KINDS[0] and 'force limit' in why:
        why += ('; a force loop closed on a load cell of the wrong sign or unit runs away: '
                'check the force first')
    return why


def _step_checks(step: _Run, *, params: Mapping, profile: rc.CheckProfile, command_kind: str,
                 sine: list | None) -> dict:
    """The checks of the step run (contract, clock, stamps, measurement, the signals, stuck
    sensor, sensor noise, command timing)."""
    dt = profile.dt
    out = {}
    rig_params = step.bag.node_params.get(step.rig_node) if step.bag is not None else None
    out['contract'] = rc.check_contract(step.ready(), rig_params, command_kind,
                                        step.rig_unsealed, step.seal_text)
    latency = out['contract'].values.get('command_latency_s', math.nan)
    final = step.final() or {}
    expected = int(final.get('published', step.params['n_steps']))
    out['clock'] = rc.check_clock(step.steps, step.arrivals, dt, clock_ns=step.clock_ns)
    out['stamps'] = rc.check_stamps(step.stamps, step.arrivals, dt, expected=expected,
                                    t0_ns=step.t0_ns())
    n = int(step.params['n_steps'])
    record = step.record(n)
    live_rows = np.full((step.steps.size, len(MEASUREMENT_FIELDS)), np.nan)
    inside = (step.steps >= 0) & (step.steps < n)
    live_rows[inside] = record[step.steps[inside]]
    out['measurement'] = rc.check_measurement(step.names, step.values, live_rows,
                                              unsealed=step.unsealed,
                                              frame_id=step.unsealed_frame,
                                              seal=step.seal_text)
    fields = step.fields(n, record)
    why = _cut_short(step, n, profile.hold.stop, command_kind)
    if fields is None or why is not None:
        why = why or step.error or 'no samples of the step run'
        for name in (*rc.SIGNAL_CHECKS, 'swapped fields', 'stuck sensor', 'sensor noise',
                     'command timing'):
            out[name] = rc.not_run(name, why)
        return out
    for r in rc.check_signals(fields, dt=dt, amplitude_N=profile.amplitude_N,
                              stiffness_N_per_m=float(params['stiffness_N_per_m']),
                              hold=profile.hold, rest=profile.rest):
        out[r.name] = r
    out['stuck sensor'] = rc.check_stuck(fields, sine)
    out['sensor noise'] = rc.check_noise(
        fields[0], fields[3], profile.quiet, dt=dt, alpha=float(params.get('alpha', 0.0)),
        mass_kg=float(params['mass_kg']), cutoff_hz=monitor_cutoff_hz(params),
        threshold=float(params['monitor_threshold']), floor_N=float(params['monitor_floor_N']))
    if math.isfinite(latency):
        command = step.command(scoped(rig_contract.command_signal(command_kind).name,
                                      step.rig), n)
        out['command timing'] = rc.check_command_timing(
            command, fields[0], profile.quiet, profile.onset_step, dt, latency,
            profile.amplitude_N)
    else:
        out['command timing'] = rc.not_run('command timing', 'no command latency')
    return out


def evaluate(runs: Mapping[str, _Run], *, params: Mapping, profile: rc.CheckProfile,
             command_kind: str) -> list:
    """The results of every check of the rig (:func:`~seft_ros.core.rig_check.checks_for`,
    in order) from the runs done; a check whose run failed or was not run is a failure that
    says why.

    The signals are judged on the live measurement the graph used (the checker's own
    subscription), completed from the bag where the checker missed a sample."""
    dt = profile.dt
    out = {}
    step = runs.get('step')
    onset = profile.onset_step
    sine = None
    for run_name in rc.FAULT_RUNS:
        run = runs.get(run_name)
        fault = run.fault_step_of(profile) if run is not None else 0
        fields = (run.fields(fault)
                  if run is not None and run.sample_count() >= fault else None)
        if fields is not None:
            sine = [s[onset:fault] for s in fields]
            break
    if step is None:
        for name in rc.CHECKS[:rc.CHECKS.index('command timing') + 1]:
            out[name] = rc.not_run(name, 'the step run was not run')
        latency = math.nan
    else:
        out.update(_step_checks(step, params=params, profile=profile,
                                command_kind=command_kind, sine=sine))
        latency = out['contract'].values.get('command_latency_s', math.nan)
    for run_name, check in rc.FAULT_RUNS.items():
        run = runs.get(run_name)
        if run is None:
            out[check] = rc.not_run(check, f'the {run_name} run was not run')
            continue
        if run.error is not None and run.final() is None:
            out[check] = rc.not_run(check, run.error)
            continue
        early = run.ended_before_fault(profile)
        if early is not None:
            out[check] = rc.not_run(check, early)
            continue
        late = run.fault_late_s(profile)
        if late is not None and late > LATE_FAULT_S:
            out[check] = rc.not_run(check, f'the fault came {late:.2f} s after its sample '
                                    '(the checker heard the rig late)')
            continue
        fields = run.fields(run.sample_count())
        f, v = (fields[0], fields[2]) if fields is not None else (np.zeros(0),) * 2
        cycle = int(round(1.0 / (profile.sine_hz * dt)))
        fault = run.fault_step_of(profile)
        lat = latency if math.isfinite(latency) else rig_contract.command_latency_s(params)
        out[check] = rc.check_safe_state(
            check, final=run.final(), command_kind=command_kind, time_s=np.arange(f.size) * dt,
            force_N=f, velocity_m_s=v, quiet=slice(0, onset), before=slice(fault - cycle,
                                                                            fault),
            fault_ns=run.fault_ns, t0_ns=run.t0_ns(), params=run.params, latency_s=lat,
            amplitude_N=profile.amplitude_N,
            reason_prefix=rig_contract.WATCHDOG_REASON if run_name == 'watchdog' else '')
    udp = params.get('rig_interface') == 'udp_bridge'
    if udp and step is None:
        out[rc.SECOND_SENDER] = rc.not_run(rc.SECOND_SENDER, 'the step run was not run')
    elif udp:
        out[rc.SECOND_SENDER] = rc.check_second_sender(
            step.second_sender, step.final(), int(step.params['n_steps']))
    out['final status'] = rc.check_final_status(
        {n: r.final() for n, r in runs.items()},
        int(step.params['n_steps']) if step is not None else 0,
        {n: r.unsealed_final() for n, r in runs.items() if r.unsealed_final() is not None})
    out['bag closed'] = rc.check_bags_closed({n: r.bag_closed for n, r in runs.items()})
    return [out[name] for name in rc.checks_for(udp)]


def main_lines(report: RigCheckReport, rig: str = '') -> list[str]:
    """The lines ``seft rig-check`` prints: one per check, then the verdict (naming the
    `rig` of a structure)."""
    lines = [rc.format_line(r) for r in report.results]
    failed = [r.name for r in report.results if not r.passed]
    who = f'rig-check {rig}' if rig else 'rig-check'
    lines.append(f'{who}: {len(report.results) - len(failed)} of {len(report.results)} '
                 'checks passed' + (f'; failed: {", ".join(failed)}' if failed else '')
                 + f' ({report.wall_s:.0f} s; runs in {report.out_dir}'
                 + (f'; fault injected: {report.injected_fault}' if report.injected_fault
                    else '') + ')')
    return lines

