"""The rig contract: what a rig node of the seft graph is, as data (versioned).

A rig node is the graph's actuator, specimen and sensors behind one ROS 2 node: seft's
simulated rigs (``seft_plant_sim.rig_node``), the UDP bridge to a laboratory's real-time
controller, or a lab's own node in any language that talks DDS. This module says what every
one of them must do, so that ``seft rig-check`` can check a rig against it step by step and a
bag can say which version its rig followed (the rig reports :data:`CONTRACT` in its status).

Nothing here is defined twice: topic names, message types, fields and units come from
:mod:`seft_msgs_py.signals`, QoS from :mod:`seft_msgs_py.topics` (read on demand: it imports
rclpy), parameters from :mod:`seft_msgs_py.parameters`, status states from ``signals``. What
this module adds is the rig's side of each: which topics it publishes and takes, when, the
status keys it reports, its timing promises, its safe state and the parameters it must
accept. ``docs/rig_contract.md`` holds the page; its tables are :func:`markdown_tables`
(checked by the tests).

Imports no rclpy.

Versioning: :data:`VERSION` is ``MAJOR.MINOR``. A change that can make a conforming rig fail
(a new obligation, a changed unit or timing) raises MAJOR; an addition a rig may ignore (a new
optional status key) raises MINOR. 2.0 (issue 42): a rig seals its measurement with the run's
seal and takes only sealed commands (:data:`SEAL_RULE`, :mod:`seft_msgs_py.provenance`); the
controller behind the UDP bridge follows the session rules
(``seft_plant_sim.udp_layout.SESSION_RULES``); with it (issue 39, an addition on its own
1.1) the ranges of the sensors and the capacity of the actuator (:data:`RANGE_PARAMETERS`).
3.0: a rig seals its status reports too and acts only on sealed ones
(:data:`STATUS_SEAL_RULE`): the graph drops the reports of a rig of 2.0, its ready and final
ones too (:func:`unsealed_status_advice` says what to change).
"""

from dataclasses import dataclass
import math
from typing import Mapping

from seft_msgs_py import parameters
from seft_msgs_py import signals as sig

__all__ = [
    'VERSION', 'CONTRACT', 'CONTRACT_KEY', 'TopicRole', 'PUBLISHES', 'SUBSCRIBES',
    'StatusKey', 'STATUS_KEYS', 'STATES', 'REQUIRED_PARAMETERS', 'COMMAND_SOURCE_LAG',
    'COMMAND_KINDS', 'command_kind', 'command_signal', 'command_latency_s', 'SAFE_HOLD_S',
    'safe_stop_s', 'safe_confirm_s',
    'reaction_limit_s', 'first_effect_step', 'qos_of', 'markdown_tables', 'is_compatible',
    'WATCHDOG_REASON', 'BRIDGE_REASON', 'PROGRESS_EVERY', 'SEAL_RULE', 'STATUS_SEAL_RULE',
    'FOREIGN_REASON', 'unsealed_status_advice',
    'RANGE_PARAMETERS',
    'INTERRUPT_REASON',
    'runner_interrupt',
    'is_runner_interrupt',
]

#: Version of the contract (``MAJOR.MINOR``; module notes).
VERSION = '3.0'
#: What a conforming rig reports under :data:`CONTRACT_KEY` in its status: name and version.
CONTRACT = f'seft-rig/{VERSION}'
#: The key of the contract in the rig's ``/seft/status`` values (ready and final reports).
CONTRACT_KEY = 'contract'

