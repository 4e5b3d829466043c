"""The nodes started by hand as the docs' 'Running the nodes by hand' does (issue 12).

Five separate processes, the installed executables with ``--ros-args --params-file
config/default.yaml`` plus ``-p`` overrides, in the test session's ROS domain. With the docs'
former mistake (``-p alpha:=0.5`` on the reference-force builder only) the graph must refuse to
run and every node must name the parameter, the nodes and their values; with alpha on every
node the run completes and the bag holds each node's parameters.
"""

from collections import defaultdict
import json
import math
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py.node_support import STACKS_SIGNAL
from seft_ros.analysis.bag import read_run

REPO = Path(__file__).resolve().parents[2]
PARAMS_FILE = 'config/default.yaml'   # relative to REPO, as in the docs
LIB = Path(sys.executable).parent.parent / 'lib'

#: The docs' start order (the recorder first) with each executable's package.
NODES = (('recorder', 'seft_ros'), ('ground_motion_publisher', 'seft_ros'),
         ('reference_force_builder', 'seft_ros'), ('force_servo_controller', 'seft_ros'),
         ('rig', 'seft_plant_sim'))
NODE_NAMES = tuple(n for n, _ in NODES)

#: Every node, as the docs' P: a short run (n_steps from the ground-motion publisher's
#: record length), and the rig waits for the recorder (else a slow discovery lets the rig run
#: and exit before the recorder heard it: no sample, no final status in the bag).
SHORT = ('-p', 'duration_s:=1.0', '-p', 'wait_for_recorder:=true')
N_STEPS = 500

EXIT_TIMEOUT_S = 30.0


def executable(node: str, package: str) -> Path:
    path = LIB / package / node
    assert path.is_file() and os.access(path, os.X_OK), f'{path}: node executable missing'
    return path


def session_members(sids) -> list[str]:
    """Command lines of live processes in any of the sessions `sids` (leftover processes)."""
    found = []
    for pid in os.listdir('/proc'):
        if not pid.isdigit():
            continue
        try:
            stat = Path(f'/proc/{pid}/stat').read_text()
            cmd = Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode()
        except OSError:
            continue
        fields = stat[stat.rindex(')') + 2:].split()   # after 'pid (comm) '
        state, sid = fields[0], int(fields[3])
        if sid in sids and state != 'Z':
            found.append(f'{pid}: {cmd}')
    return found


