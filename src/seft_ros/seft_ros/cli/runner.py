"""Start the node graph of one run as separate processes, watch it, shut it down cleanly.

The runner is itself a small rclpy node (``seft_runner``) that listens to ``/seft/status``
for readiness, progress, the end of the run and abort reasons, and publishes there only to
end a run safely: when one of its nodes died, or on Ctrl-C.

Start-up: every node at once (the recorder, the ground-motion publisher, the reference-force
builder, the force servo controller (not for the 'delay' rig) and the rig). The rig starts
stepping only once every node of its graph has sent its parameters, the recorder listens and,
in real time, every input path is matched at both ends, so nothing is published before the
recorder listens. The run is over when the recorder reports the bag 'closed'.

Several hosts: a runner may start only some of the nodes (``nodes``); the others are started
by the runner of another host, in the same ROS domain. The runner waits until every node of
the graph, local or remote, has reported ready, and ends when the bag is closed or, where the
recorder runs elsewhere, when the run is over and its own nodes have exited. A host gone
silent (its link cut, or down) ends the run on the other side: ``REFERENCE_SILENT_S``.

Only the run commands its rig (issue 42): each run gets a new run token
(:mod:`seft_msgs_py.provenance`, the nodes seal their messages with it), and every
``AUDIT_EVERY_S`` while the run goes the runner checks the publishers of every topic of
the run against the graph it started (:meth:`~seft_msgs_py.graph.Graph.foreign_publishers`;
publishers that were there before it started its nodes, a previous run's not yet forgotten,
are not the run's either way and are left out): a foreign publisher on a topic that commands
the rig ends the run (an abort on ``/seft/status`` that names it and the topic), on any other
topic it is a named warning, once each.
"""

from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time
from typing import Callable

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from seft_msgs_py import parameters
from seft_msgs_py.clock import OFFSET_ENV
from seft_msgs_py.convert import (
    STATE_ABORTED,
    STATE_CLOSED,
    STATE_DONE,
    STATE_FAILED,
    STATE_READY,
    STATE_RUNNING,
    status_msg,
    status_values,
)
from seft_msgs_py.dds import use_seft_profile
from seft_msgs_py.errors import Interrupted, SeftError
from seft_msgs_py.graph import UNKNOWN_NODE, Graph, split_qualified
from seft_msgs_py.node_support import MISMATCH_ABORT
from seft_msgs_py.provenance import NONE as NO_TOKEN
from seft_msgs_py.provenance import RunSeal, new_run_token
from seft_msgs_py.rig_contract import (
    CONTRACT_KEY,
    FOREIGN_REASON,
    is_compatible,
    runner_interrupt,
    unsealed_status_advice,
)
from seft_msgs_py.signals import CLOCK, RUN_PARAMETERS
from seft_msgs_py.stopping import (
    RUNNER_PID_ENV,
    STOP_SIGNALS,
    raise_stop,
    signal_name,
    spinning,
)
from seft_msgs_py.topics import NODE_PARAMETERS, STATUS, TOPICS
from seft_ros.cli.config import write_params_file
from seft_ros.cli.partition import PROCESSES
from seft_ros.cli.spawn import prepare as prepare_nodes
from seft_ros.cli.spawn import start_node

__all__ = ['NODE_MODULES', 'RunOutcome', 'GraphRunner', 'node_command', 'RUNNER_NAME']

#: Executable module of each node (``ros2 run <package> <node>`` on a full ROS install).
NODE_MODULES = {
    'recorder': 'seft_ros.nodes.recorder',
    'ground_motion_publisher': 'seft_ros.nodes.ground_motion_publisher',
    'reference_force_builder': 'seft_ros.nodes.reference_force_builder',
    'force_servo_controller': 'seft_ros.nodes.force_servo_controller',
    'rig': 'seft_plant_sim.rig_node',
}

#: The module of the process that holds the nodes of one rig's loop (``--processes loop``).
LOOP_MODULE = 'seft_ros.nodes.loop'
#: The module of seft's rig node with a fault injected (``seft rig-check --inject``).
FAULT_RIG_MODULE = 'seft_plant_sim.fault_rig'
#: What the fork server imports before the first node starts (cli/spawn.py).
PRELOAD = (*NODE_MODULES.values(), LOOP_MODULE, FAULT_RIG_MODULE)
#: The nodes ``--processes loop`` puts in a rig's loop process.
LOOP_KINDS = ('reference_force_builder', 'force_servo_controller', 'rig')

#: How long a node that exited cleanly without a report may take to be heard [s].
EXITED_GRACE_S = 3.0
#: Longest wait for the nodes to report ready [s].
STARTUP_TIMEOUT_S = 60.0
#: Longest wait for the nodes of another host to report ready [s] (an operator starts them).
REMOTE_TIMEOUT_S = 600.0
#: Longest wait for the bag to close after the runner ended a run (a node died, Ctrl-C) [s].
END_TIMEOUT_S = 15.0
#: How long a rig that exited with an error before its first sample may take to be heard
#: reporting why [s] (its final report and its exit race to the runner: the CI of 08955b2
#: saw the exit first, and the run was named a node's death instead of the rig's refusal).
REPORT_GRACE_S = 1.0
#: A host without the recorder whose nodes have all ended ends them at once when it has not
#: heard the host with the recorder (its runner pings every host once a second) for this
#: long [s]: the link or that host is lost, and nothing more reaches the bag. Otherwise its
#: nodes linger until the recorder closes the bag (``RECORDER_WAIT_S`` of
#: seft_msgs_py.node_support, 20 s): a lab whose link was cut waited those 20 s. The host with
#: the recorder takes a host that has not answered its pings, and whose nodes have not
#: reported, for this long for lost, and ends the run (:meth:`GraphRunner._host_lost`): the
#: recorder waited for that host's rig forever, and the runner gave up with 'the run stalled'
#: after ``STALL_TIMEOUT_S``, no report written.
REFERENCE_SILENT_S = 5.0
#: Name of the runner's status reports.
RUNNER_NAME = 'seft_runner'

#: Longest time without any progress report before the run is declared stalled [s].
STALL_TIMEOUT_S = 30.0
#: How often the runner checks the publishers of the run's topics against its graph [s]
#: (``benchmarks/provenance_cost.py`` measures what a check costs).
AUDIT_EVERY_S = 0.25
#: How long the runner listens before it says what already runs in its domain [s]. A node
#: that has made its start-up announcements is discovered at its next periodic one (Fast
#: DDS: every 3 s): measured on this machine, a node started 2 s earlier took a new runner
#: 1.7 s to discover in 5 of 6 tries (the former 1 s missed it), up to 2.7 s otherwise.
DISCOVERY_SETTLE_S = 3.5
#: Environment variable that sets that wait [s] instead (e.g. a test session whose domain
#: is claimed by a lock and has nothing started by hand; a lab on a LAN with static peers).
DISCOVERY_SETTLE_ENV = 'SEFT_DISCOVERY_SETTLE_S'


