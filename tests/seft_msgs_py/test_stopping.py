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