#: The rig's command kinds (``seft_msgs_py.interface``): the valve voltage of the force servo
#: controller (the graph closes the force loop) or the reference force (the rig closes it).
COMMAND_KINDS = ('valve_command_V', 'reference_force_N')
#: A command stamped ``t_j`` is computed from sample ``j - lag``: the valve command ``u[j]``
#: from sample j, the reference force ``f_r[j]`` from sample j - 1 (paper Eq. 5.3: the
#: acceleration measured at the previous step).
COMMAND_SOURCE_LAG = {'valve_command_V': 0, 'reference_force_N': 1}
#: Real time: after its command has ramped to zero the rig keeps sampling at least this long
#: before it reports 'aborted' [s], so that the safe state is in the bag.
SAFE_HOLD_S = 0.05
#: A rig reports 'running' at sample 0 and every this many samples [-].
PROGRESS_EVERY = 250
#: The final message of a rig that went to its safe state because no command came starts so.
WATCHDOG_REASON = 'watchdog:'
#: The final message of a rig behind the UDP bridge that ended the run on what it saw of its
#: controller or the link to it (silence, datagrams lost or reordered, the controller's own
#: safe state, a refusal) starts so. Such a reason is the run's rather than another node's
#: watchdog, which the controller's silence trips first (the graph's inputs stop with it).
BRIDGE_REASON = 'udp_bridge: '
#: The final message of a rig (or the abort of another node) that dropped a message without
#: the run's seal starts so, and names the topic and the publisher.
FOREIGN_REASON = 'foreign publisher on '
#: The abort of ``seft run``'s runner when the operator interrupts it (Ctrl-C, SIGTERM):
#: with the ``signal`` of a node stopped by a signal, what marks a run as interrupted (the
#: report's reason; not an unstable run).
INTERRUPT_REASON = 'interrupted (Ctrl-C or SIGTERM at the runner)'


def runner_interrupt(signame: str) -> str:
    """The abort reason of ``seft run``'s runner stopped by the operator's signal `signame`
    (``'SIGINT'``, ``'SIGTERM'``, ``'SIGHUP'``): ``'interrupted (SIGINT at the runner)'``."""
    return f'interrupted ({signame} at the runner)'


def is_runner_interrupt(message: str) -> bool:
    """Whether an abort reason is the runner's interrupt (:func:`runner_interrupt`, or
    :data:`INTERRUPT_REASON` of bags recorded before the signal was named)."""
    return message == INTERRUPT_REASON or (message.startswith('interrupted (')
                                           and message.endswith(' at the runner)'))
#: What a rig does with the run's seal (``run_token``, ``message_auth``, ``auth_key_file``;
#: :mod:`seft_msgs_py.provenance`), as the page says it.
SEAL_RULE = ("header.frame_id of every measurement is the run's seal: 'actuator#' + "
             "run_token (message_auth hmac: 'actuator#' + the first 32 hex digits of "
             'HMAC-SHA256(key, provenance.mac_input(run_token, topic, stamp, values))); '
             "run_token 'none': 'actuator'. A command whose frame id is not the run's seal "
             'of it is dropped, never applied, and the run ends safely with a reason '
             f"starting {FOREIGN_REASON!r} that names the topic and the publisher")
#: The run's seal on the status reports (``/seft/status``; :mod:`seft_msgs_py.provenance`).
STATUS_SEAL_RULE = ("hardware_id of every status report is the run's seal: 'seft#' + "
                    "run_token (message_auth hmac: 'seft#' + the first 32 hex digits of "
                    'HMAC-SHA256(key, provenance.status_mac_input(run_token, /seft/status, '
                    "name, level, message, key/values))); run_token 'none': 'seft'. Another "
                    "node's report without the run's seal (another run's node or one started "
                    'by hand on the domain) is dropped: it never ends the run nor sends the '
                    'rig to its safe state; the graph counts it and names its publisher once')


def unsealed_status_advice(contract: str | None) -> str:
    """What a rig whose status reports do not carry the run's seal must change, in words
    (``seft rig-check``'s contract line, ``seft run``'s warning): typically a rig written to
    contract 2.0, which sealed its measurement but not its reports.

    Parameters
    ----------
    contract : str or None
        The contract the rig's unsealed ready report names, None if it named none.
    """
    who = f'a rig of {contract!r}' if contract else 'a rig'
    return (f"{who} that does not seal its status reports: the graph drops them, its ready "
            f"and final reports too; {CONTRACT} asks the run's seal in hardware_id of every "
            "report ('seft#' + run_token; with message_auth hmac 'seft#' + the HMAC of "
            'provenance.status_mac_input) and that the rig act only on reports that carry '
            "it (docs/rig_contract.md: the run's seal)")


