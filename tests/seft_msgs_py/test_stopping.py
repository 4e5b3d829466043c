"""How a node process takes its stop requests (seft_msgs_py.stopping): a second signal held
by a node's safe stop, within a bound; the end of the runner that started it.

The node processes themselves are in tests/seft_ros/test_faults.py (a hang-up, a killed
runner, a second Ctrl-C during the rig's real-time ramp).
"""

import signal
import subprocess
import sys
import time

import pytest

from seft_msgs_py import stopping
from seft_msgs_py.errors import Interrupted
from seft_msgs_py.rig_contract import SAFE_HOLD_S, safe_stop_s
from seft_msgs_py.stopping import RunnerWatch, StopRequests, signal_name


def test_a_second_signal_is_held_by_a_safe_stop_and_a_third_ends(capsys):
    requests = StopRequests(lambda: 0.3, 'rig')
    requests.on_signal(signal.SIGHUP, None)
    assert requests.names == ['SIGHUP']
    requests.on_signal(signal.SIGINT, None)            # held: no KeyboardInterrupt
    assert requests.held == 'SIGINT' and requests.names == ['SIGHUP']
    requests.check()
    requests.check()
    err = capsys.readouterr().err
    assert err.count('\n') == 1                         # said once
    assert err.startswith('rig: SIGINT again: finishing the safe stop first (at most 2.')
    assert err.endswith(' s more; one more signal ends the process now)\n')
    with pytest.raises(KeyboardInterrupt):
        requests.on_signal(signal.SIGINT, None)


def test_without_a_safe_stop_a_second_signal_ends_at_once():
    requests = StopRequests(lambda: 0.0, 'force_servo_controller')
    requests.on_signal(signal.SIGINT, None)
    with pytest.raises(KeyboardInterrupt):
        requests.on_signal(signal.SIGINT, None)


def test_a_held_signal_ends_the_process_past_the_bound(monkeypatch, capsys):
    """The hold is bounded: its length plus STOP_HOLD_MARGIN_S from the first request; a
    second signal after that ends the process at once, and a held one ends it once the
    loop sees the bound passed."""
    monkeypatch.setattr(stopping, 'STOP_HOLD_MARGIN_S', 0.05)
    requests = StopRequests(lambda: 0.05, 'rig')
    requests.request('the end of its runner (pid 7)')
    requests.on_signal(signal.SIGTERM, None)
    assert requests.held == 'SIGTERM'
    requests.check()
    time.sleep(0.15)
    with pytest.raises(KeyboardInterrupt):
        requests.check()
    assert 'did not end within its bound' in capsys.readouterr().err
    late = StopRequests(lambda: 0.05, 'rig')
    late.on_signal(signal.SIGINT, None)
    time.sleep(0.15)
    with pytest.raises(KeyboardInterrupt):
        late.on_signal(signal.SIGINT, None)


def test_the_rigs_safe_stop_is_its_latency_ramp_and_hold(reference_params):
    realtime = dict(reference_params, mode='realtime')
    assert safe_stop_s(realtime) == pytest.approx(
        realtime['io_latency_s'] + realtime['safe_ramp_s'] + SAFE_HOLD_S)
    assert safe_stop_s(dict(reference_params, mode='lockstep')) == 0.0


def test_the_runner_watch_sees_its_runner_end_zombie_or_gone(monkeypatch):
    runner = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)'])
    try:
        monkeypatch.setenv(stopping.RUNNER_PID_ENV, str(runner.pid))
        watch = RunnerWatch.from_environment()
        assert watch.pid == runner.pid and not watch.gone()
        assert watch.reason == f'the end of its runner (pid {runner.pid})'
        runner.kill()
        time.sleep(0.1)                           # ended, not waited for: a zombie
        assert not watch.gone()                   # checked 0.1 s ago: not again yet
        assert watch.gone(time.monotonic() + stopping.RUNNER_CHECK_S)
    finally:
        runner.kill()
        runner.wait()
    # a runner that ended before the node started its watch: gone at the first check
    assert RunnerWatch(runner.pid).gone()
    # started by hand (no runner): no watch
    monkeypatch.delenv(stopping.RUNNER_PID_ENV)
    assert RunnerWatch.from_environment() is None
    monkeypatch.setenv(stopping.RUNNER_PID_ENV, '1')
    assert RunnerWatch.from_environment() is None


def test_the_signal_of_an_interrupt():
    assert signal_name(KeyboardInterrupt()) == 'SIGINT'
    assert signal_name(KeyboardInterrupt('SIGHUP')) == 'SIGHUP'
    assert signal_name(Interrupted('SIGTERM', 'nothing was run')) == 'SIGTERM'


def test_a_signal_that_ends_the_process_during_a_callback_is_left_to_the_loop(capsys):
    """While the loop spins (a node's callback may run), the second signal does not raise
    in the handler (it surfaced inside the callback, the executor's '[FATAL] Exception in
    'timers' callback' with a traceback): the loop's check ends the process in one line; a
    further signal while that end is pending raises at once."""
    requests = StopRequests(lambda: 0.0, 'rig')
    requests.on_signal(signal.SIGINT, None)
    requests.spinning = True
    requests.on_signal(signal.SIGTERM, None)            # inside a callback: no raise
    assert requests.end_now == 'SIGTERM'
    with pytest.raises(KeyboardInterrupt):
        requests.on_signal(signal.SIGTERM, None)        # the callback does not return
    requests.spinning = False
    with pytest.raises(KeyboardInterrupt):
        requests.check()
    assert capsys.readouterr().err == 'rig: SIGTERM again: ending the process now\n'


#: A node process whose main thread is in a timer callback most of the time (50 ms busy
#: every 5 ms), stopped safely by nothing: a second signal ends it.
BUSY_NODE = """
import sys, time
from seft_msgs_py.node_support import SeftNode, main_for_nodes


class Busy(SeftNode):
    def __init__(self):
        super().__init__('recorder')
        self.said = False
        self.wall_timer(0.005, self._busy)

    def _busy(self):
        if not self.said:
            self.said = True
            print('ready', flush=True)
        end = time.monotonic() + 0.05
        while time.monotonic() < end:
            pass

    def on_stop_signal(self, signame):
        print('stop ' + signame, flush=True)


sys.exit(main_for_nodes([(Busy, 'busy', None)], ['busy']))
"""


def test_a_second_signal_inside_a_nodes_callback_ends_it_in_one_line(tmp_path, ros_env):
    """Session 23: the runner's SIGINT, then its SIGTERM, ended a refused rig with '[FATAL]
    [rig]: Exception in 'timers' callback' and a KeyboardInterrupt traceback. Now the
    process ends with one line."""
    script = tmp_path / 'busy.py'
    script.write_text(BUSY_NODE)
    proc = subprocess.Popen([sys.executable, str(script)], env=ros_env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert proc.stdout.readline() == 'ready\n'
        proc.send_signal(signal.SIGINT)
        assert proc.stdout.readline() == 'stop SIGINT\n'
        time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
        proc.wait()
    assert 'Traceback' not in err and 'Exception in' not in err, err
    assert err.strip().splitlines() == ['busy: SIGTERM again: ending the process now']
