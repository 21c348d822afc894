"""SIGTERM taken as Ctrl-C, and only the first stop signal acted on (``econdor_gcs.lifetime``):
the clean-up it starts is not cut short by another."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")


def _run(body: str) -> subprocess.CompletedProcess[str]:
    script = textwrap.dedent("""
        import os, signal, sys
        sys.path.insert(0, {root!r})
        from econdor_gcs.lifetime import Terminated, sigterm_as_interrupt
        me = os.getpid()

        def spin():  # a Python handler runs between bytecodes: give it some
            for _ in range(10_000):
                pass
    """).format(root=str(ROOT)) + textwrap.dedent(body)
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60)


def test_the_first_signal_raises_and_the_next_ones_are_ignored_until_the_scope_ends():
    r = _run("""
        with sigterm_as_interrupt():
            try:
                os.kill(me, signal.SIGTERM)
                spin()
                print("not stopped")
            except Terminated:
                os.kill(me, signal.SIGTERM)   # while the clean-up runs
                os.kill(me, signal.SIGINT)
                spin()
                print("cleaned up")
        print("handlers back:", signal.getsignal(signal.SIGTERM) == signal.SIG_DFL,
              signal.getsignal(signal.SIGINT) is signal.default_int_handler)
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["cleaned up", "handlers back: True True"]


def test_ctrl_c_first_raises_keyboard_interrupt():
    r = _run("""
        with sigterm_as_interrupt():
            try:
                os.kill(me, signal.SIGINT)
                spin()
            except Terminated:
                print("terminated")
            except KeyboardInterrupt:
                os.kill(me, signal.SIGTERM)
                spin()
                print("interrupted")
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["interrupted"]


def test_nested_scopes_ignore_the_next_signal_until_the_outermost_ends():
    r = _run("""
        with sigterm_as_interrupt():
            try:
                with sigterm_as_interrupt():
                    os.kill(me, signal.SIGTERM)
                    spin()
            except Terminated:
                os.kill(me, signal.SIGTERM)   # after the inner scope: still cleaning up
                spin()
                print("cleaned up")
        with sigterm_as_interrupt():          # a new scope acts on its first signal again
            try:
                os.kill(me, signal.SIGTERM)
                spin()
            except Terminated:
                print("stopped again")
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["cleaned up", "stopped again"]


def test_a_sigint_the_process_ignores_stays_ignored():
    r = _run("""
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        with sigterm_as_interrupt():
            os.kill(me, signal.SIGINT)
            spin()
            print("still here")
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["still here"]