def discovery_settle_s() -> float:
    """The busy-domain check's discovery wait [s]: ``$SEFT_DISCOVERY_SETTLE_S``, else
    :data:`DISCOVERY_SETTLE_S`.

    Raises
    ------
    SeftError
        The variable is not a number in 0..60.
    """
    text = os.environ.get(DISCOVERY_SETTLE_ENV)
    if text is None or not text.strip():
        return DISCOVERY_SETTLE_S
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 <= value <= 60.0:
        raise SeftError(f'{DISCOVERY_SETTLE_ENV}={text!r}: expected a number of seconds in '
                        '0..60')
    return value


def node_command(node: str, params_file) -> list[str]:
    """The command line that starts `node` (a qualified name: ``<rig>/<node>`` in the rig's
    namespace, ``-r __ns:=/<rig>``) with a parameter file."""
    rig, kind = split_qualified(node)
    return ([sys.executable, '-m', NODE_MODULES[kind], '--ros-args', '--params-file',
             str(params_file)] + (['-r', f'__ns:=/{rig}'] if rig else []))


def log_name(node: str) -> str:
    """The log file of a node (``<rig>.<node>.log`` for a namespaced one)."""
    return node.replace('/', '.') + '.log'


def loop_log_name(node: str) -> str:
    """The log file of the loop process of `node`'s rig (``<rig>.loop.log``; ``loop.log``
    for the study's single rig); each node's own log name links to it."""
    rig, _ = split_qualified(node)
    return f'{rig}.loop.log' if rig else 'loop.log'


def loop_groups(nodes, exclude=()) -> list[list[str]]:
    """The loop processes of ``--processes loop``: the nodes of ``LOOP_KINDS`` among
    `nodes`, grouped by namespace (a rig's, or the root namespace's for the study's single
    rig), in that order; groups of one node, and the nodes in `exclude` (started with a
    command of their own), are left to run alone."""
    groups: dict[str, list[str]] = {}
    for name in nodes:
        rig, kind = split_qualified(name)
        if kind in LOOP_KINDS and name not in exclude:
            groups.setdefault(rig, []).append(name)
    return [sorted(g, key=lambda n: LOOP_KINDS.index(split_qualified(n)[1]))
            for g in groups.values() if len(g) > 1]


def rig_params_files(params: dict, run_dir: Path) -> dict[str, Path]:
    """A structure run's parameter file per rig (``params_<rig>.yaml``: the run's parameters
    updated by the rig's section, :func:`~seft_ros.core.structure.rig_parameters`, for the
    rig's own nodes, ``parameters.RIG_SCOPED_NODES``); the study's test: none."""
    if params.get('structure', 'none') in ('none', '', None):
        return {}
    from seft_ros.core.structure import Structure, rig_parameters
    structure = Structure.from_json(params['structure'])
    return {r: write_params_file(rig_parameters(params, structure, r),
                                 run_dir / f'params_{r}.yaml') for r in structure.rig_names}


@dataclass
class RunOutcome:
    """What one graph run left behind."""

    bag_path: Path
    run_dir: Path
    wall_time_s: float
    rig_state: str
    message: str
    #: Whether this host ran the recorder (else the bag is on another host).
    recorded_here: bool = True
    #: The warnings said on the console during the run, as ``(node, warning)``: the bag may
    #: hold more (a report that reached the runner after the recorder closed the bag).
    warnings_said: frozenset = frozenset()


