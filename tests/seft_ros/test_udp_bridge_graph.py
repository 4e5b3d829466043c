"""The UDP bridge in the node graph (issue 21): ``seft emulate-controller`` as the lab's
real-time target in a process of its own, ``seft run --set rig_interface=udp_bridge`` as a
user runs it, every node a process over DDS.

* A run through the bridge is the servohydraulic rig in real time: fed the commands of the
  bag at the instants the controller took them (the loop latencies it reported),
  :class:`~seft_plant_sim.realtime.WallClockRig` (the real-time simulated rig's plant)
  reproduces the bag's measurement exactly (measured: bit for bit). Against the lockstep
  simulation of the same parameters (``seft simulate``, which a real-time run with every
  command in time equals) it differs where a command came after its output instant (a stale
  command acts from its arrival, here up to about 1 ms later; 0.2-0.5 % of the samples on
  this shared host): measured 0.00-0.21 % NRMS of the displacement and 0.0-2.7 % of the
  force (the force loop's high frequencies feel a late valve command first); the tolerance is
  1 % and 5 %, checked when at most 1 % of the commands came late (on a noisy day this host
  made 3-10 % late: force 12-27 %; the exact replay checks those runs). The simulated rig in
  real time: 0.00-0.05 % and 0.0-0.3 % (a hop less).
* ``seft rig-check`` passes through the bridge, and catches a controller that sends a channel
  scaled or reversed (``seft emulate-controller --inject``).
* A silent controller (SIGSTOP) ends the run within the watchdog, and the controller, once it
  runs again, reads the PC's safe request; a silent PC (SIGSTOP of the rig node) brings the
  controller to its safe state within the watchdog, and the PC ends the run aborted.
"""

import json
import os
from pathlib import Path
import re
import signal
import socket
import subprocess
import threading
import time

import numpy as np
import pytest
from test_node_graph_integration import leftover_processes
from test_realtime_integration import _pid_of

from seft_plant_sim.realtime import WallClockRig
from seft_ros.analysis.bag import read_run
from seft_ros.core.experiment import simulate

#: NRMS tolerance of a bridge run against the lockstep simulation (module notes).
TOLERANCE = {'displacement_m': 0.01, 'measured_force_N': 0.05}
#: The late-command fraction the tolerance holds for (measured: 0.2-0.5 %, module notes).
STALE_MAX = 0.01


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


class Emulator:
    """``seft emulate-controller`` in a process of its own; its JSON events as they come."""

    def __init__(self, seft_exe, env, cwd, sets, runs=None):
        argv = [str(seft_exe), 'emulate-controller', *sets] + (
            ['--runs', str(runs)] if runs else [])
        self.proc = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, start_new_session=True)
        self.events, self.stderr = [], []
        self.readers = [threading.Thread(target=self._read, args=(self.proc.stdout, True),
                                         daemon=True),
                        threading.Thread(target=self._read, args=(self.proc.stderr, False),
                                         daemon=True)]
        for r in self.readers:
            r.start()
        deadline = time.monotonic() + 30
        while not any('emulating' in line for line in self.stderr):
            assert time.monotonic() < deadline and self.proc.poll() is None, self.stderr
            time.sleep(0.05)

    def _read(self, stream, events):
        for line in stream:
            if events:
                self.events.append(json.loads(line) | {'at': time.monotonic()})
            else:
                self.stderr.append(line)

    def of(self, kind):
        return [e for e in self.events if e['event'] == kind]

    def stop(self):
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGCONT)
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        for r in self.readers:
            r.join(timeout=5)


@pytest.fixture
def bridge_sets():
    return ['--set', 'rig_interface=udp_bridge', '--set',
            f'udp_controller_address=127.0.0.1:{free_port()}']


@pytest.fixture
def emulator(seft_exe, ros_env, tmp_path, bridge_sets):
    made = []

    def start(*extra, runs=None):
        made.append(Emulator(seft_exe, ros_env, tmp_path, bridge_sets + list(extra), runs))
        return made[-1]
    yield start
    for e in made:
        e.stop()


def replay_measurement(run) -> dict:
    """The bag's measurement as WallClockRig makes it from the bag's valve commands, each
    arriving at ``j dt + loop latency`` (the controller's clock)."""
    p = dict(run.params, rig_interface='simulated')
    dt, rig = p['dt'], WallClockRig(p)
    timing = run.extra['timing_data']['rig']
    latency = dict(zip(timing.step.tolist(), timing.loop_latency_s.tolist()))
    assert all(np.isfinite(latency[j]) for j in range(run.n_steps)), 'a latency is missing'
    commands = sorted((j * dt + latency[j], j, run.valve_command_V[j])
                      for j in range(run.n_steps))
    out = {'displacement_m': [], 'measured_force_N': []}
    i = 0
    for k in range(run.n_steps):
        if k > 0:
            rig.advance()
        m = rig.measure()
        out['displacement_m'].append(m.displacement_m)
        out['measured_force_N'].append(m.force_N)
        # the commands that came by the next tick (one that comes later acts later anyway)
        while i < len(commands) and commands[i][0] <= (k + 1) * dt:
            rig.arrive(commands[i][1], commands[i][2], commands[i][0])
            i += 1
    return {name: np.array(values) for name, values in out.items()}


