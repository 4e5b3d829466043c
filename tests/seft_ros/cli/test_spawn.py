"""How the runner starts node processes (seft_ros.cli.spawn): forked from a server that
imported the node modules, or executed; both give the node the same command line, arguments,
environment, log and exit code, and both are stopped alike."""

from pathlib import Path
import signal
import subprocess
import sys
import time

import pytest

from seft_msgs_py.errors import SeftError
from seft_ros.cli import spawn

PROBE = 'spawn_probe'
#: The probe's folder (the executed probe's PYTHONPATH; the fork server has pytest's path).
HERE = Path(__file__).resolve().parent


@pytest.fixture(params=['fork', 'exec'])
def start(request, monkeypatch, tmp_path):
    monkeypatch.setenv(spawn.NODE_START_ENV, request.param)

    def run(*args, env=None):
        log = tmp_path / f'{request.param}-{len(list(tmp_path.glob("*.log")))}.log'
        argv = [sys.executable, '-m', PROBE, *args]
        proc = spawn.start_node(argv, dict(env or {'SPAWN_PROBE': 'set'},
                                           PYTHONPATH=str(HERE)), log, (PROBE,))
        return proc, log, ' '.join(argv)
    run.mode = request.param
    return run


def test_a_started_node_has_its_arguments_environment_command_line_and_exit_code(start):
    proc, log, cmdline = start('3', '--ros-args', '-r', '__ns:=/pier_a')
    assert proc.wait(timeout=30) == 3 and proc.poll() == 3 and proc.returncode == 3
    lines = log.read_text().splitlines()
    assert 'argv 3 --ros-args -r __ns:=/pier_a' in lines
    assert 'env set' in lines                     # the environment given, not the runner's
    assert f'cmdline {cmdline}' in lines          # as ps, pgrep -f and /proc show it
    assert 'stderr too' in lines                  # stdout and stderr in the one log
    assert isinstance(proc, spawn.NodeProcess) == (start.mode == 'fork')
    # forked: the server's objects are frozen out of the collector's way (a node's full
    # collection traversed all of them: 0.13-0.27 s of CPU a node at a graph's start)
    frozen, tracked = (int(w) for w in next(x for x in lines if x.startswith('gc ')).split()[1:])
    if start.mode == 'fork':
        assert frozen > 2 * tracked, (frozen, tracked)        # here 11459 and 1864
    else:
        assert frozen == 0


def test_a_node_killed_by_a_signal_reads_as_popen_has_it(start):
    proc, log, _ = start('sleep', '30')
    deadline = time.monotonic() + 30
    while 'cmdline' not in log.read_text():
        assert time.monotonic() < deadline
        time.sleep(0.02)
    assert proc.poll() is None
    with pytest.raises(subprocess.TimeoutExpired):
        proc.wait(timeout=0.1)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait(timeout=30) == -signal.SIGKILL
    proc.send_signal(signal.SIGKILL)              # ended: a no-op, not another process's


def test_a_command_that_is_not_a_seft_node_module_is_executed(monkeypatch, tmp_path):
    monkeypatch.setenv(spawn.NODE_START_ENV, 'fork')
    log = tmp_path / 'x.log'
    proc = spawn.start_node([sys.executable, '-c', 'print("hello")'], {}, log, (PROBE,))
    assert isinstance(proc, subprocess.Popen) and proc.wait(timeout=30) == 0
    assert log.read_text() == 'hello\n'


@pytest.mark.parametrize('value', ['thread', 'FORK', '1'])
def test_an_unknown_start_method_is_refused(monkeypatch, value):
    monkeypatch.setenv(spawn.NODE_START_ENV, value)
    with pytest.raises(SeftError, match=f"^SEFT_NODE_START='{value}': expected one of fork, "
                                        'exec$'):
        spawn.node_start()