class GraphRunner:
    """Runs experiments as node graphs, one after the other, in one ROS domain.

    Parameters
    ----------
    domain_id : int
        ROS_DOMAIN_ID of the nodes and of the runner.
    progress : callable(text), optional
        Receives progress lines.
    localhost_default : bool
        Where ``ROS_AUTOMATIC_DISCOVERY_RANGE`` is unset, keep discovery on this host (one
        host); False leaves ROS's default (the subnet), for runs over several hosts.
    processes : {'node', 'loop'}
        One process per node (``ros2 run``'s way, the default), or the nodes of each rig's
        loop that run on this host (its rig, force servo controller and the builder of its
        namespace) in one process (:mod:`seft_ros.nodes.loop`); see
        ``seft_ros.cli.partition.PROCESSES``.

    Raises
    ------
    SeftError
        `processes` is not one of ``seft_ros.cli.partition.PROCESSES``.
    """

    def __init__(self, domain_id: int, progress: Callable[[str], None] | None = None, *,
                 localhost_default: bool = True, processes: str = 'node'):
        if processes not in PROCESSES:
            raise SeftError(f'--processes {processes}: expected one of {", ".join(PROCESSES)}')
        self.processes = processes
        self.domain_id = domain_id
        self.progress = progress or (lambda text: None)
        # the nodes' imports, once, while this runner starts and listens (cli/spawn.py)
        prepare_nodes(PRELOAD)
        use_seft_profile()    # this process's participant and the nodes it starts
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
        if localhost_default:
            # one host: stay on it unless the environment says otherwise
            self.env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
            os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE',
                                  self.env['ROS_AUTOMATIC_DISCOVERY_RANGE'])
        self.env.setdefault('PYTHONUNBUFFERED', '1')
        # the nodes stop the run safely when this process ends (seft_msgs_py.stopping)
        self.env[RUNNER_PID_ENV] = str(os.getpid())
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node('seft_runner', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.statuses = []
        self.warnings_said: set[tuple[str, str]] = set()
        #: After an interrupt, while the run ends: the further stop signals (_HeldSignals).
        self._held: _HeldSignals | None = None
        #: The processes of the run in progress (:meth:`run`).
        self.procs: dict[str, subprocess.Popen] = {}
        self._bag_path: Path | None = None    # the bag of the run in progress
        #: The graph of the run in progress (:meth:`run`).
        self.graph = Graph(('',), {'': 'servohydraulic'})
        #: The parameters of the run in progress as its nodes get them (its run token).
        self.run_params: dict = {}
        #: The seal of the run in progress (its status reports carry it; the runner acts on
        #: the run's reports only): none before the first run.
        self.seal = RunSeal()
        #: Status reports without the run's seal received during the run in progress (another
        #: run's node on the domain): dropped, never acted on; their publisher named once.
        self.foreign_statuses = 0
        #: The run's topics the audit checks: topic -> whether it commands the rig; the
        #: publishers there before the run's nodes started (gids); the foreign ones named.
        self.audited: dict[str, bool] = {}
        self.earlier: set[bytes] = set()
        self.named: set[tuple[str, str]] = set()
        #: The link measurement of a split run (:mod:`seft_ros.cli.link`), made on demand.
        self.link = None
        #: A live view runs beside this runner (``seft run --live``): its recorder lets the rig
        #: start once the view has matched the run's streams (``wait_for_live_view``).
        self.live_view = False
        self.node.create_subscription(STATUS.msg_type, STATUS.name, self._on_status, STATUS.qos)
        self.node_params: dict[str, dict] = {}
        #: The nodes of the run in progress (None before the first): only their parameters
        #: are compared (the previous run's latched ones can arrive after it ended).
        self.run_nodes: set[str] | None = None
        #: ``(node, run_token)`` of the parameters heard from another run's nodes (named).
        self.foreign_params: set[tuple[str, str]] = set()
        #: The run in progress was stopped on parameters that differ after its start.
        self.mismatch_stopped = False
        self.node.create_subscription(NODE_PARAMETERS.msg_type, NODE_PARAMETERS.name,
                                      self._on_node_parameters, NODE_PARAMETERS.qos)
        self.status_pub = self.node.create_publisher(STATUS.msg_type, STATUS.name, STATUS.qos)

    def busy_topics(self, settle_s: float | None = None) -> list[str]:
        """The seft topics that already have publishers in this domain (another run?).

        Two runs in one domain would mix their samples; the runner refuses to start then.
        `settle_s`: how long to listen first (default ``discovery_settle_s``).
        """
        self._spin(discovery_settle_s() if settle_s is None else settle_s)
        names = {t.name for t in TOPICS if t is not STATUS}
        # and the topics of a structure's rigs (/<rig>/seft/...)
        names |= {n for n, _ in self.node.get_topic_names_and_types()
                  if '/seft/' in n and n != STATUS.name}
        return sorted(n for n in names if self.node.count_publishers(n) > 0)

    def present_nodes(self, names, settle_s: float | None = None) -> list[str]:
        """Which of the node `names` already run in this domain (on any host); `settle_s` as
        :meth:`busy_topics`."""
        self._spin(discovery_settle_s() if settle_s is None else settle_s)
        present = {f'{ns.strip("/")}/{n}' if ns.strip('/') else n
                   for n, ns in self.node.get_node_names_and_namespaces()}
        return [n for n in names if n in present]

    def close(self) -> None:
        """Shut the runner's ROS context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def _on_status(self, msg) -> None:
        if not self.seal.status_ok(msg, STATUS.name):
            self._foreign_status(msg)
            return
        values = status_values(msg)
        values.update(name=msg.name, message=msg.message, received=time.monotonic())
        self.statuses.append(values)

    def _foreign_status(self, msg) -> None:
        """A status report without the run's seal (another run's node, a node by hand on the
        domain): counted, never acted on (it neither ends the run nor is shown as its), and
        the first one said on the console and in the bag (a warning naming the publisher and
        the report), as a foreign parameter message is."""
        self.foreign_statuses += 1
        if self.foreign_statuses > 1 or not self.run_params:
            return
        found = [(i.node_name, i.node_namespace, i.endpoint_gid)
                 for i in self.node.get_publishers_info_by_topic(STATUS.name)]
        who = (', '.join(self.graph.foreign_publishers(STATUS.name, found))
               or "no publisher but the run's own in the runner's view (a sender that has "
               'left, or a node of the run with another token or key)')
        values = status_values(msg)
        line = (f'{FOREIGN_REASON}{STATUS.name}: {who}: a status report of {msg.name!r} '
                f"(state {values.get('state')!r}, hardware id "
                f"{msg.hardware_id!r}) not sealed for this run: ignored (another run's or a "
                'hand-started node on this domain)')
        contract = values.get(CONTRACT_KEY)
        if msg.name in self.graph.rig_nodes() and contract and not is_compatible(contract):
            # the run's own rig written to an earlier contract (2.0 sealed no report)
            line += f"; if it is this run's: {unsealed_status_advice(contract)}"
        self.status_pub.publish(status_msg(RUNNER_NAME, STATE_RUNNING, line, seal=self.seal,
                                           warning=line, foreign_topic=STATUS.name))

    def _on_node_parameters(self, msg) -> None:
        """Collect a node's parameters: a node of the run in progress with its token.

        Parameters with another ``run_token`` are another run's (a node started by hand on
        this domain, another test): never compared with this run's; named once on the
        console and in the bag (a warning), as a foreign publisher is."""
        try:
            data = json.loads(msg.data)
            node = str(data['node'])
            if self.run_nodes is not None and node not in self.run_nodes:
                return          # a node of the previous run (its latched message, late)
            values = dict(data['parameters'])
        except (ValueError, KeyError, TypeError):
            return
        token = str(values.get('run_token', NO_TOKEN))
        if 'run_token' in self.run_params and token != str(self.run_params['run_token']):
            if (node, token) not in self.foreign_params:
                self.foreign_params.add((node, token))
                line = (f'{FOREIGN_REASON}{NODE_PARAMETERS.name}: parameters of a node '
                        f"{node!r} with run_token {token!r}, not this run's: ignored "
                        "(another run's node on this domain)")
                self.status_pub.publish(status_msg(RUNNER_NAME, STATE_RUNNING, line,
                                                   seal=self.seal, warning=line,
                                                   foreign_topic=NODE_PARAMETERS.name))
            return
        self.node_params[node] = values

    def _check_parameters(self) -> None:
        """Stop when the nodes of the run resolved different values of a shared parameter.

        Each differing parameter is shown on one line (the nodes print the same lines).
        Before any rig has begun stepping the run is refused (nothing was run); once one
        has, the run is stopped safely instead (an abort on ``/seft/status``: the rigs to
        their safe state, the bag closed, the report written), once.

        Raises
        ------
        SeftError
            Before the start: the number of differing parameters, 'nothing was run'.
        """
        if self.mismatch_stopped:
            return
        lines = parameters.shared_mismatches(self.node_params)
        if not lines:
            return
        for line in lines:
            self.progress(line)
        if not self._stepping_begun():
            self._wait_for_the_rigs_word()
        if not self._stepping_begun():
            raise SeftError(f'{len(lines)} shared parameter(s) differ between the nodes '
                            '(listed above); nothing was run')
        self.mismatch_stopped = True
        self._publish_abort(MISMATCH_ABORT + '; '.join(lines) + '; the run is stopped safely')

    def _wait_for_the_rigs_word(self) -> None:
        """Before calling a run not begun: spin up to :data:`REPORT_GRACE_S` for the rigs'
        reports, longer (up to :data:`DISCOVERY_SETTLE_S`) while a rig has not been heard at
        all; return early once one says it is stepping. A rig's 'running' report and the
        parameters that differ come over two topics with no order between them, and a rig
        this runner has not discovered yet may already be stepping (the CI of 43ca88f: a
        lockstep run at step 300 refused as 'nothing was run' while its nodes stopped it)."""
        start = time.monotonic()
        while not self._stepping_begun():
            waited = time.monotonic() - start
            unheard = any(self._latest(r) is None for r in self.graph.rig_nodes())
            if waited >= (DISCOVERY_SETTLE_S if unheard else REPORT_GRACE_S):
                return
            self._spin(0.05)

    def _stepping_begun(self) -> bool:
        """A rig of the run in progress has reported that it began stepping ('running' with
        its step, or a final status after samples)."""
        return any(s['name'] in self.graph.rig_nodes() and 'step' in s
                   and (s.get('state') == STATE_RUNNING or int(s.get('published', 0)) > 0)
                   for s in self.statuses)

    def _spin(self, seconds: float) -> None:
        """Serve the runner's subscriptions for `seconds` [s]; a stop signal meanwhile is
        raised between two ``spin_once`` (:func:`~seft_msgs_py.stopping.spinning`)."""
        deadline = time.monotonic() + seconds
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            with spinning():
                self.executor.spin_once(timeout_sec=min(left, 0.05))

    def _latest(self, name: str, states=None):
        for s in reversed(self.statuses):
            if s['name'] == name and (states is None or s.get('state') in states):
                return s
        return None

    def run(self, params: dict, run_dir, *, label: str = '', nodes=None,
            commands: dict[str, Callable[[Path], list[str]]] | None = None) -> RunOutcome:
        """Run one experiment; return where its bag is.

        Parameters
        ----------
        params : dict
            The run's parameters (resolved).
        run_dir : path
            Where this host writes ``params.yaml``, the node logs, the bag (if it runs the
            recorder) and ``outcome.json`` (the end of the run as this host saw it).
        label : str
            Prefix of the progress lines.
        nodes : sequence of str, optional
            The nodes this host starts (default: the whole graph); the others are started by
            another host in the same ROS domain.
        commands : dict of str to callable, optional
            Node -> ``command(params_file) -> argv``: start that node with this command line
            instead of seft's (``seft rig-check`` starts a lab's rig node so). During the run
            :attr:`procs` holds the started processes.

        Raises
        ------
        SeftError
            A node failed, died or was stopped by a signal (which node and when; the bag up
            to then is closed and readable), the graph did not start or stalled.
        Interrupted
            Ctrl-C, SIGTERM or SIGHUP: after the run was ended (the rig to its safe state,
            the bag closed), with what it reached (the rig's final status, or that none
            came; the bag). A further signal while it ends is said and waited out; one more
            leaves at once (``KeyboardInterrupt``; the nodes then stop the run themselves).
        """
        run_dir = Path(run_dir)
        log_dir = run_dir / 'logs'
        log_dir.mkdir(parents=True, exist_ok=True)
        bag_path = run_dir / 'bag'
        self._bag_path = bag_path
        # a new run token for every run (seft_msgs_py.provenance): what an earlier run or
        # another test sent is not this run's; over several hosts the reference's, agreed
        params = dict(params, bag_path=str(bag_path.resolve()), wait_for_recorder=True,
                      wait_for_live_view=self.live_view, run_token=new_run_token())
        self.graph = Graph.from_parameters(params)
        graph = ['recorder', *self.graph.nodes()]
        local = [n for n in graph if nodes is None or n in nodes]
        remote = [n for n in graph if n not in local]
        env = dict(self.env, ROS_LOG_DIR=str(log_dir / 'ros'))
        decision = None
        if remote:
            # several hosts: measure the links, agree on the playout delay and the preview,
            # and run this host's nodes in the reference host's clock (cli/link.py)
            decision = self._agree(params, run_dir.name, local, label)
            params = dict(params, network_delay_s=decision['network_delay_s'],
                          preview_steps=decision['preview_steps'],
                          run_token=decision.get('run_token', params['run_token']))
            env[OFFSET_ENV] = str(self.link.offset_ns())
        self.run_params = params
        params_file = write_params_file(params, run_dir / 'params.yaml')
        rig_files = rig_params_files(params, run_dir)
        # what other graphs of this domain published while this runner was idle (another
        # `seft run`'s latched parameters and reports) is still queued: take it, then forget it
        self._spin(0.1)
        self.statuses.clear()
        # this run's seal from now: what is queued from an earlier run was taken with its own
        self.seal = RunSeal.from_parameters(params)
        self.foreign_statuses = 0
        self.warnings_said.clear()
        self.node_params.clear()
        self.foreign_params.clear()
        self.mismatch_stopped = False
        self.audited = self._audited_topics()
        self.earlier = {g for _, _, g in self._publishers(self.audited)}
        self.named = set()
        self.run_nodes = set(local) | set(remote)
        # a new status publisher per run: the reports are latched (transient local), and the
        # nodes of this run must not receive the previous run's (an abort the runner sent
        # when one of its nodes died would end this run at its start)
        self.node.destroy_publisher(self.status_pub)
        self.status_pub = self.node.create_publisher(STATUS.msg_type, STATUS.name, STATUS.qos)
        procs: dict[str, subprocess.Popen] = {}
        self.procs = procs
        start = time.monotonic()
        outcome: dict = {'nodes': local, 'remote_nodes': remote, 'link': decision}

        def params_of(name):
            # a rig's own nodes take its parameters; a builder (even in the rig's namespace)
            # and the other nodes the test's
            rig, kind = split_qualified(name)
            own = rig_files.get(rig) if kind in parameters.RIG_SCOPED_NODES else None
            return own or params_file

        def launch(name):
            argv = (commands[name](params_of(name)) if commands and name in commands
                    else node_command(name, params_of(name)))
            procs[name] = start_node(argv, env, log_dir / log_name(name), PRELOAD)

        def launch_loop(names):
            # one process for the nodes of a rig's loop; each node's log is a link to its log
            argv = [sys.executable, '-m', LOOP_MODULE]
            for name in names:
                argv += ['--node', split_qualified(name)[1],
                         *node_command(name, params_of(name))[3:]]
            log = log_dir / loop_log_name(names[0])
            proc = start_node(argv, env, log, PRELOAD)
            for name in names:
                link = log_dir / log_name(name)
                link.unlink(missing_ok=True)
                link.symlink_to(log.name)
                procs[name] = proc

        try:
            # every node at once (the recorder first): the rig starts its clock only when the
            # parameters of every node are in, the recorder listens and, in real time, every
            # input path is matched, so the order of the start-ups does not matter; started
            # together they take the time of the slowest, not of all of them in turn
            rigs = set(self.graph.rig_nodes())
            for names in (loop_groups(local, exclude=commands or ())
                          if self.processes == 'loop' else []):
                launch_loop(names)
            for name in sorted(local, key=lambda n: (n != 'recorder', n in rigs)):
                if name not in procs:
                    launch(name)
            self._wait_ready([n for n in local if n not in rigs], procs, log_dir)
            if remote:
                self._wait_remote(remote, procs, log_dir, label)
            self.progress(f'{label}graph up in {time.monotonic() - start:.1f} s '
                          f'(ROS_DOMAIN_ID={self.domain_id}'
                          + (f'; here: {", ".join(local)}' if remote else '') + '); running')
            rig_final = self._watch(procs, log_dir, label, 'recorder' in local)
            outcome.update(rig_final=rig_final)
            return RunOutcome(bag_path, run_dir, time.monotonic() - start,
                              rig_final.get('state', ''), rig_final.get('message', ''),
                              'recorder' in local, frozenset(self.warnings_said))
        except KeyboardInterrupt as exc:
            signame = signal_name(exc)
            outcome.update(error='interrupted')
            if not procs:
                raise Interrupted(signame, 'before the nodes of the run started: nothing '
                                  'was run') from None
            self.progress(f'{label}interrupted by {signame}: ending the run (rig to its '
                          'safe state, bag closed)')
            self._held = _HeldSignals()
            try:
                with self._held:
                    self._end_run(runner_interrupt(signame), procs)
                    self._stop(procs)
            finally:
                self._held = None
            state = self._interrupted_state(procs)
            outcome.update(interrupted=state, rig_final=self._rig_final(heard_only=True))
            raise Interrupted(signame, state) from None
        except SeftError as exc:
            outcome.update(error=str(exc))
            raise
        finally:
            self._stop(procs)
            outcome.update(statuses=[{k: v for k, v in st.items() if k != 'received'}
                                     for st in self.statuses
                                     if st.get('state') not in (STATE_RUNNING, STATE_READY)])
            # the wall time of the rig's sample 0 [ns since the epoch] (real time): the
            # rig's times (abort_at_s) on the wall clock
            t0 = [st['t0_ns'] for st in self.statuses
                  if st['name'] == self.graph.master and 't0_ns' in st]
            if t0:
                outcome['rig_t0_ns'] = int(t0[0])
            try:
                (run_dir / 'outcome.json').write_text(json.dumps(outcome, indent=1,
                                                                 default=str))
            except OSError as exc:      # the run directory is gone: say so, lose nothing else
                self.progress(f'{label}could not write outcome.json: {exc}')

    def _agree(self, params: dict, key: str, local: list[str], label: str) -> dict:
        """The link phase of a split run (:class:`~seft_ros.cli.link.LinkPhase`); progress
        lines say what was measured and decided."""
        from seft_ros.cli.link import LinkPhase
        if self.link is None:
            self.link = LinkPhase(self.node, self._spin, self.progress)
        decision = self.link.agree(params, key, local, self.graph, REMOTE_TIMEOUT_S)
        for peer, link in decision.get('links', {}).items():
            rtt = link['round_trip_ms']
            self.progress(f'{label}link {decision["reference"]} - {peer}: round trip '
                          f'{rtt["p50"]:.2f} / {rtt["p99"]:.2f} / {rtt["max"]:.2f} ms '
                          f'(p50 / p99 / max), clock offset {link["offset_ms"]:+.3f} ms '
                          f'({decision.get("emulation", "none")})')
        if str(decision.get('playout')).startswith('dropped'):
            self.progress(f'{label}note: network_delay_s set to 0: no builder is on another '
                          'host than the controllers it commands (the loop stays local)')
        if decision.get('playout') == 'auto':
            self.progress(f'{label}network_delay_s auto: '
                          f'{1e3 * decision["network_delay_s"]:.0f} ms (round trip p99 '
                          f'{decision["round_trip_p99_ms"]:.2f} ms + margin, whole steps)')
        if decision['preview_steps'] != int(params['preview_steps']):
            self.progress(f'{label}preview_steps {decision["preview_steps"]} (the ground '
                          'motion ahead of the round trip)')
        if not self.link.reference:
            self.progress(f"{label}this host's clock offset from the reference host: "
                          f'{1e-6 * self.link.offset_ns():+.3f} ms (corrected)')
        return decision

    def _publish_abort(self, reason: str, **values) -> None:
        """Report an abort on ``/seft/status``: the rig goes to its safe state and ends the
        run, the recorder closes the bag after it."""
        self.status_pub.publish(status_msg(RUNNER_NAME, STATE_ABORTED, reason, seal=self.seal,
                                           **values))

    def _end_run(self, reason: str, procs, **values) -> None:
        """End the run from the runner (`reason` recorded in the bag), then wait until the
        bag is closed or the recorder of this host is gone (or, without a recorder here, until
        this host's nodes have exited)."""
        self._publish_abort(reason, **values)
        self._wait_closed(procs)

    def _wait_closed(self, procs) -> None:
        """Wait (at most :data:`END_TIMEOUT_S`) until the bag is closed or the recorder of
        this host is gone (or, without a recorder here, until this host's nodes have
        exited)."""
        deadline = time.monotonic() + END_TIMEOUT_S
        recorder = procs.get('recorder')
        while time.monotonic() < deadline:
            self._say_held()
            if self._latest('recorder', (STATE_CLOSED,)):
                return
            if recorder is not None and recorder.poll() is not None:
                return                        # killed: nothing left to close
            if recorder is None and all(p.poll() is not None for p in procs.values()):
                return
            self._spin(0.05)

    def _when(self) -> str:
        """When in the run, as the (first) rig's latest report tells it; without one (a
        process killed before this runner had discovered it: a loaded host can take seconds),
        the last sample of that rig in this host's closed bag."""
        rig = self._latest(self.graph.master)
        if not rig:
            return self._when_from_bag()
        if 'abort_at_s' in rig:
            return f'at t = {float(rig["abort_at_s"]):.3f} s (rig safe state from then)'
        return f'at t = {float(rig.get("time_s", 0.0)):.3f} s (step {rig.get("step", "?")})'

    def _when_from_bag(self) -> str:
        """When in the run, from the first rig's last measured sample in this host's bag
        (``step * dt``, the rig contract's stamps), or 'before the rig started'."""
        last = self._bag_last_step([self.graph.master])
        if last is None:
            return 'before the rig started'
        step, t_s = last
        return (f'at t = {t_s:.3f} s (step {step}, the last in the bag; no report of the rig '
                'reached this runner)')

    def _bag_last_step(self, rig_nodes) -> tuple[int, float] | None:
        """The last step every sensor of the rigs `rig_nodes` has in this host's closed bag,
        and its time [s] (``step * dt``, the rig contract's stamps); None when the bag is not
        closed, cannot be read or holds none."""
        if not self._bag_closed():
            return None
        from seft_ros.analysis.bag import read_signals  # the error path only: no import cost
        try:
            bag = read_signals(self._bag_path)
        except (SeftError, OSError):            # a when, never a second error
            return None
        rigs = [self.graph.rig_of(n) for n in rig_nodes]
        steps = [max(bag.samples[s.name]) for r in rigs for s in self.graph.sensors(r)
                 if bag.samples.get(s.name)]
        if not steps:
            return None
        step = min(steps)
        return step, step * float(bag.params['dt'])

    def _check_procs(self, procs, log_dir) -> None:
        """A node of this host that died ends the run safely, then the runner fails naming
        it, when and how."""
        for name, proc in procs.items():
            code = proc.poll()
            if code is None or code == 0:
                continue
            # (a process of a rig's loop, --processes loop, holds its rig with other nodes)
            together = [n for n, p in procs.items() if p is proc]
            if any(self._refused_the_run(n, code) for n in together):
                continue
            how = (f'was killed by {signal.Signals(-code).name}' if code < 0
                   else f'exited with code {code}')
            if len(together) > 1:
                how = f'(one process with {", ".join(n for n in together if n != name)}) {how}'
            self._end_run(f'node {name} {how}', procs, failed_node=name)
            saved = ('the bag was not closed: seft compare recovers it up to at most the '
                     'last 0.25 s' if name == 'recorder' else 'the recording up to then is '
                     'closed')
            log = log_dir / log_name(name)
            raise SeftError(f'node {name} {how} {self._when()}: {_last_line(log)} '
                            f'(log: {log}; {saved})')

    def _refused_the_run(self, name: str, code: int) -> bool:
        """Whether node `name`, which exited with `code`, is a rig that refused the run before
        its first sample and said why: its final report (failed or aborted) heard, waited for
        up to :data:`REPORT_GRACE_S` (a UDP bridge whose controller is not at its address, or
        turns the run down). The run then ends as the rig ended it (the watch reads its
        reason: 'the rig failed before its first sample: ...; nothing was run'), not as a
        node's death."""
        if code <= 0 or name not in self.graph.rig_nodes() or self._stepping_begun():
            return False
        deadline = time.monotonic() + REPORT_GRACE_S
        while self._latest(name, (STATE_FAILED, STATE_ABORTED)) is None:
            if time.monotonic() >= deadline:
                return False
            self._spin(0.05)
        return True

    def _rig_final(self, heard_only: bool = False):
        """The rigs' final status (done, aborted or failed) once every rig's is heard: the
        first rig's, or the first that did not end done (its reason); None before.

        With ``heard_only`` the rigs whose final status this runner heard (the same when it
        heard every rig's; a lab whose link to another lab is cut never hears that lab's rig
        end: its own rig's is the one it reports); None if none."""
        finals = [self._latest(r, (STATE_DONE, STATE_ABORTED, STATE_FAILED))
                  for r in self.graph.rig_nodes()]
        if heard_only:
            finals = [f for f in finals if f]
        if not finals or not all(finals):
            return None
        return next((f for f in finals if f.get('state') != STATE_DONE), finals[0])

    def _over_here(self, procs) -> bool:
        """The run is over as this host sees it: every rig's final status, this host's rigs
        exited cleanly, or this host's bag closed on disk. A short run can end before this
        runner hears a node at all (a node's reports are not kept after it exits)."""
        rigs = [procs[r] for r in self.graph.rig_nodes() if r in procs]
        return bool(self._rig_final() or (rigs and all(p.poll() == 0 for p in rigs))
                    or self._closed_on_disk(procs))

    def _closed_on_disk(self, procs) -> bool:
        """The recorder of this host exited cleanly and its bag is closed on disk (rosbags
        writes ``metadata.yaml`` on close only): the run is over even when its last status
        reports never reached this runner (a short run on a fast machine can end before the
        runner has discovered every node's status publisher; the statuses are in the bag)."""
        recorder = procs.get('recorder')
        return recorder is not None and recorder.poll() == 0 and self._bag_closed()

    def _bag_closed(self) -> bool:
        """This host's bag of the run is closed on disk (rosbags writes ``metadata.yaml`` on
        close only)."""
        return self._bag_path is not None and (Path(self._bag_path) / 'metadata.yaml').is_file()

    def _wait_ready(self, names, procs, log_dir) -> None:
        """Wait until every node of `names` has reported ready (or running), or the run is
        already over (a short run may end before this runner has discovered a node)."""
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        gone: dict[str, float] = {}     # node -> when it was seen exited (code 0) unheard
        while not all(self._latest(n, (STATE_READY, STATE_RUNNING)) for n in names):
            if self._over_here(procs):
                return
            self._check_parameters()
            self._check_procs(procs, log_dir)
            for n in names:
                if procs[n].poll() == 0 and not self._latest(n):
                    # ended cleanly before its reports reached this runner: give them (and
                    # the rig's final status) a moment before calling it a failed start
                    since = gone.setdefault(n, time.monotonic())
                    if time.monotonic() - since > EXITED_GRACE_S:
                        raise SeftError(f'node {n} exited before it was ready: '
                                        f'{_last_line(log_dir / log_name(n))}')
            if time.monotonic() > deadline:
                missing = [n for n in names if not self._latest(n, (STATE_READY,))]
                raise SeftError(f'nodes not ready after {STARTUP_TIMEOUT_S:.0f} s: '
                                + ', '.join(missing))
            self._spin(0.05)

    def _wait_remote(self, names, procs, log_dir, label) -> None:
        """Wait until the nodes of the other host(s) have reported ready (or already run).

        The run's end on this host (:meth:`_over_here`) ends the wait too."""
        deadline = time.monotonic() + REMOTE_TIMEOUT_S
        said = 0.0
        while True:
            missing = [n for n in names if not self._latest(n)]
            if not missing or self._over_here(procs):
                return
            self._check_parameters()
            self._check_procs(procs, log_dir)
            now = time.monotonic()
            if now > deadline:
                raise SeftError(f'nodes of the other host not ready after '
                                f'{REMOTE_TIMEOUT_S:.0f} s: {", ".join(missing)} (same '
                                f'ROS_DOMAIN_ID={self.domain_id}, discovery range and '
                                'parameters there?)')
            if now - said > 10.0:
                said = now
                self.progress(f'{label}waiting for the other host: {", ".join(missing)} '
                              f'(seft run --nodes {",".join(missing)} there, '
                              f'ROS_DOMAIN_ID={self.domain_id})')
            self._spin(0.05)

    def _audited_topics(self) -> dict[str, bool]:
        """The run's topics the audit checks (topic -> it commands the rig): every data and
        record topic of the graph, ``/clock``, the status and parameter topics."""
        commands = set(self.graph.command_topics())
        topics = commands | {r.name for r in self.graph.record_streams()} | {
            CLOCK.name, STATUS.name, NODE_PARAMETERS.name, RUN_PARAMETERS.name}
        return {t: t in commands for t in sorted(topics)}

    def _publishers(self, topics):
        """``(topic, (node, namespace, gid), gid)`` of every publisher of `topics` this
        runner knows of (gid as bytes)."""
        for topic in topics:
            for i in self.node.get_publishers_info_by_topic(topic):
                gid = bytes(i.endpoint_gid)
                yield topic, (i.node_name, i.node_namespace, gid), gid

    def audit(self) -> list[str]:
        """Check the publishers of the run's topics against the graph (module notes); an
        abort or a warning for each foreign publisher not named before. Returns the lines
        said."""
        found: dict[str, list] = {}
        for topic, endpoint, gid in self._publishers(self.audited):
            if gid not in self.earlier:
                found.setdefault(topic, []).append(endpoint)
        lines = []
        for topic, endpoints in found.items():
            if any(node == UNKNOWN_NODE for node, _, _ in endpoints):
                continue            # a node that has not announced its name: the next check
            who = [w for w in self.graph.foreign_publishers(topic, endpoints)
                   if (topic, w) not in self.named]
            if not who:
                continue
            self.named.update((topic, w) for w in who)
            line = (f'{FOREIGN_REASON}{topic}: {", ".join(who)}: not a node of this run (the '
                    "runner's check of the graph it started)")
            if self.audited[topic]:
                self._publish_abort(line, foreign_topic=topic)
            else:
                self.status_pub.publish(status_msg(RUNNER_NAME, STATE_RUNNING, line,
                                                   seal=self.seal, warning=line,
                                                   foreign_topic=topic))
            lines.append(line)
        return lines

    def _watch(self, procs, log_dir, label, recorded_here: bool) -> dict:
        last_progress = time.monotonic()
        last_print = 0.0
        seen = 0
        stepping = None                 # (wall, sim time) when the rig was first seen running
        audited_at = 0.0
        while True:
            self._spin(0.1)
            if time.monotonic() - audited_at > AUDIT_EVERY_S:
                audited_at = time.monotonic()
                self.audit()
            if self.link is not None:
                self.link.tick()
            self._check_parameters()
            self._check_procs(procs, log_dir)
            new = self.statuses[seen:]
            seen = len(self.statuses)
            for s in new:
                last_progress = time.monotonic()
                if s.get('state') in (STATE_ABORTED, STATE_FAILED):
                    self.progress(f'{label}{s["name"]}: {s.get("state")}: {s["message"]}')
                elif s.get('warning'):
                    self.progress(f'{label}{s["name"]}: warning: {s["warning"]}')
                    self.warnings_said.add((s['name'], s['warning']))
            rig = self._latest(self.graph.master)
            now = time.monotonic()
            if rig and rig.get('state') == STATE_RUNNING:
                sim_t = float(rig.get('time_s', 0.0))
                if stepping is None:          # the pace is the stepping's, not the start-up's
                    stepping = (now, sim_t)
                if now - last_print > 2.0:
                    last_print = now
                    step, n = int(rig.get('step', 0)), int(rig.get('n_steps', 0) or 1)
                    elapsed = now - stepping[0]
                    pace = (f', {(sim_t - stepping[1]) / elapsed:.2f}x real time'
                            if elapsed >= 1.0 else '')
                    self.progress(f'{label}step {step}/{n} ({100 * step / n:.0f} %), '
                                  f't = {sim_t:.2f} s sim{pace}')
            # the recorder's exit read once, before its bag is looked at: one that exits
            # between the two is judged by the next pass (the CI of 24ad652 took a recorder
            # that had closed its bag for one that had not)
            recorder_exited = recorded_here and procs['recorder'].poll() is not None
            over = (self._latest('recorder', (STATE_CLOSED,)) or (
                not recorded_here and all(p.poll() is not None for p in procs.values())))
            if over or (recorded_here and self._closed_on_disk(procs)):
                self._check_stopped()
                return self._rig_final(heard_only=True) or {}
            if not recorded_here and self._reference_lost(procs, label):
                self._check_stopped()
                return self._rig_final(heard_only=True) or {}
            if recorded_here and self._host_lost(procs, label):
                self._check_stopped()
                return self._rig_final(heard_only=True) or {}
            if recorder_exited:
                raise SeftError('the recorder exited before closing the bag: '
                                f'{_last_line(log_dir / log_name("recorder"))}')
            if now - last_progress > STALL_TIMEOUT_S:
                raise SeftError(f'the run stalled: no report for {STALL_TIMEOUT_S:.0f} s '
                                f'(logs in {log_dir})')

    def _reference_lost(self, procs, label: str) -> bool:
        """On a host without the recorder: every node here has ended (a final status) and
        the host with the recorder has been silent for :data:`REFERENCE_SILENT_S`; then say
        so and stop this host's lingering nodes (one SIGINT each: they have ended, so they
        exit at once, with their exit codes)."""
        silent_s = 0.0 if self.link is None else self.link.reference_silent_s()
        if silent_s <= REFERENCE_SILENT_S:
            return False
        if not all(self._latest(n, (STATE_DONE, STATE_ABORTED, STATE_FAILED)) for n in procs):
            return False
        self.progress(f'{label}no word from the host with the recorder for '
                      f'{silent_s:.1f} s after the nodes here ended '
                      '(link or host lost): ending them; its bag holds what reached it')
        for p in _running(procs):
            p.send_signal(signal.SIGINT)
        return True

    def _host_lost(self, procs, label: str) -> bool:
        """On the host with the recorder: another host has answered none of its pings, and
        none of its nodes has reported, for :data:`REFERENCE_SILENT_S` (its link cut, or the
        host down: its rig's end can no longer reach the recorder). Then end the run: an abort
        that names the host and its nodes (the recorder stops waiting for them and closes the
        bag with what reached it; the nodes here end on it), then one line saying so."""
        silent = {} if self.link is None else self.link.hosts_silent_s()
        lost = {}
        for host, silent_s in silent.items():
            if silent_s <= REFERENCE_SILENT_S:
                continue
            nodes = [n for n in self.link.hellos.get(host, {}).get('nodes', ())
                     if n in self.run_nodes]
            heard = [s['received'] for s in self.statuses if s['name'] in nodes]
            silent_s = min([silent_s, *(time.monotonic() - t for t in heard[-1:])])
            if silent_s > REFERENCE_SILENT_S:
                lost[host] = (silent_s, nodes)
        if not lost:
            return False
        for host, (silent_s, nodes) in lost.items():
            rigs = [n for n in nodes if n in self.graph.rig_nodes()]
            self._publish_abort(f'lab host {host} lost: no word from it for {silent_s:.1f} s '
                                '(link cut or host down)', lost_nodes=','.join(nodes),
                                **({'failed_node': rigs[0]} if rigs else {}))
        self._wait_closed(procs)
        closed = ('recording closed' if self._bag_closed() else
                  f'recording not closed after {END_TIMEOUT_S:.0f} s: stopping the recorder')
        for host, (silent_s, nodes) in lost.items():
            rigs = [n for n in nodes if n in self.graph.rig_nodes()]
            last = self._bag_last_step(rigs)
            heard = [self._latest(r, (STATE_RUNNING,)) for r in rigs]
            when = (f'after t = {last[1]:.3f} s (its last sample here)' if last is not None
                    else 'before its rig started' if not any(heard) else
                    f'after t = {max(float(h.get("time_s", 0.0)) for h in heard if h):.3f} s '
                    '(its last report here)')
            self.progress(f'{label}lab host {host} lost {when}: link cut or host down, no '
                          f'word from it for {silent_s:.1f} s; {closed}')
        return True

    def _check_stopped(self) -> None:
        """A node stopped by a signal (SIGINT, SIGTERM) ended the run safely; the runner still
        fails, naming it."""
        for st in self.statuses:
            if st.get('signal') and st.get('state') == STATE_ABORTED:
                raise SeftError(f'node {st["name"]} was stopped by {st["signal"]} '
                                f'at t = {float(st.get("time_s", 0.0)):.3f} s; the run ended '
                                'safely and the recording up to then is closed')

    def _stop(self, procs) -> None:
        """Let finished nodes exit; SIGINT the rest (the recorder closes its bag), then kill."""
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and any(p.poll() is None for p in procs.values()):
            self._say_held()
            self._spin(0.05)
        for sig, wait in ((signal.SIGINT, 10.0), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
            # one signal per process (a loop process holds several nodes: a second SIGINT
            # would end it at once instead of safely)
            alive = _running(procs)
            if not alive:
                return
            for p in alive:
                p.send_signal(sig)
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline and any(p.poll() is None for p in alive):
                self._say_held()
                time.sleep(0.05)

    def _say_held(self) -> None:
        """Say once that a further stop signal came while the run ends (:class:`_HeldSignals`)."""
        if self._held is not None and self._held.names and not self._held.said:
            self._held.said = True
            self.progress(f'{self._held.names[0]} again: still ending the run (the rig '
                          'finishes its safe ramp, the recorder closes the bag); once more to '
                          'leave at once (the nodes then stop by themselves)')

    def _interrupted_state(self, procs) -> str:
        """What an interrupted run reached, once it has ended: the rig's safe state (from its
        final status; without one, that it is not confirmed) and the bag."""
        parts = []
        rig = self._rig_final(heard_only=True)
        here = [r for r in self.graph.rig_nodes() if r in procs]
        if rig is not None:
            step = int(rig.get('step', 0) or 0)
            if rig.get('safe_unconfirmed'):
                # a UDP bridge whose controller never reported its safe state
                parts.append(f'the rig was asked for its safe state from t = '
                             f'{float(rig.get("abort_at_s", 0.0)):.3f} s, but '
                             f'{rig["safe_unconfirmed"]}')
            elif 'abort_at_s' in rig:
                parts.append(f'the rig ramped to its safe state from t = '
                             f'{float(rig["abort_at_s"]):.3f} s')
            elif rig.get('state') == STATE_DONE:
                parts.append('the rig had completed its run')
            elif step == 0:
                parts.append('the rig stopped before its first step')
            else:
                parts.append(f'the rig stopped at t = {float(rig.get("time_s", 0.0)):.3f} s '
                             f'(step {step})')
        elif here:
            logs = ', '.join(str(self._bag_path.parent / 'logs' / log_name(r)) for r in here)
            parts.append(f'NO final status from {", ".join(here)}: its safe stop is not '
                         f'confirmed; check the rig (log: {logs})')
        else:
            parts.append("the rig's host did not report its end here")
        if self._bag_closed():
            parts.append(f'bag closed: {self._bag_path}')
        elif 'recorder' in procs:
            parts.append(f'the bag was not closed: {self._bag_path} (seft compare recovers '
                         'it up to at most the last 0.25 s)')
        return '; '.join(parts)


class _HeldSignals:
    """While a runner ends an interrupted run: the next stop signal (SIGINT, SIGTERM, SIGHUP)
    is noted, not raised, so that a second Ctrl-C does not leave the run's end unwatched (the
    runner said it ended safely while the rig died in its ramp); the one after raises
    ``KeyboardInterrupt``. The signals are the main thread's only: elsewhere it does nothing.
    """

    def __init__(self):
        self.names: list[str] = []
        self.said = False
        self._previous: dict = {}

    def _on_signal(self, signum, frame):
        name = signal.Signals(signum).name
        if self.names:
            raise_stop(name)
            return
        self.names.append(name)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._previous = {s: signal.signal(s, self._on_signal) for s in STOP_SIGNALS}
        return self

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        return False


def _running(procs) -> list:
    """The processes of `procs` (node -> process) still running, each once (a loop process
    holds several nodes, and a second SIGINT would end it at once instead of safely)."""
    return list({id(p): p for p in procs.values() if p.poll() is None}.values())


def _last_line(path: Path) -> str:
    """The last non-empty line of a log file ('' if none)."""
    try:
        lines = [ln.strip() for ln in path.read_text(errors='replace').splitlines()]
    except OSError:
        return ''
    lines = [ln for ln in lines if ln]
    return lines[-1] if lines else ''