def test_a_run_through_the_bridge_equals_the_servohydraulic_rig(emulator, bridge_sets,
                                                               tmp_path, run_process, seft_exe):
    emu = emulator(runs=1)
    out = tmp_path / 'run'
    proc = run_process([seft_exe, 'run', '--mode', 'realtime', '--alpha', '0.5', '--duration',
                        '2', *bridge_sets, '--out', out], cwd=tmp_path, timeout=180)
    assert proc.returncode == 0, proc.stderr
    assert leftover_processes(str(out)) == []
    run = read_run(next(out.glob('*/bag')))
    assert run.params['rig_interface'] == 'udp_bridge' and run.stable
    assert run.extra['rig_contract'] == 'seft-rig/1.1'
    # the real-time simulated rig's plant, fed the commands as the controller took them
    replay = replay_measurement(run)
    for name in ('displacement_m', 'measured_force_N'):
        assert np.array_equal(replay[name], getattr(run, name)), name
    sim = simulate(dict(run.params, rig_interface='simulated', mode='lockstep'))
    assert run.n_steps == sim.n_steps == 1000
    # against lockstep: within TOLERANCE when at most STALE_MAX of the commands came late, as
    # the tolerance was measured. A host that made more of them late (this shared one does at
    # times: 3-10 % measured, force NRMS 12-27 %) sets the difference itself; the exact
    # replay above has already checked the run with every late command in it.
    stale = np.mean(np.asarray(run.extra['timing_data']['rig'].stale, dtype=bool))
    if stale <= STALE_MAX:
        for name, tolerance in TOLERANCE.items():
            a, b = getattr(run, name), getattr(sim, name)
            nrms = np.sqrt(np.mean((a - b) ** 2) / np.mean(b ** 2))
            assert nrms < tolerance, (name, nrms, stale)
    final = run.extra['rig_final']
    assert final['state'] == 'done'
    for key in ('udp_bad', 'udp_lost', 'udp_duplicate', 'udp_reordered', 'controller_bad',
                'controller_lost', 'controller_duplicate', 'controller_reordered'):
        assert final[key] == '0', key
    # the loop latency of the samples, as the controller measured it
    rig = run.extra['timing_data']['rig']
    latency = np.asarray(rig.loop_latency_s)
    assert np.mean(np.isfinite(latency)) > 0.98
    assert 0 < np.nanmedian(latency) < 0.002
    deadline = time.monotonic() + 10
    while not emu.of('end') and time.monotonic() < deadline:
        time.sleep(0.05)
    end = emu.of('end')[0]
    assert end['samples'] == 1001 and end['lost'] == end['bad'] == end['reordered'] == 0
    assert emu.proc.wait(timeout=10) == 0           # --runs 1: it exits after the run


def test_rig_check_passes_through_the_bridge(emulator, bridge_sets, tmp_path, run_process,
                                             seft_exe):
    watchdog = ['--set', 'watchdog_timeout_s=0.05']      # as test_rig_check.WATCHDOG_S
    emulator(*watchdog)
    out = tmp_path / 'check'
    proc = run_process([seft_exe, 'rig-check', '--rig', 'servohydraulic', *bridge_sets,
                        *watchdog, '--out', out], cwd=tmp_path, timeout=400)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert re.search(r'^rig-check: 21 of 21 checks passed', proc.stdout, re.MULTILINE)


@pytest.mark.parametrize('fault, model, failing, words', [
    # a target that closes the force loop itself and sends the force in kN
    ('force_kN', 'delay', 'force scale', 'kN instead of N?'),
    # the PC closes the force loop; the target sends the acceleration reversed
    ('acceleration_reversed', 'servohydraulic', 'acceleration sign',
     'the builder would feed back -a'),
])
def test_rig_check_catches_a_faulty_controller_through_the_bridge(
        fault, model, failing, words, emulator, bridge_sets, tmp_path, run_process, seft_exe):
    """A lab's controller that sends a channel scaled or reversed (``seft emulate-controller
    --inject``) fails that channel's check through the bridge, and no other check of the step
    run (the safe-state runs are not run: they are not the fault's)."""
    sets = ['--rig', model, '--set', 'watchdog_timeout_s=0.05']
    emulator(*sets, '--inject', fault)
    out = tmp_path / 'check'
    proc = run_process([seft_exe, 'rig-check', *bridge_sets, *sets, '--runs', 'step',
                        '--out', out], cwd=tmp_path, timeout=200)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    failed = [line for line in proc.stdout.splitlines() if line.startswith('FAIL ')
              and ': not measured: the ' not in line]
    assert len(failed) == 1 and failed[0].startswith(f'FAIL {failing}: '), proc.stdout
    assert words in failed[0], failed[0]


