"""How test sessions and `seft run` choose their ROS domain (`seft_msgs_py.domain`)."""

import subprocess
import sys
import textwrap

from conftest import DOMAIN_ID, DOMAIN_RANGE, claim_domain
import pytest


def test_the_session_holds_a_domain_outside_seft_runs_random_range():
    assert DOMAIN_ID in DOMAIN_RANGE
    assert not set(DOMAIN_RANGE) & set(range(100, 200)) and max(DOMAIN_RANGE) <= 232


def test_concurrent_claims_never_share_a_domain_and_end_with_their_owner(tmp_path):
    held = [claim_domain(range(5, 8), tmp_path, start=1) for _ in range(3)]
    assert [d for d, _ in held] == [6, 7, 5]       # from the start, wrapping round
    with pytest.raises(RuntimeError, match=r'^no free ROS domain in 5-7: every one is '
                                           r'claimed \(lock files in '):
        claim_domain(range(5, 8), tmp_path)
    held[0][1].close()                               # the owner of 6 ends ...
    again = claim_domain(range(5, 8), tmp_path, start=0)
    assert again[0] == 6                             # ... and 6 is free again
    # another process sees the claims, and its own claim dies with it (even on SIGKILL)
    code = textwrap.dedent(f"""
        import os, signal, sys
        sys.path.insert(0, {str(__import__('conftest').__file__.rsplit('/', 1)[0])!r})
        from pathlib import Path
        from conftest import claim_domain
        d, f = claim_domain(range(5, 9), Path({str(tmp_path)!r}), start=0)
        print(d, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=60)
    assert out.stdout.split() == ['8']
    assert claim_domain(range(5, 9), tmp_path, start=3)[0] == 8
    assert len(held) == 3 and again[1].closed is False


def test_seft_run_refuses_a_domain_another_process_claimed(seft_exe, run_process, tmp_path):
    """`seft run` follows the same rule: a domain another (unrelated) process holds is
    refused before any node starts, in one line; the test session's own domain is its
    children's to use (held by an ancestor)."""
    holder = subprocess.Popen(
        [sys.executable, '-c', textwrap.dedent("""
            import sys, time
            from seft_msgs_py.domain import claim_domain
            d, f = claim_domain(range(200, 233))
            print(d, flush=True)
            time.sleep(60)
        """)], stdout=subprocess.PIPE, text=True)
    try:
        held = int(holder.stdout.readline())
        proc = run_process([seft_exe, 'run', '--duration', '0.2', '--domain-id', str(held),
                            '--out', tmp_path / 'out'], cwd=tmp_path)
    finally:
        holder.kill()
        holder.wait()
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        f'seft: error: ROS_DOMAIN_ID={held} is claimed by another seft process on this '
        f'machine (lock /tmp/seft-ros-domains/{held}.lock): choose another --domain-id')
    assert not any((tmp_path / 'out').rglob('bag'))


def test_a_child_uses_its_ancestors_claim():
    from seft_msgs_py.domain import held_by_ancestor
    code = ('from seft_msgs_py.domain import held_by_ancestor; '
            f'print(held_by_ancestor({DOMAIN_ID}))')
    child = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                           timeout=60)
    assert child.stdout.strip() == 'True', child.stderr
    assert not held_by_ancestor(DOMAIN_ID)      # this process holds it: not an ancestor
