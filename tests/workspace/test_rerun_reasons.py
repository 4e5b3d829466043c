"""rerun_reasons: a test run again says in the summary why its first attempt failed (a pytest
session of its own, in a subprocess, with pytest-rerunfailures as the suite uses it)."""

from pathlib import Path
import subprocess
import sys

import rerun_reasons

TESTS = Path(rerun_reasons.__file__).resolve().parent

CONFTEST = """
import rerun_reasons


def pytest_runtest_logreport(report):
    rerun_reasons.record(report)


def pytest_terminal_summary(terminalreporter):
    rerun_reasons.summary(terminalreporter)
"""

FLAKY = """
from pathlib import Path

import pytest


@pytest.mark.flaky(reruns=1)
def test_once_late():
    mark = Path(__file__).with_name('tried')
    if not mark.exists():
        mark.write_text('1')
        assert 72.5 <= 70.0, 'the silent controller was noticed 72.5 ms after its last datagram'


@pytest.mark.flaky(reruns=1)
def test_twice_broken():
    raise RuntimeError('no datagram from the controller at 127.0.0.1:9 for 10 s')


def test_fine():
    pass
"""


def test_a_rerun_test_names_why_it_failed_first(tmp_path):
    (tmp_path / 'conftest.py').write_text(CONFTEST)
    (tmp_path / 'test_flaky.py').write_text(FLAKY)
    proc = subprocess.run(
        [sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', '-rfER',
         str(tmp_path)], cwd=tmp_path, capture_output=True, text=True,
        timeout=120, env={'PYTHONPATH': str(TESTS), 'PATH': '/usr/bin:/bin'})
    out = proc.stdout
    assert proc.returncode == 1, out + proc.stderr
    assert '1 failed, 2 passed' in out and '2 rerun' in out, out
    section = out.split('why the reruns failed first', 1)[1]
    assert ('test_flaky.py::test_once_late (call):\n'
            '    AssertionError: the silent controller was noticed 72.5 ms after its last '
            'datagram') in section, section
    assert ('test_flaky.py::test_twice_broken (call):\n'
            '    RuntimeError: no datagram from the controller at 127.0.0.1:9 for 10 s'
            ) in section, section
    assert 'test_fine' not in section


def _kept(message: str, *outcomes: str) -> list:
    """What :func:`rerun_reasons.record` keeps of reports of one test (``t.py::test_x``,
    setup) whose crash message is `message`, one report per outcome, in order."""
    from types import SimpleNamespace
    longrepr = SimpleNamespace(reprcrash=SimpleNamespace(message=message))
    before = len(rerun_reasons.REASONS)
    for outcome in outcomes:
        rerun_reasons.record(SimpleNamespace(outcome=outcome, nodeid='t.py::test_x',
                                             when='setup', longrepr=longrepr))
    kept = rerun_reasons.REASONS[before:]
    del rerun_reasons.REASONS[before:]
    return kept


def test_a_long_message_is_cut_to_its_first_lines():
    # a final failure ('failed') is not kept: pytest prints it itself
    kept = _kept('\n'.join(f'line {i}' for i in range(30)), 'rerun', 'failed')
    assert len(kept) == 1 and kept[0][:2] == ('t.py::test_x', 'setup')
    lines = kept[0][2].splitlines()
    assert lines[:2] == ['line 0', 'line 1'] and len(lines) == rerun_reasons.MAX_LINES + 1
    assert lines[-1] == f'... ({30 - rerun_reasons.MAX_LINES} more lines)'


def test_a_long_report_of_checks_keeps_what_failed():
    """A rig-check's output as the message: its PASS lines are left out first, so the FAIL
    line and the lines after it are kept."""
    (kept,) = _kept('\n'.join(['AssertionError: PASS contract: seft-rig/3.0']
                               + [f'  PASS check {i}: fine' for i in range(20)]
                               + ['  FAIL safe state: watchdog: 31 ms after the fault '
                                  '(limit 24 ms)', '  rig-check: 21 of 22 checks passed']),
                    'rerun')
    lines = kept[2].splitlines()
    assert lines[-3:] == ['  FAIL safe state: watchdog: 31 ms after the fault (limit 24 ms)',
                          '  rig-check: 21 of 22 checks passed', '... (11 PASS lines left out)']
    assert lines[0] == 'AssertionError: PASS contract: seft-rig/3.0'
    assert len(lines) == rerun_reasons.MAX_LINES + 1