class Graph:
    """The node processes of one run, each in its own session, output in files."""

    def __init__(self, tmp_path: Path, env: dict):
        self.dir, self.env = tmp_path, env
        self.procs: dict[str, subprocess.Popen] = {}
        self.codes: dict[str, int | None] = {}
        #: Seconds from the start of the first node to each node's exit.
        self.exit_s: dict[str, float] = {}
        self.started = 0.0

    def start(self, extra: dict[str, tuple[str, ...]]) -> None:
        """Start every node as the docs do, `extra[node]` appended to its ``-p`` list."""
        self.started = time.monotonic()
        for node, package in NODES:
            argv = [str(executable(node, package)), '--ros-args', '--params-file', PARAMS_FILE,
                    *SHORT, *extra.get(node, ())]
            with open(self.dir / f'{node}.out', 'wb') as out, \
                    open(self.dir / f'{node}.err', 'wb') as err:
                self.procs[node] = subprocess.Popen(
                    argv, cwd=REPO, env=self.env, stdin=subprocess.DEVNULL, stdout=out,
                    stderr=err, start_new_session=True)

    def wait(self, timeout: float) -> dict[str, int | None]:
        """Exit code of every node (None: still running after `timeout` seconds)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for node, proc in self.procs.items():
                if node not in self.exit_s and proc.poll() is not None:
                    self.exit_s[node] = time.monotonic() - self.started
            if len(self.exit_s) == len(self.procs):
                break
            time.sleep(0.05)
        self.codes = {node: proc.poll() for node, proc in self.procs.items()}
        alive = [proc for proc in self.procs.values() if proc.poll() is None]
        for proc in alive:
            # where a node that did not end is: its threads' stacks to its stderr (output())
            os.kill(proc.pid, STACKS_SIGNAL)
        if alive:
            time.sleep(1.0)
        return dict(self.codes)

    def stderr(self, node: str) -> str:
        return (self.dir / f'{node}.err').read_text(errors='replace')

    def output(self) -> str:
        """Everything the nodes wrote, for failure messages."""
        return '\n'.join(f'--- {node} (exit {self.codes.get(node)} after '
                         f'{self.exit_s.get(node, math.nan):.1f} s) ---\n'
                         + (self.dir / f'{node}.out').read_text(errors='replace')
                         + self.stderr(node) for node in self.procs)

    def stop(self) -> list[str]:
        """SIGINT, then SIGKILL, every process group still alive; return the leftovers."""
        for sig, grace in ((signal.SIGINT, 10.0), (signal.SIGKILL, 5.0)):
            alive = [p for p in self.procs.values() if session_members({p.pid})]
            for proc in alive:
                try:
                    os.killpg(proc.pid, sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + grace
            while alive and time.monotonic() < deadline:
                alive = [p for p in alive if session_members({p.pid})]
                for proc in alive:
                    proc.poll()
                time.sleep(0.05)
        for proc in self.procs.values():
            proc.poll()
        return session_members({p.pid for p in self.procs.values()})


@pytest.fixture
def graph(tmp_path, ros_env):
    g = Graph(tmp_path, ros_env)
    try:
        yield g
    finally:
        leftovers = g.stop()
        assert leftovers == [], f'leftover node processes: {leftovers}'


def read_bag(path: Path):
    """``{topic: message count}`` and ``{topic: [message, ...]}`` read by rosbags."""
    store = get_typestore(Stores.ROS2_JAZZY)
    messages = defaultdict(list)
    with Reader(path) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn, _, raw in reader.messages():
            if conn.topic in ('/seft/node_parameters', '/seft/status'):
                messages[conn.topic].append(store.deserialize_cdr(raw, conn.msgtype))
    return counts, messages


#: The one line a node prints for the docs' mistake: the nodes whose parameters it had
#: received by then with their alpha (the builder's 0.5, the others' 0.0), grouped by value.
ALPHA_LINE = re.compile(r'(?P<node>\w+): error: parameter alpha differs: '
                        r'(?P<values>\w+=\d\.\d(, \w+=\d\.\d)+)')


def test_a_node_that_does_not_end_says_where_it_is(tmp_path, ros_env):
    """``kill -USR1`` of a node process: every thread's Python stack on its stderr, and the
    node goes on (a builder that did its 500 lockstep steps was alive 60 s later under the
    suite's load, printed nothing and ignored SIGINT: its stack says where it waits)."""
    graph = Graph(tmp_path, ros_env)
    graph.procs['rig'] = subprocess.Popen(
        [str(executable('rig', 'seft_plant_sim')), '--ros-args', '--params-file', PARAMS_FILE,
         *SHORT], cwd=REPO, env=ros_env, stdin=subprocess.DEVNULL,
        stdout=open(tmp_path / 'rig.out', 'wb'), stderr=open(tmp_path / 'rig.err', 'wb'),
        start_new_session=True)
    try:
        # alone, the rig waits for its graph (the recorder, the controller) and never ends
        assert graph.wait(4.0) == {'rig': None}, graph.output()
        stacks = graph.stderr('rig')
        assert re.search(r'^Current thread 0x[0-9a-f]+ \(most recent call first\):\n'
                         r'(  File .*\n)*  File ".*node_support\.py", line \d+ in main_for_nodes$',
                         stacks,
                         re.MULTILINE), stacks
        assert graph.procs['rig'].poll() is None, stacks          # and it goes on
    finally:
        assert graph.stop() == []
    assert graph.procs['rig'].returncode is not None


def test_readme_mistake_alpha_on_one_node_is_refused(graph, tmp_path):
    """Issue 12: ``-p alpha:=0.5`` on the builder only; nothing runs, every node names it."""
    bag = tmp_path / 'bag'
    graph.start({'recorder': ('-p', f'bag_path:={bag}'),
                 'reference_force_builder': ('-p', 'alpha:=0.5')})
    codes = graph.wait(EXIT_TIMEOUT_S)
    out = graph.output()
    assert codes == {n: 2 for n in NODE_NAMES}, out
    assert 'Traceback' not in out, out
    rig_err = graph.stderr('rig')
    assert 'starting' not in rig_err, out       # the rig never started stepping
    for node in NODE_NAMES:
        lines = [ln for ln in graph.stderr(node).splitlines() if 'alpha' in ln]
        assert len(lines) == 1, (node, out)
        m = ALPHA_LINE.fullmatch(lines[0])
        assert m, (node, lines[0])
        assert m['node'] == node, lines[0]
        named = dict(part.split('=') for part in m['values'].split(', '))
        assert len(named) == len(m['values'].split(', ')), lines[0]    # each node once
        assert named.pop('reference_force_builder') == '0.5', lines[0]
        assert named and set(named) <= set(NODE_NAMES), lines[0]
        assert set(named.values()) == {'0.0'}, lines[0]
        # alpha is the only difference
        assert [ln for ln in graph.stderr(node).splitlines() if 'differs' in ln] == lines, out
    # nothing ran: the recorder's bag (closed on exit) holds no sample of the rig
    if bag.exists():
        counts, messages = read_bag(bag)
        assert counts.get('/seft/measured_force', 0) == 0, counts
        assert counts.get('/seft/reference_force', 0) == 0, counts


def test_alpha_on_every_node_runs_and_records_each_nodes_parameters(
        graph, tmp_path, seft_exe, run_process):
    """The docs' command with alpha on every node: the run completes, the bag holds each
    node's parameters, and ``seft compare`` takes alpha from the reference-force builder."""
    bag = tmp_path / 'bag'
    alpha = ('-p', 'alpha:=0.5')
    extra = {node: alpha for node in NODE_NAMES}
    extra['recorder'] = (*alpha, '-p', f'bag_path:={bag}')
    graph.start(extra)
    codes = graph.wait(60.0)
    out = graph.output()
    assert codes == {n: 0 for n in NODE_NAMES}, out
    assert 'Traceback' not in out and 'differs' not in out, out

    counts, messages = read_bag(bag)
    assert counts['/seft/measured_force'] == N_STEPS, counts
    entries = [json.loads(m.data) for m in messages['/seft/node_parameters']]
    assert sorted(e['node'] for e in entries) == sorted(NODE_NAMES), entries
    for e in entries:
        assert e['parameters']['alpha'] == 0.5, e['node']
        assert e['parameters'].get('duration_s', 1.0) == 1.0, e['node']

    run = read_run(bag)
    assert run.params['alpha'] == 0.5
    assert run.extra['param_sources']['alpha'] == 'reference_force_builder'
    assert run.extra['parameter_mismatches'] == []
    assert set(run.extra['node_params']) == set(NODE_NAMES)
    assert all(v['alpha'] == 0.5 for v in run.extra['node_params'].values())
    assert run.n_steps == N_STEPS

    report = tmp_path / 'report'
    proc = run_process([seft_exe, 'compare', bag, '--out', report], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert 'Traceback' not in proc.stderr
    (entry,) = json.loads((report / 'summary.json').read_text())['runs']
    assert (entry['alpha'], entry['stable']) == (0.5, True), entry
    assert entry['parameter_sources']['alpha'] == 'reference_force_builder'
    # the errors against the alpha = 0.5 reference are those of the same run simulated in one
    # process (uncompensated servohydraulic rig: about 30 % displacement NRMS over 1 s)
    sim_out = tmp_path / 'sim'
    proc = run_process([seft_exe, 'simulate', '--alpha', '0.5', '--duration', '1.0', '--out',
                        sim_out], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    (sim,) = json.loads((sim_out / 'summary.json').read_text())['runs']
    assert sim['alpha'] == 0.5
    for name in ('displacement', 'acceleration', 'force'):
        assert entry['nrms'][name] == pytest.approx(sim['nrms'][name], rel=1e-9, abs=1e-12), name