@dataclass(frozen=True)
class TopicRole:
    """One topic on the rig's side of the graph.

    Attributes
    ----------
    signal : Signal
        The topic (name, ROS type, field, unit: :mod:`seft_msgs_py.signals`).
    when : str
        When the rig publishes it, or what it does with it.
    condition : str
        Which rigs: 'all', 'valve' (command kind ``valve_command_V``), 'force'
        (``reference_force_N``), 'real time' (mode realtime), 'clock master' (the first rig
        of a run).
    """

    signal: sig.Signal
    when: str
    condition: str = 'all'


#: What a rig publishes (topic names relative to its namespace but /clock and /seft/status).
PUBLISHES = (
    TopicRole(sig.MEASUREMENT, 'every sample k, stamped t_k = k dt exactly (integer ns), '
              f'name = {", ".join(sig.MEASUREMENT_FIELDS)} (SI: N, m, m/s, m/s^2; REP-103, '
              "x positive in extension), header.frame_id the run's seal (below)"),
    TopicRole(sig.record_signal(sig.record_streams_of('rig')[0]),
              'rows [step, force N, displacement m, velocity m/s, acceleration m/s^2] every '
              f"{sig.RECORD_ROWS} samples and before the final status (the bag's four "
              'sensor topics)'),
    TopicRole(sig.CLOCK, f't_k every {sig.CLOCK_EVERY} samples', 'clock master'),
    TopicRole(sig.record_signal(sig.record_streams_of('rig')[1]), 'one timing record per '
              f'sample in rows [step, {", ".join(sig.TIMING_FIELDS)}] (the bag\'s '
              '/seft/timing/rig)', 'real time'),
    TopicRole(sig.STATUS, "'ready' (with the keys below) until the graph is up, 'running' "
              f'at start and every {PROGRESS_EVERY} samples, one final report (done, '
              'aborted, failed) with the reason in message'),
    TopicRole(sig.NODE_PARAMETERS, 'once at start: {"node": "rig", "parameters": {...}} with '
              'at least the required parameters'),
)

#: What a rig takes.
SUBSCRIBES = (
    TopicRole(sig.VALVE_COMMAND, 'u[j] stamped t_j: held from t_j, acts after '
              "command_latency_s (module notes); only with the run's seal (below)", 'valve'),
    TopicRole(sig.REFERENCE_FORCE, 'f_r[j] stamped t_j (from sample j-1): held from t_j, '
              "acts after command_latency_s; only with the run's seal (below)", 'force'),
    TopicRole(sig.STATUS, "another node's 'aborted' or 'failed': safe state (real time) or "
              'end (lockstep)'),
    TopicRole(sig.NODE_PARAMETERS, 'the graph starts once every node has published its '
              'parameters and the shared ones agree'),
)

#: The states of the rig's reports, in the order a run goes through them.
STATES = (sig.STATE_READY, sig.STATE_RUNNING, sig.STATE_DONE, sig.STATE_ABORTED,
          sig.STATE_FAILED)


@dataclass(frozen=True)
class StatusKey:
    """A key of the rig's ``/seft/status`` values (``diagnostic_msgs/KeyValue``, text).

    Attributes
    ----------
    key : str
    states : tuple of str
        The reports that carry it.
    unit : str
    meaning : str
    condition : str
        As :attr:`TopicRole.condition`.
    """

    key: str
    states: tuple
    unit: str
    meaning: str
    condition: str = 'all'


_FINAL = (sig.STATE_DONE, sig.STATE_ABORTED, sig.STATE_FAILED)
#: The status keys a rig reports (every value is text, as DiagnosticStatus holds it).
STATUS_KEYS = (
    StatusKey('state', STATES, '', 'ready, running, done, aborted or failed'),
    StatusKey(CONTRACT_KEY, (sig.STATE_READY,) + _FINAL, '',
              f'the contract the rig follows, {CONTRACT!r}'),
    StatusKey('command_kind', (sig.STATE_READY,), '', ' or '.join(COMMAND_KINDS)),
    StatusKey('command_latency_s', (sig.STATE_READY,), 's', 'from the stamp t_j of a command '
              'to the instant it starts acting at the actuator (lockstep, and real time when '
              'it arrived in time)'),
    StatusKey('n_steps', (sig.STATE_READY, sig.STATE_RUNNING) + _FINAL, '',
              'samples of the run'),
    StatusKey('mode', (sig.STATE_READY,) + _FINAL, '', 'lockstep or realtime'),
    StatusKey('step', (sig.STATE_RUNNING,) + _FINAL, '', 'the current sample'),
    StatusKey('time_s', (sig.STATE_RUNNING,) + _FINAL, 's', 't_k of that sample'),
    StatusKey('t0_ns', (sig.STATE_RUNNING,), 'ns', 'system-clock time of sample 0 (the '
              'others time their inputs against it)', 'real time'),
    StatusKey('abort_at_s', (sig.STATE_ABORTED,), 's', 'sample time at which the rig entered '
              'its safe state', 'real time'),
    StatusKey('published', _FINAL, '', 'samples published'),
    StatusKey('ended_by', (sig.STATE_ABORTED,), '', 'the node whose abort ended the '
              "rig's run (absent: the rig's own abort). Lockstep: a rig ending on "
              "another rig's abort first publishes the samples the run holds, up to "
              "that rig's `published`", 'another node aborted'),
)

