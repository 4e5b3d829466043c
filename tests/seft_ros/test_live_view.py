"""The live view as a person uses it: ``seft run --live`` started from the command line,
Foxglove's WebSocket protocol spoken by a client of the tests, the web page opened in a real
browser (Debian's headless Chromium driven by Playwright), everything checked against the
bag on disk.

* a lockstep run with a token: the Foxglove client (through the token proxy) receives every
  advertised channel, each value spot-checked against the bag; the page draws the plots as
  they advance and turns ``done``; a wrong token is refused in one line each;
* a real-time run with the operator's stop: the Foxglove client receives every channel,
  the timing among them, checked against the bag; the page's stop button ends the test, the
  page turns ``aborted`` with the reason, the rig goes to its safe state and the bag names
  who stopped it;
* bad input: a port in use, an address that cannot be bound, bad options: one line each,
  and the test runs on;
* TLS: the page over https and Foxglove over wss, with and without a token.

Screenshots of the page go to ``$SEFT_SCREENSHOT_DIR`` (the docs' figures come from there:
``SEFT_SCREENSHOT_DIR=docs/figures``), else to the test's temporary folder.
"""

import json
import os
from pathlib import Path
import re
import shutil
import socket
import ssl
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request

from foxglove_client import FoxgloveClient
import numpy as np
import pytest
from test_node_graph_integration import leftover_processes, read_bag, stamps_ns
from websockets.exceptions import InvalidStatus

from seft_msgs_py.convert import status_values
from seft_msgs_py.signals import TIMING_FIELDS

DT_NS = 2_000_000
CHROMIUM = '/usr/bin/chromium'
#: As the machine's notes say: without the background-networking flags Chromium's
#: connections are refused by this machine's closed network, many at a time.
CHROMIUM_ARGS = ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
                 '--disable-background-networking', '--disable-component-update',
                 '--disable-sync']
TOKEN = 'lab-b-watches-7Qx'


def free_port_pair() -> int:
    """A port P with P and P+1 free on 127.0.0.1 (Foxglove, the page)."""
    for _ in range(50):
        with socket.socket() as s:
            s.bind(('127.0.0.1', 0))
            port = s.getsockname()[1]
        if port >= 65534:
            continue
        try:
            with socket.socket() as a, socket.socket() as b:
                a.bind(('127.0.0.1', port))
                b.bind(('127.0.0.1', port + 1))
            return port
        except OSError:
            continue
    raise RuntimeError('no free pair of ports')


class SeftRun:
    """``seft run`` in the background; its stderr lines as they come."""

    def __init__(self, seft_exe, args, env, cwd):
        self.proc = subprocess.Popen([str(seft_exe), 'run', *map(str, args)], cwd=cwd,
                                     env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True,
                                     start_new_session=True)
        self.lines: list[str] = []
        self.stdout = ''
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        for line in self.proc.stderr:
            self.lines.append(line.rstrip('\n'))

    def wait_line(self, pattern: str, timeout: float = 60.0) -> re.Match:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in list(self.lines):
                m = re.search(pattern, line)
                if m:
                    return m
            if self.proc.poll() is not None and not self.thread.is_alive():
                break
            time.sleep(0.05)
        raise AssertionError(f'no line matching {pattern!r}:\n' + '\n'.join(self.lines))

    def finish(self, timeout: float = 150.0) -> int:
        try:
            self.stdout = self.proc.stdout.read() if self.proc.stdout else ''
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, 2)
            self.proc.wait(20)
            raise
        self.thread.join(5)
        return code

    @property
    def stderr(self) -> str:
        return '\n'.join(self.lines)


@pytest.fixture(scope='module')
def chromium():
    """Playwright's Chromium: Debian's (tools/setup.sh installs it where CI=true or
    SEFT_BROWSER=1); skipped on a developer's machine without it, a failure in CI."""
    if not Path(CHROMIUM).is_file():
        if os.environ.get('CI') == 'true':
            pytest.fail(f'{CHROMIUM} missing: tools/setup.sh installs it when CI=true')
        pytest.skip(f'{CHROMIUM} missing (SEFT_BROWSER=1 bash tools/setup.sh installs it)')
    from playwright.sync_api import sync_playwright
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield browser
        browser.close()


