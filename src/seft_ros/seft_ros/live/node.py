"""The live view's process: a ROS node outside the loop feeding the Foxglove server and the page.

``seft run --live`` starts it (:mod:`seft_ros.cli.live`); by hand, in the run's ROS domain::

    python -m seft_ros.live.node --host 127.0.0.1 --port 8765 [--stop]

It never slows or blocks a node of the test: it is a process of its own at a lower priority
(nice 10), it publishes nothing on the graph's topics, and it reads the record batches the
nodes publish for the recorder (ten samples a message, ``seft_msgs_py.signals.RecordStream``)
with **best-effort** subscriptions: a publisher never waits for it nor repeats a sample it
missed, so a live view that falls behind loses display samples, never a sample of the test
(the recorder's subscriptions are reliable). The run's parameters, the status reports and
the link figures are subscribed to as the graph publishes them (reliable, latched: a few
messages a second), so that the view learns of a run it joined late and never misses its
end. A new run (a new ``/seft/run_parameters``, the next of a sweep) replaces the shown one.

**The operator's stop** (``--live-stop`` only): the page's stop button makes this node report
``aborted`` on ``/seft/status`` under the name ``seft_live`` with the reason ``operator stop
from the live view (client <address>)`` and ``stopped_by=operator``: one more of the rig
contract's safe-state paths (another node's abort), so the rig ramps to its safe state, ends
the run ``aborted`` with ``ended_by=seft_live``, and the bag holds both reports. The
publisher exists from the stop until the run's end only (its report is latched: the next
run's nodes must not hear it).
"""

import argparse
import json
import os
import queue
import signal
import sys
import threading

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from seft_msgs_py.convert import STATE_ABORTED, STATE_READY, status_msg, status_values
from seft_msgs_py.errors import SeftError
from seft_msgs_py.node_support import exit_if_longer
from seft_msgs_py.provenance import AUTH_TOKEN, RunSeal, status_id_of_run
from seft_msgs_py.rig_contract import FOREIGN_REASON
from seft_msgs_py.signals import FINAL_STATES
from seft_msgs_py.stopping import STOP_SIGNALS, RunnerWatch
from seft_msgs_py.topics import LINK, RUN_PARAMETERS, STATUS, record_topic
from seft_ros.cli.arguments import OneLineParser
from seft_ros.live.access import DEFAULT_HOST, DEFAULT_PORT, TOKEN_ENV, LiveOptions, listen_error
from seft_ros.live.channels import DISPLAY_RATE_HZ
from seft_ros.live.view import LIVE_NAME, LiveView

__all__ = ['LiveNode', 'main', 'LIVE_DATA_QOS', 'READY_LINE', 'OFF_LINE', 'NICE', 'LAYOUT_FILE',
           'layout_file']

#: The record batches as the live view reads them: best effort, volatile, a short queue.
LIVE_DATA_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50,
                           reliability=ReliabilityPolicy.BEST_EFFORT,
                           durability=DurabilityPolicy.VOLATILE)
#: The line the process prints once it listens and subscribes (``seft run`` waits for it).
READY_LINE = 'live view: ready'
#: The line it prints when nothing could listen (it then exits; the test runs on).
OFF_LINE = 'live view: off; the test runs without it'
#: The process's niceness: below the test's nodes.
NICE = 10
#: The most status reports held before the first run's parameters are heard.
EARLY_STATUSES = 1000
#: How long the page's stop waits for the ROS side [s].
STOP_WAIT_S = 2.0
#: The longest the process takes to close its servers and ROS once stopped [s]; then it
#: exits at once.
SHUTDOWN_TIMEOUT_S = 10.0