#: The parameters every rig must accept (declare) and publish on /seft/node_parameters: the
#: graph checks the shared ones against the other nodes', the analysis takes the specimen and
#: the clock from the rig (``parameters.VALUE_SOURCE``).
REQUIRED_PARAMETERS = (
    'dt', 'mode', 'n_steps', 'rig_model', 'mass_kg', 'stiffness_N_per_m', 'damping_N_s_per_m',
    'stroke_limit_m', 'force_limit_N', 'watchdog_timeout_s', 'safe_ramp_s', 'realtime_output',
    'wait_for_recorder', 'recorder_window_steps', 'run_token', 'message_auth', 'auth_key_file',
)


#: The ranges of the rig's sensors and the capacity of its actuator (since 1.1): a rig declares
#: and publishes them (the graph takes the configuration's values from a rig that does not);
#: the builder flags and counts each reading at its range, its compensator's identifications
#: skip it, and the pre-run check compares the reference's peaks with them
#: (``seft_msgs_py.sensor_range``, ``seft_ros.analysis.range_check``). A simulated rig's
#: sensors saturate there.
RANGE_PARAMETERS = ('force_range_N', 'displacement_range_m', 'velocity_range_m_s',
                    'accelerometer_range_m_s2', 'actuator_velocity_limit_m_s')


def command_kind(params: Mapping) -> str:
    """The command kind of the rig of `params`: the valve voltage where the graph has a force
    servo controller for it (``parameters.graph_nodes``), else the reference force."""
    nodes = parameters.graph_nodes(params.get('rig_model', 'servohydraulic'))
    return COMMAND_KINDS[0] if 'force_servo_controller' in nodes else COMMAND_KINDS[1]


def command_signal(kind: str) -> sig.Signal:
    """The topic that carries a command of `kind` (one of :data:`COMMAND_KINDS`)."""
    return {COMMAND_KINDS[0]: sig.VALVE_COMMAND, COMMAND_KINDS[1]: sig.REFERENCE_FORCE}[kind]


def command_latency_s(params: Mapping) -> float:
    """The command latency seft's rig models promise [s]: ``io_latency_s`` of a valve rig
    (DAQ, computation, D/A, amplifier), ``tau_s`` of the delay rig (its actuator delay)."""
    if command_kind(params) == COMMAND_KINDS[0]:
        return float(params['io_latency_s'])
    return float(params['tau_s'])


def safe_stop_s(params: Mapping) -> float:
    """How long a rig's safe stop lasts from its safe state's start to its final status [s]:
    the commands already output still reach the actuator (:func:`command_latency_s`), then
    the ramp (``safe_ramp_s``) and the hold after it (:data:`SAFE_HOLD_S`). 0 in lockstep
    mode (an abort ends the run at once: a simulation has nothing to ramp)."""
    if params.get('mode') != 'realtime':
        return 0.0
    return command_latency_s(params) + float(params['safe_ramp_s']) + SAFE_HOLD_S