def new_page(browser):
    """A page at a control-room screen's size. The page's Content-Security-Policy forbids
    eval, which Playwright's wait_for_function uses: the test's context bypasses it."""
    return browser.new_context(viewport={'width': 1500, 'height': 1150},
                               bypass_csp=True).new_page()


def screenshot_dir(tmp_path) -> Path:
    where = Path(os.environ.get('SEFT_SCREENSHOT_DIR') or tmp_path)
    where.mkdir(parents=True, exist_ok=True)
    return where


def plot_points(page) -> dict:
    """The test samples each plot of the page has drawn, by title."""
    return page.eval_on_selector_all(
        '.plot', 'els => Object.fromEntries(els.map(e => [e.dataset.title, '
        '+e.dataset.points]))')


def bag_values(messages, topic, path):
    """``{step: value}`` of a scalar topic of the bag."""
    out = {}
    for stamp, (_, m) in zip(stamps_ns(messages[topic]), messages[topic]):
        v = m
        for part in path.split('.'):
            v = getattr(v, part)
        out[stamp // DT_NS] = v
    return out


#: Live channel field -> (bag topic, where the value is).
SPOT = {
    ('/seft/live/measurement', 'measured_force_N'): ('/seft/measured_force', 'wrench.force.x'),
    ('/seft/live/measurement', 'displacement_m'): ('/seft/displacement', 'point.x'),
    ('/seft/live/measurement', 'velocity_m_s'): ('/seft/velocity', 'twist.linear.x'),
    ('/seft/live/measurement', 'acceleration_m_s2'): ('/seft/acceleration',
                                                      'accel.linear.x'),
    ('/seft/live/reference_force', 'reference_force_N'): ('/seft/reference_force',
                                                          'wrench.force.x'),
    ('/seft/live/valve_command', 'valve_command_V'): ('/seft/valve_command', 'vector.x'),
    ('/seft/live/ground_acceleration', 'ground_acceleration_m_s2'): (
        '/seft/ground_acceleration', 'accel.linear.x'),
}


def check_channels_against_bag(client: FoxgloveClient, messages, may_be_empty=()) -> dict:
    """Every advertised channel received messages (but those of `may_be_empty`); every shown
    sample of a data channel equals the bag's sample of its step (the values are the recorded
    ones, unchanged), at the display rate's steps (every 10th); returns the messages by
    channel."""
    received = {t: client.json_messages(t) if t != '/seft/live/events' else
                client.messages.get(t, []) for t in client.advertised}
    empty = [t for t, ms in received.items() if not ms and t not in may_be_empty]
    # the message short enough to survive pytest's truncation: what was empty, the server's
    # statuses, how the connection ended; then the counts of every channel
    assert not empty, (f'advertised but never received: {empty}; server statuses: '
                       f'{[o.get("message") for o in client.ops if o.get("op") == "status"]}; '
                       f'connection: {client.closed_by or "open to the end"}',
                       {t: len(ms) for t, ms in received.items()}, client.ops)
    for (channel, name), (topic, path) in SPOT.items():
        if channel not in received or topic not in messages:
            continue
        bag = bag_values(messages, topic, path)
        shown = received[channel]
        assert all(m['step'] % 10 == 0 for m in shown), channel
        assert all(m['t_s'] == pytest.approx(m['step'] * 0.002, abs=1e-12) for m in shown)
        mismatched = [(m['step'], m[name], bag.get(m['step'])) for m in shown
                      if bag.get(m['step']) != m[name]]
        assert not mismatched, (channel, name, mismatched[:5])
    return received


def final_statuses(messages) -> dict:
    out = {}
    for _, m in messages['/seft/status']:
        values = status_values(m)
        if values.get('state') in ('done', 'aborted', 'failed'):
            out.setdefault(m.name, values | {'message': m.message})
    return out


def test_lockstep_run_live_in_foxglove_and_a_browser(tmp_path, seft_exe, ros_env, chromium):
    port = free_port_pair()
    env = dict(ros_env, SEFT_LIVE_TOKEN=TOKEN)
    page = new_page(chromium)
    run = SeftRun(seft_exe, ['--live', f'127.0.0.1:{port}', '--alpha', '0.5', '--duration',
                             '20', '--out', tmp_path / 'run'], env, tmp_path)
    try:
        web = run.wait_line(r'live view: web page (\S+)').group(1)
        fox = run.wait_line(r'live view: Foxglove (\S+)').group(1)
        assert web == f'http://127.0.0.1:{port + 1}/?token={TOKEN}'
        assert fox == f'ws://127.0.0.1:{port}/?token={TOKEN}'
        client = FoxgloveClient(fox)
        # a wrong token: refused, for Foxglove and for the page
        with pytest.raises(InvalidStatus, match='403'):
            FoxgloveClient(f'ws://127.0.0.1:{port}/?token=guess')
        with pytest.raises(urllib.error.HTTPError, match='403'):
            urllib.request.urlopen(f'http://127.0.0.1:{port + 1}/?token=guess', timeout=10)
        page.goto(web)
        # the plots advance while the run goes (the page's own count of drawn samples)
        page.wait_for_function("document.querySelector('.plot') && "
                               "+document.querySelector('.plot').dataset.points > 20",
                               timeout=60_000)
        first = plot_points(page)
        page.wait_for_timeout(700)
        later = plot_points(page)
        page.wait_for_function("document.getElementById('state').dataset.state === 'done'",
                               timeout=120_000)
        page.wait_for_timeout(400)
        page.screenshot(path=str(screenshot_dir(tmp_path) / 'live_view.png'))
        final = plot_points(page)
        code = run.finish()
        client.close()
    finally:
        page.close()
        if run.proc.poll() is None:
            os.killpg(run.proc.pid, 2)
    assert code == 0, run.stderr
    assert 'Traceback' not in run.stderr
    assert leftover_processes(str(tmp_path / 'run')) == []
    titles = ['Force', 'Displacement', 'Acceleration', 'Valve command']
    assert list(first) == titles
    advanced = [t for t in titles if later[t] > first[t] or final[t] > first[t]]
    assert advanced == titles, (first, later, final)
    # one line each for the refused clients
    assert run.stderr.count('live view: refused a Foxglove client from 127.0.0.1: wrong '
                            'token') == 1, run.stderr
    assert run.stderr.count('live view: refused a page from 127.0.0.1: wrong token') == 1
    bag = next((tmp_path / 'run').glob('*/bag'))
    _, messages = read_bag(bag)
    received = check_channels_against_bag(client, messages)
    assert set(received) == {
        '/seft/live/run', '/seft/live/events', '/seft/live/measurement',
        '/seft/live/reference_force', '/seft/live/valve_command',
        '/seft/live/ground_acceleration', '/seft/live/analytical'}
    # the analytical reference at the shown steps: the whole structure's response
    from seft_ros.analysis.bag import read_run
    from seft_ros.analysis.reference import reference_from_run
    rd = read_run(bag)
    ref = reference_from_run(rd)
    for m in received['/seft/live/analytical']:
        k = m['step']
        assert m['displacement_m'] == pytest.approx(ref.displacement_m[k], rel=1e-9,
                                                    abs=1e-15)
        assert m['force_N'] == pytest.approx(ref.force_N[k], rel=1e-9, abs=1e-9)
    states = [m['state'] for m in received['/seft/live/run']]
    assert states[-1] == 'done' and 'running' in states
    assert received['/seft/live/run'][-1]['bag_closed'] is True


def test_realtime_run_live_with_the_operator_stop(tmp_path, seft_exe, ros_env, chromium):
    port = free_port_pair()
    page = new_page(chromium)
    page.on('dialog', lambda dialog: dialog.accept())
    run = SeftRun(seft_exe, ['--mode', 'realtime', '--live', f'127.0.0.1:{port}',
                             '--live-stop', '--alpha', '0.5', '--duration', '10', '--set',
                             'monitor_threshold=0', '--set', 'watchdog_timeout_s=0.5',
                             '--out', tmp_path / 'run'], ros_env, tmp_path)
    try:
        web = run.wait_line(r'live view: web page (\S+) \(with the operator stop button\)'
                            ).group(1)
        fox = run.wait_line(r'live view: Foxglove (\S+)').group(1)
        assert fox == f'ws://127.0.0.1:{port}'
        client = FoxgloveClient(fox)
        page.goto(web)
        page.wait_for_function("document.querySelector('.plot') && "
                               "+document.querySelector('.plot').dataset.points > 50",
                               timeout=60_000)          # 1 s of the test drawn
        before = plot_points(page)
        page.click('#stop')
        page.wait_for_function(
            "document.getElementById('state').dataset.state === 'aborted'", timeout=30_000)
        reason = page.inner_text('#reason')
        page.wait_for_timeout(400)
        page.screenshot(path=str(screenshot_dir(tmp_path) / 'live_view_aborted.png'))
        code = run.finish()
        client.close()
    finally:
        page.close()
        if run.proc.poll() is None:
            os.killpg(run.proc.pid, 2)
    assert code == 0, run.stderr
    assert 'Traceback' not in run.stderr
    assert 'operator stop from the live view (client 127.0.0.1)' in reason, reason
    assert reason.startswith('aborted: ')
    assert before['Loop latency'] > 0
    assert 'live view: operator stop from the live view (client 127.0.0.1): the rig goes ' \
        'to its safe state' in run.stderr
    bag = next((tmp_path / 'run').glob('*/bag'))
    _, messages = read_bag(bag)
    # the bag says who stopped it: the live view's report and the rig's final status
    reports = [(m.name, status_values(m)) for _, m in messages['/seft/status']]
    stops = [(m, v) for m, v in reports if m == 'seft_live' and v['state'] != 'ready']
    assert len(stops) == 1 and stops[0][1]['state'] == 'aborted'
    # the view said it matched every stream of this run before the rig started (the
    # recorder's wait_for_live_view): it shows the run from its first sample
    params = json.loads(messages['/seft/run_parameters'][-1][1].data)
    matched = [i for i, (m, v) in enumerate(reports) if m == 'seft_live'
               and v['state'] == 'ready' and v['run_token'] == params['run_token']]
    started = next(i for i, (m, v) in enumerate(reports) if m == 'rig'
                   and v['state'] == 'running')
    assert len(matched) == 1 and matched[0] < started
    assert stops[0][1]['stopped_by'] == 'operator' and stops[0][1]['client'] == '127.0.0.1'
    rig = final_statuses(messages)['rig']
    assert rig['state'] == 'aborted' and rig['ended_by'] == 'seft_live'
    assert 'operator stop' in rig['message']
    # the safe state: the valve ramped closed over safe_ramp_s after the stop, sampled to
    # its end; the piston then only creeps (as the fault tests check)
    from seft_ros.analysis.bag import read_run
    rd = read_run(bag)
    abort_at = float(rig['abort_at_s'])
    assert 1.0 < abort_at < 9.0
    v = np.array([m.twist.linear.x for _, m in messages['/seft/velocity']])
    f = np.array([m.wrench.force.x for _, m in messages['/seft/measured_force']])
    p = rd.params
    assert len(v) * 0.002 >= abort_at + p['safe_ramp_s']
    creep = ((p['valve_pressure_coefficient_m3_per_s_Pa'] + p['leakage_coefficient_m3_per_s_Pa'])
             * np.abs(f[-5:]) / p['piston_area_m2'] ** 2)
    assert np.all(np.abs(v[-5:]) <= 1.2 * creep + 1e-4)
    # Foxglove: every channel, the timing among them, against the bag
    received = check_channels_against_bag(client, messages)
    timing = {t for t in received if '/timing/' in t}
    assert timing == {f'/seft/live/timing/{n}' for n in (
        'rig', 'force_servo_controller', 'reference_force_builder',
        'ground_motion_publisher')}
    rows = {int(round(s / DT_NS)): list(m.position) for s, (_, m) in
            zip(stamps_ns(messages['/seft/timing/rig']), messages['/seft/timing/rig'])}
    missed_until = np.cumsum([rows[k][TIMING_FIELDS.index('missed_deadline')]
                              for k in sorted(rows)])
    for m in received['/seft/live/timing/rig']:
        row = rows[m['step']]
        latency = row[TIMING_FIELDS.index('loop_latency_s')]
        assert m['loop_latency_s'] == (latency if latency == latency else None)
        # the running total counts every sample up to the shown one, shown or not
        assert m['missed_deadlines'] == missed_until[sorted(rows).index(m['step'])]
    states = [m['state'] for m in received['/seft/live/run']]
    assert states[-1] == 'aborted' and received['/seft/live/run'][-1]['stopped_by']
    events = [e for _, e in client.messages['/seft/live/events']]
    assert any(b'operator stop' in e for e in events)


def test_live_view_bad_input_is_one_line_and_the_test_runs_on(tmp_path, seft_exe, ros_env,
                                                              run_process):
    port = free_port_pair()
    # the Foxglove port in use: one line, the page still served, the run completes
    with socket.socket() as blocker:
        blocker.bind(('127.0.0.1', port))
        blocker.listen()
        proc = run_process([seft_exe, 'run', '--live', f'127.0.0.1:{port}', '--duration',
                            '1', '--out', tmp_path / 'busy'], cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if 'live view:' in ln]
    assert lines[0] == (f'[seft] live view: Foxglove cannot listen on 127.0.0.1:{port}: '
                        f'port {port} is in use (another live view or program?)'), lines
    assert lines[1].startswith(f'[seft] live view: web page http://127.0.0.1:{port + 1}/')
    assert len(lines) == 2 and 'Traceback' not in proc.stderr
    # an address that is not this host's (TEST-NET-1): a line each, then off; the run goes on
    proc = run_process([seft_exe, 'run', '--live', f'192.0.2.1:{port}', '--duration', '1',
                        '--out', tmp_path / 'far'], cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if 'live view:' in ln]
    # (another address than this machine's: a token, so Foxglove is behind the proxy)
    assert sorted(lines[:2]) == [
        f'[seft] live view: Foxglove cannot listen on 192.0.2.1:{port}: 192.0.2.1 is not an '
        'address of this host',
        f'[seft] live view: the web page cannot listen on 192.0.2.1:{port + 1}: 192.0.2.1 is '
        'not an address of this host'], proc.stderr
    assert lines[2:] == ['[seft] live view: off; the test runs without it'], proc.stderr
    assert (tmp_path / 'far' / 'report.md').is_file()


def test_a_bad_live_option_is_one_line_and_nothing_runs(tmp_path, seft_exe, run_process):
    proc = run_process([seft_exe, 'run', '--live', 'lab:port', '--duration', '1', '--out',
                        tmp_path / 'x'], cwd=tmp_path, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        'seft: error: --live lab:port: expected [HOST][:PORT] with PORT 1-65534 (the web page '
        'takes PORT+1), e.g. --live 0.0.0.0:8765']
    assert not (tmp_path / 'x').exists()


@pytest.mark.parametrize('args,expected', [
    (['--live', ':65535'], '--live :65535: expected [HOST][:PORT]'),
    (['config/main.yaml', '--live'], None),
    (['--live', 'config/main.yaml'], '--live config/main.yaml: expected [HOST][:PORT], not a '
     'configuration file'),
    (['--live-stop'], '--live-stop and --live-tls need --live [ADDRESS]'),
    (['--live', '--live-tls', 'nocert.pem', 'nokey.pem'],
     '--live-tls: nocert.pem: no such certificate file'),
])
def test_live_options(args, expected):
    """What seft run's parser and the live view's options make of the command line."""
    from seft_msgs_py.errors import InputError
    from seft_ros.cli.live import options_from_args
    from seft_ros.cli.main import build_parser
    parsed = build_parser().parse_args(['run', *args])
    if expected is None:
        assert parsed.config == 'config/main.yaml'
        assert options_from_args(parsed).urls()[0] == 'http://127.0.0.1:8766/'
        return
    with pytest.raises(InputError, match=re.escape(expected)):
        options_from_args(parsed)


@pytest.mark.parametrize('token', ['', TOKEN], ids=['direct', 'token proxy'])
def test_live_view_over_tls(token, tmp_path, ros_env):
    if not shutil.which('openssl'):
        pytest.skip('openssl missing (makes the test certificate)')
    cert, key = tmp_path / 'cert.pem', tmp_path / 'key.pem'
    subprocess.run(['openssl', 'req', '-x509', '-newkey', 'rsa:2048', '-nodes', '-keyout',
                    key, '-out', cert, '-days', '1', '-subj', '/CN=localhost'], check=True,
                   capture_output=True)
    port = free_port_pair()
    env = dict(ros_env, SEFT_LIVE_TOKEN=token)
    proc = subprocess.Popen([sys.executable, '-m', 'seft_ros.live.node', '--port', str(port),
                             '--tls-cert', cert, '--tls-key', key], env=env,
                            stdout=subprocess.PIPE, text=True)
    try:
        lines = []
        for line in proc.stdout:
            lines.append(line.strip())
            if line.startswith('live view: ready') or line.startswith('live view: off'):
                break
        query = f'?token={token}' if token else ''
        assert lines[0] == f'live view: web page https://127.0.0.1:{port + 1}/{query}', lines
        assert lines[1].startswith(f'live view: Foxglove wss://127.0.0.1:{port}')
        context = ssl.create_default_context(cafile=str(cert))
        context.check_hostname = False
        html = urllib.request.urlopen(f'https://127.0.0.1:{port + 1}/{query}',
                                      context=context, timeout=10).read()
        assert b'seft live view' in html
        with pytest.raises(OSError):        # not served without TLS (the server hangs up)
            urllib.request.urlopen(f'http://127.0.0.1:{port + 1}/{query}', timeout=10)
        client = FoxgloveClient(f'wss://127.0.0.1:{port}/{query}', insecure_tls=True)
        deadline = time.monotonic() + 10
        while '/seft/live/run' not in client.advertised and time.monotonic() < deadline:
            time.sleep(0.05)
        assert client.server_info.get('name') == 'seft live view'
        assert client.server_info.get('capabilities') == []            # read-only
        assert '/seft/live/run' in client.advertised
        client.close()
    finally:
        proc.terminate()
        proc.wait(30)          # a loaded host (load 15 on 2 cores) took > 10 s
    assert proc.returncode == 0


def test_layout_file_names_the_channels_of_a_run(reference_params):
    """The shipped Foxglove layout plots paths the live view publishes for the study's run."""
    from seft_ros.live.channels import RunChannels
    from seft_ros.live.node import layout_file
    # the console names it by its absolute path (it named it relative to the repository,
    # wherever seft ran)
    layout = Path(layout_file())
    assert layout == Path(__file__).resolve().parents[2] / 'docs' / 'foxglove' / \
        'seft_live_layout.json'
    text = layout.read_text()
    doc = json.loads(text)
    assert 'configById' in doc or 'content' in doc or 'layout' in doc
    run = RunChannels(dict(reference_params, mode='realtime'))
    run.add_analytical()
    paths = set(re.findall(r'"value":\s*"([^"]+)"', text))
    assert paths, 'no plotted paths'
    known = {f'{c}.{f}' for c, fields in run.fields.items() for f in fields}
    assert paths <= known, sorted(paths - known)