class LiveNode(Node):
    """Subscribes to a run's record batches, statuses, parameters and links (module notes).

    Parameters
    ----------
    view : LiveView
        Receives what the node hears.
    say : callable(str)
        Receives one-line messages (the stop).
    """

    def __init__(self, view: LiveView, say=print):
        super().__init__(LIVE_NAME)
        self.view = view
        self.say = say
        self.batch_subs: dict = {}
        self.foreign: set[str] = set()
        self.create_subscription(RUN_PARAMETERS.msg_type, RUN_PARAMETERS.name,
                                 self._on_params, RUN_PARAMETERS.qos)
        self.create_subscription(STATUS.msg_type, STATUS.name, self._on_status, STATUS.qos)
        self.create_subscription(LINK.msg_type, LINK.name, self._on_link, LINK.qos)
        self.stops: queue.SimpleQueue = queue.SimpleQueue()
        self.status_pub = None
        self.run_token = None
        #: The shown run's seal (from its parameters): None before a run, or a run in
        #: ``message_auth: hmac`` whose key file this host cannot read (its reports are then
        #: taken by their seal's form, ``status_id_of_run``, and the operator's stop cannot
        #: be sealed).
        self.seal: RunSeal | None = None
        self.has_run = False
        self.message_auth = AUTH_TOKEN
        #: The reports heard before the first run's parameters (replayed against its seal).
        self.early: list = []
        #: Reports without the shown run's seal (another run's node on the domain): dropped.
        self.foreign_statuses = 0
        self.matched_said = True          # no run yet
        self.create_timer(0.02, self._service)

    def _on_params(self, msg) -> None:
        try:
            params = json.loads(msg.data)
            if not self.view.new_run(params):
                return
        except (ValueError, KeyError, TypeError, SeftError) as exc:
            self.get_logger().warning(f'run parameters not shown: {exc}')
            return
        wanted = {s.stream.name: s.stream for s in self.view.run.sources}
        for name in list(self.batch_subs):
            if name not in wanted:
                self.destroy_subscription(self.batch_subs.pop(name))
        for name, stream in wanted.items():
            if name in self.batch_subs:
                self.destroy_subscription(self.batch_subs.pop(name))
            spec = record_topic(stream)
            self.batch_subs[name] = self.create_subscription(
                spec.msg_type, name, lambda m, s=stream: self._on_batch(s, m), LIVE_DATA_QOS)
        self._drop_status_publisher()
        self.run_token = params.get('run_token')
        self.message_auth = str(params.get('message_auth', AUTH_TOKEN))
        self.foreign_statuses = 0
        try:
            self.seal = RunSeal.from_parameters(params)
        except SeftError as exc:      # hmac, the key file not on this host
            self.seal = None
            self.get_logger().warning(f'{exc}: the reports are taken by the form of their '
                                      "seal, and the operator's stop cannot be sent")
        self.has_run = True
        self.matched_said = False
        early, self.early = self.early, []
        for held in early:
            self._on_status(held)
        self.view.add_reference()         # after subscribing: the run may be short

    def _on_batch(self, stream, msg) -> None:
        try:
            columns = stream.columns_of(msg)
        except ValueError as exc:
            if stream.name not in self.foreign:
                self.foreign.add(stream.name)
                self.get_logger().warning(f'{exc}; not shown')
            return
        self.view.on_batch(stream.name, columns, msg.data)

    def _on_status(self, msg) -> None:
        """A report of the shown run (its seal): to the view; another run's: dropped,
        counted, its first said in the log; before any run's parameters: held."""
        if not self.has_run:
            if len(self.early) < EARLY_STATUSES:
                self.early.append(msg)
            return
        if not self._of_run(msg):
            self.foreign_statuses += 1
            if self.foreign_statuses == 1:
                self.get_logger().warning(
                    f'{FOREIGN_REASON}{STATUS.name}: a report of {msg.name!r} (state '
                    f"{status_values(msg).get('state')!r}, hardware id {msg.hardware_id!r}) "
                    "not sealed for the shown run: not shown (another run's or a "
                    'hand-started node on this domain)')
            return
        self.view.on_status(msg.name, msg.message, status_values(msg))

    def _of_run(self, msg) -> bool:
        """Whether a report carries the shown run's seal (checked with the key where this
        host has it, else by its form)."""
        if self.seal is not None:
            return self.seal.status_ok(msg, STATUS.name)
        return status_id_of_run(msg.hardware_id, str(self.run_token), self.message_auth)

    def _on_link(self, msg) -> None:
        try:
            self.view.on_link(json.loads(msg.data))
        except (ValueError, AttributeError, TypeError):
            return

    # -- the operator's stop --------------------------------------------------------------

    def request_stop(self, client: str) -> str:
        """From the web server's thread: stop the run (module notes); return one line."""
        done = threading.Event()
        answer: list[str] = []
        self.stops.put((client, done, answer))
        done.wait(STOP_WAIT_S)
        return answer[0] if answer else 'the stop was not sent in time (ROS side busy)'

    def _service(self) -> None:
        while True:
            try:
                client, done, answer = self.stops.get_nowait()
            except queue.Empty:
                break
            answer.append(self._stop(client))
            done.set()
        if self.view.status.state in FINAL_STATES:
            self._drop_status_publisher()
        elif not self.matched_said and self.batch_subs and all(
                sub.get_publisher_count() > 0 for sub in self.batch_subs.values()):
            self.matched_said = True
            self._status_publisher().publish(status_msg(
                LIVE_NAME, STATE_READY, 'live view: every stream of the run matched',
                seal=self.seal or RunSeal(),
                run_token=str(self.run_token), streams=len(self.batch_subs)))

    def _stop(self, client: str) -> str:
        state = self.view.status.state
        if state not in ('starting', 'running'):
            return f'no run to stop (state: {state})'
        if self.seal is None:
            return ("cannot stop the run: its reports are sealed with the test's key "
                    '(message_auth hmac), whose file this host cannot read')
        reason = f'operator stop from the live view (client {client})'
        self._status_publisher().publish(status_msg(LIVE_NAME, STATE_ABORTED, reason,
                                                    seal=self.seal,
                                                    stopped_by='operator', client=client,
                                                    step=self.view.status.step))
        self.say(f'live view: {reason}: the rig goes to its safe state')
        return f'stop sent: {reason}'

    def _status_publisher(self):
        if self.status_pub is None:
            self.status_pub = self.create_publisher(STATUS.msg_type, STATUS.name, STATUS.qos)
        return self.status_pub

    def _drop_status_publisher(self) -> None:
        if self.status_pub is not None:
            self.destroy_publisher(self.status_pub)
            self.status_pub = None


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog='python -m seft_ros.live.node', error_prefix='live view',
                                description='The live view of seft runs in this ROS domain '
                                f'(token: ${TOKEN_ENV}).')
    p.add_argument('--host', default=DEFAULT_HOST)
    p.add_argument('--port', type=int, default=DEFAULT_PORT,
                   help='Foxglove; the web page is on PORT+1')
    p.add_argument('--tls-cert', default='')
    p.add_argument('--tls-key', default='')
    p.add_argument('--stop', action='store_true', help="offer the operator's stop button")
    p.add_argument('--rate', type=float, default=DISPLAY_RATE_HZ, help='display rate [Hz]')
    return p


