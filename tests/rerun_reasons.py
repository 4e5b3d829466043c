"""Why a test that was run again failed its first time (pytest-rerunfailures reports that
attempt as ``rerun`` and prints no traceback for it: the CI logs of 2026-11-29/30 named
``test_a_run_with_no_controller_at_its_address_is_refused_naming_it`` as rerun twice and
said nothing of why). :func:`record` keeps the failure's message from each such report and
:func:`summary` writes them in the session's summary; ``tests/conftest.py`` wires them as its
``pytest_runtest_logreport`` and ``pytest_terminal_summary`` hooks."""

#: At most this many lines of a first failure's message are kept.
MAX_LINES = 12

#: ``(test id, phase, message)`` of every first failure that was run again.
REASONS: list[tuple[str, str, str]] = []


def record(report) -> None:
    """Keep why `report` (a ``TestReport``) failed, if it is a first attempt that is run
    again (outcome ``rerun``): its crash message (the assertion or the exception's line), or
    the end of its text where there is none."""
    if report.outcome != 'rerun':
        return
    crash = getattr(report.longrepr, 'reprcrash', None)
    text = crash.message if crash is not None else str(report.longrepr or '').strip()
    lines = text.splitlines() or ['(no message)']
    if crash is None:
        lines = lines[-MAX_LINES:]
    elif len(lines) > MAX_LINES:
        # a report of checks (seft rig-check's): its passing lines go first, so that what
        # failed is kept (a CI log of 2026-11-30 showed 12 PASS lines of 22 and no FAIL)
        passing = [i for i, line in enumerate(lines) if line.lstrip().startswith('PASS ')]
        drop = set(passing[:len(lines) - MAX_LINES])
        lines = [line for i, line in enumerate(lines) if i not in drop]
        if len(lines) > MAX_LINES:
            lines = lines[:MAX_LINES] + [f'... ({len(lines) - MAX_LINES} more lines)']
        if drop:
            lines.append(f'... ({len(drop)} PASS lines left out)')
    REASONS.append((report.nodeid, report.when, '\n'.join(lines)))


def summary(terminalreporter) -> None:
    """A section ``why the reruns failed first`` with each kept message under its test."""
    if not REASONS:
        return
    terminalreporter.section('why the reruns failed first')
    for nodeid, when, text in REASONS:
        terminalreporter.write_line(f'{nodeid} ({when}):')
        for line in text.splitlines():
            terminalreporter.write_line(f'    {line}')