def _start_run(seft_exe, env, cwd, out, sets):
    return subprocess.Popen(
        [str(seft_exe), 'run', '--mode', 'realtime', '--alpha', '0.5', '--duration', '20',
         '--set', 'watchdog_timeout_s=0.05', *sets, '--out', str(out)], cwd=cwd, env=env,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def _wait_running(emu, seconds=1.0, timeout=90):
    deadline = time.monotonic() + timeout
    while not emu.of('start'):
        assert time.monotonic() < deadline, 'the run did not start'
        time.sleep(0.05)
    time.sleep(seconds)


def _finish(proc):
    try:
        return proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_a_silent_controller_ends_the_run_and_then_reads_the_safe_request(
        emulator, bridge_sets, tmp_path, seft_exe, ros_env):
    emu = emulator('--set', 'watchdog_timeout_s=0.05')
    out = tmp_path / 'silent_controller'
    proc = _start_run(seft_exe, ros_env, tmp_path, out, bridge_sets)
    _wait_running(emu)
    os.kill(emu.proc.pid, signal.SIGSTOP)
    stopped = time.monotonic()
    _, err = _finish(proc)
    assert 'Traceback' not in err
    run = read_run(next(out.glob('*/bag')))
    final = run.extra['rig_final']
    assert final['state'] == 'aborted'
    assert final['message'].startswith('udp_bridge: no datagram from the controller for ')
    # the silence to 0.1 ms (in whole ms, a watchdog that fired just past 50 ms read '50')
    silent = float(re.search(r'for ([\d.]+) ms', final['message']).group(1))
    assert 50 < silent <= 50 + 15                       # the watchdog, and its check period
    os.kill(emu.proc.pid, signal.SIGCONT)               # the target runs again
    deadline = time.monotonic() + 10
    while not emu.of('end') and time.monotonic() < deadline:
        time.sleep(0.05)
    safe = emu.of('safe_state')
    assert safe and safe[0]['reason'] == 'requested by the PC', emu.events
    assert emu.of('end')[0]['why'] == 'the PC ended the run'
    assert time.monotonic() - stopped < 60


def test_a_silent_pc_brings_the_controller_to_its_safe_state(emulator, bridge_sets, tmp_path,
                                                             seft_exe, ros_env):
    emu = emulator('--set', 'watchdog_timeout_s=0.05')
    out = tmp_path / 'silent_pc'
    proc = _start_run(seft_exe, ros_env, tmp_path, out, bridge_sets)
    _wait_running(emu)
    rig = _pid_of('rig', str(out))
    os.kill(rig, signal.SIGSTOP)
    deadline = time.monotonic() + 5
    while not emu.of('safe_state') and time.monotonic() < deadline:
        time.sleep(0.01)
    os.kill(rig, signal.SIGCONT)
    safe = emu.of('safe_state')
    assert safe and safe[0]['reason'] == 'PC silent', emu.events
    assert 0.05 < safe[0]['silent_s'] <= 0.05 + 0.006        # within the watchdog (+ a tick)
    _, err = _finish(proc)
    run = read_run(next(out.glob('*/bag')))
    assert run.extra['rig_final']['state'] == 'aborted'      # the PC ended it too
    assert not run.stable
    assert Path(out).exists() and leftover_processes(str(out)) == []


def test_emulator_and_bridge_errors_are_one_line(tmp_path, run_process, seft_exe):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(('127.0.0.1', 0))
        port = taken.getsockname()[1]
        proc = run_process([seft_exe, 'emulate-controller', '--set',
                            f'udp_controller_address=127.0.0.1:{port}'], cwd=tmp_path)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        f'seft: error: parameter udp_controller_address=127.0.0.1:{port}: cannot bind it '
        '(Address already in use)')
    proc = run_process([seft_exe, 'emulate-controller', '--set',
                        'udp_controller_address=lab-pxi'], cwd=tmp_path)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines()[-1] == (
        "seft: error: parameter udp_controller_address='lab-pxi': expected host:port with a "
        'port 1-65535')
    proc = run_process([seft_exe, 'emulate-controller', '--runs', '0'], cwd=tmp_path)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines()[-1] == (
        'seft: error: --runs 0: expected a number of runs >= 1')