def _say(line: str) -> None:
    print(line, flush=True)


def _warm_up(analytical) -> None:
    """Import and run the reference's numerics once (scipy, the record reader), so that a
    run's reference takes milliseconds when it begins, not the imports' second."""
    from seft_msgs_py import parameters
    analytical(dict(parameters.resolve(), duration_s=0.1))


#: The Foxglove layout shipped with seft, relative to its repository.
LAYOUT_FILE = 'docs/foxglove/seft_live_layout.json'


def layout_file() -> str:
    """Where the shipped Foxglove layout is: its absolute path in the repository this
    package runs from (a new user ran seft outside the repository and the relative path
    named nothing there; session 39), else :data:`LAYOUT_FILE` in seft's repository (an
    installed package without the docs)."""
    from pathlib import Path
    path = Path(__file__).resolve().parents[4] / LAYOUT_FILE
    return str(path) if path.is_file() else f"{LAYOUT_FILE} in seft's repository"


def serve(options: LiveOptions):
    """Start the Foxglove server and the web server of `options`; return ``(view, web,
    foxglove_server, lines)`` where `lines` say what listens and what could not."""
    from seft_ros.live.foxglove_sink import FoxgloveSink, start_foxglove
    from seft_ros.live.reference import analytical
    from seft_ros.live.web import WebServer
    lines = []
    _warm_up(analytical)
    foxglove_server, internal = None, None
    try:
        if options.token:          # behind the token proxy: this machine only
            foxglove_server = start_foxglove('127.0.0.1', 0)
            internal = foxglove_server.port
        else:
            foxglove_server = start_foxglove(options.host, options.port, options.tls_pem())
    except RuntimeError as exc:
        lines.append(listen_error('Foxglove', options.host if not options.token
                                  else '127.0.0.1', options.port if not options.token else 0,
                                  exc))
    view = LiveView(options.rate_hz, sinks=[FoxgloveSink()] if foxglove_server else [],
                    reference=analytical, stop_enabled=options.stop)
    holder = {}
    web = WebServer(view, options, _say, lambda client: holder['node'].request_stop(client),
                    foxglove_port=internal)
    lines += web.start()
    page, fox = options.urls()
    if web.web_ok:
        lines.append(f'live view: web page {page}'
                     + (' (with the operator stop button)' if options.stop else ''))
    if foxglove_server is not None and (not options.token or web.proxy_ok):
        lines.append(f'live view: Foxglove {fox} (layout: {layout_file()})')
    elif foxglove_server is not None:
        foxglove_server.stop()
        foxglove_server = None
    return view, web, foxglove_server, lines, holder


def main(argv=None) -> int:
    """Entry point: serve the live view until SIGINT, SIGTERM or SIGHUP, or until the runner
    that started it (``$SEFT_RUNNER_PID``) has ended."""
    args = _parser().parse_args(argv)
    try:
        os.nice(NICE)
    except OSError:
        pass
    options = LiveOptions(args.host, args.port, os.environ.get(TOKEN_ENV, '').strip(),
                          args.tls_cert, args.tls_key, args.stop, args.rate)
    view, web, foxglove_server, lines, holder = serve(options)
    for line in lines:
        _say(line)
    if not web.web_ok and foxglove_server is None:
        _say(OFF_LINE)
        web.close()
        return 3
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    stopping = threading.Event()

    def on_signal(signum, frame):
        stopping.set()
    for signum in STOP_SIGNALS:
        signal.signal(signum, on_signal)
    # a viewer started by a runner ends with it (a killed runner left it serving)
    runner = RunnerWatch.from_environment()
    rclpy.init(args=None, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = LiveNode(view, _say)
    holder['node'] = node
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    _say(READY_LINE)
    try:
        while not stopping.is_set() and not (runner is not None and runner.gone()):
            executor.spin_once(timeout_sec=0.1)
    finally:
        # the shutdown is bounded: a viewer holds no sample of the test, and its servers'
        # closing once held the process past a 30 s wait (a TLS client's connection in CI)
        with exit_if_longer(SHUTDOWN_TIMEOUT_S, 'live view: its servers did not close within '
                            f'{SHUTDOWN_TIMEOUT_S:.0f} s; exiting', 0, sys.stdout):
            web.close()
            if foxglove_server is not None:
                foxglove_server.stop()
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