def safe_confirm_s(params: Mapping) -> float:
    """How long a rig behind the UDP bridge waits, from its request, for its controller to
    report its safe state (state 3, the command at zero) [s]: :func:`safe_stop_s` (the
    commands already output, the ramp ``safe_ramp_s``, and :data:`SAFE_HOLD_S`) plus
    ``watchdog_timeout_s`` (the report is a datagram like any other, and the PC allows any
    datagram that long). Past it the run ends, and its final status says that the safe
    state was NOT confirmed by the controller (``safe_confirmed`` 0). 0 in lockstep mode."""
    if params.get('mode') != 'realtime':
        return 0.0
    return safe_stop_s(params) + float(params['watchdog_timeout_s'])


def first_effect_step(stamp_step: int, latency_s: float, dt: float) -> int:
    """The first sample that can show a command stamped `stamp_step` [-].

    A command stamped ``t_j`` acts from ``t_j + L`` (``L`` = `latency_s` [s]); the sample
    ``k`` is taken at ``t_k`` after what acts at ``t_k`` took effect (``Rig.measure``), so the
    first sample that can depart from the previous command is ``j + ceil(L / dt)``.

    Raises
    ------
    ValueError
        `latency_s` negative or not finite, or `dt` not positive.
    """
    if not (math.isfinite(latency_s) and latency_s >= 0):
        raise ValueError(f'command_latency_s={latency_s!r}: expected a float >= 0')
    if not dt > 0:
        raise ValueError(f'dt={dt!r}: expected a float > 0')
    return stamp_step + math.ceil(latency_s / dt - 1e-9)


def reaction_limit_s(params: Mapping) -> float:
    """The longest a rig in real time may take to enter its safe state [s]: after an abort on
    /seft/status is published, or after its last command (its watchdog):
    ``watchdog_timeout_s + 2 dt`` (one tick to notice, one of catching up)."""
    return float(params['watchdog_timeout_s']) + 2.0 * float(params['dt'])


def is_compatible(reported: str) -> bool:
    """Whether a rig that reports `reported` (``'seft-rig/MAJOR.MINOR'``) follows this
    contract's major version."""
    name, _, version = str(reported).partition('/')
    major = VERSION.split('.')[0]
    return name == 'seft-rig' and version.split('.')[0] == major


def qos_of(signal: sig.Signal) -> str:
    """The QoS of a topic as one line (reliability, durability, history depth), from
    :mod:`seft_msgs_py.topics` (imports rclpy)."""
    from seft_msgs_py.topics import spec_for
    q = spec_for(signal).qos
    return (f'{q.reliability.name.lower()}, {q.durability.name.lower()}, '
            f'keep last {q.depth}')


def _md(text: str) -> str:
    return text.replace('|', '\\|')


def markdown_tables() -> str:
    """The page's tables (topics, status keys, required parameters, the sensors' ranges and
    the actuator's capacity, the seal), generated from this module."""
    rows = ['| direction | topic | type | field, unit | QoS | when | rigs |',
            '|---|---|---|---|---|---|---|']
    for direction, roles in (('publishes', PUBLISHES), ('subscribes', SUBSCRIBES)):
        for r in roles:
            s = r.signal
            rows.append(f'| {direction} | `{s.name}` | `{s.type_name}` | '
                        f'{s.field or "-"}{", " + s.unit if s.unit else ""} | {qos_of(s)} | '
                        f'{_md(r.when)} | {r.condition} |')
    keys = ['| status key | in | unit | meaning | rigs |', '|---|---|---|---|---|']
    for k in STATUS_KEYS:
        keys.append(f'| `{k.key}` | {", ".join(k.states)} | {k.unit or "-"} | {_md(k.meaning)}'
                    f' | {k.condition} |')
    tables = [rows, keys]
    for names in (REQUIRED_PARAMETERS, RANGE_PARAMETERS):
        params = ['| parameter | unit | allowed | meaning |', '|---|---|---|---|']
        for name in names:
            s = parameters.spec(name)
            params.append(f'| `{name}` | {s.unit or "-"} | {_md(s.expected())} | '
                          f'{_md(s.description)} |')
        tables.append(params)
    tables.append(["| the run's seal | the rig |", '|---|---|',
                   f'| on its measurement and on the commands it takes | {_md(SEAL_RULE)} |',
                   f'| on its status reports and on those it acts on | '
                   f'{_md(STATUS_SEAL_RULE)} |'])
    return '\n\n'.join('\n'.join(t) for t in tables)
