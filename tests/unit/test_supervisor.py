"""The process supervisor behind `make demo`: children start, stop cleanly, never orphan."""
from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from suite_waits import wait_until
from valve_bringup.supervisor import ChildExited, ProcessSpec, Supervisor

PY = sys.executable


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie is dead for our purpose.
    try:
        with open(f'/proc/{pid}/stat') as f:
            return f.read().split()[2] != 'Z'
    except FileNotFoundError:
        return False


def _pid_written(pidfile) -> int:  # noqa: ANN001 - a Path
    """The pid a child writes to ``pidfile``, once it is there."""
    wait_until(lambda: pidfile.exists() and pidfile.read_text().strip() != '', 20.0,
               f'a pid in {pidfile}')
    return int(pidfile.read_text())


def test_output_is_prefixed_and_children_stop_on_sigint() -> None:
    out = io.StringIO()
    with Supervisor(out=out, stop_timeout_s=3.0) as sup:
        proc = sup.start(ProcessSpec('talker', [PY, '-c', textwrap.dedent('''
            import time, sys
            try:
                print("hello from child", flush=True)
                time.sleep(60)
            except KeyboardInterrupt:
                print("got SIGINT", flush=True)
                sys.exit(0)
        ''')]))
        # the child's own line (its command line, which the supervisor echoes, has the text)
        wait_until(lambda: '] hello from child' in out.getvalue(), 20.0, 'the child\'s line')
        assert 'running' in sup.table()
    assert proc.returncode == 0
    text = out.getvalue()
    assert '[            talker] hello from child' in text
    assert 'got SIGINT' in text


def test_a_child_that_ignores_sigint_is_terminated() -> None:
    out = io.StringIO()
    sup = Supervisor(out=out, stop_timeout_s=0.5)
    proc = sup.start(ProcessSpec('stubborn', [PY, '-c',
                                              'import signal, time\n'
                                              'signal.signal(signal.SIGINT, signal.SIG_IGN)\n'
                                              'print("ignoring SIGINT", flush=True)\n'
                                              'time.sleep(60)']))
    wait_until(lambda: '] ignoring SIGINT' in out.getvalue(), 20.0,
               'the child to ignore SIGINT')
    codes = sup.stop()
    assert codes['stubborn'] == -signal.SIGTERM
    assert not _alive(proc.pid)
    assert sup.stop() == codes  # idempotent


def test_grandchildren_are_stopped_with_their_parent(tmp_path) -> None:
    pidfile = tmp_path / 'grandchild.pid'
    sup = Supervisor(out=io.StringIO(), stop_timeout_s=1.0)
    sup.start(ProcessSpec('parent', [PY, '-c', textwrap.dedent(f'''
        import subprocess, sys, time
        p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
        open({str(pidfile)!r}, "w").write(str(p.pid))
        time.sleep(60)
    ''')]))
    grandchild = _pid_written(pidfile)
    assert _alive(grandchild)
    sup.stop()
    wait_until(lambda: not _alive(grandchild), 10.0, 'the grandchild to end')


def test_children_die_when_the_supervisor_is_killed(tmp_path) -> None:
    """Even a SIGKILLed demo leaves no orphan (PR_SET_PDEATHSIG)."""
    pidfile = tmp_path / 'child.pid'
    script = textwrap.dedent(f'''
        import sys, time
        sys.path[:0] = {sys.path!r}
        from valve_bringup.supervisor import ProcessSpec, Supervisor
        sup = Supervisor()
        p = sup.start(ProcessSpec("sleeper",
                                  [sys.executable, "-c", "import time; time.sleep(60)"]))
        open({str(pidfile)!r}, "w").write(str(p.pid))
        time.sleep(60)
    ''')
    parent = subprocess.Popen([PY, '-c', script], stdout=subprocess.DEVNULL)
    child = _pid_written(pidfile)
    assert _alive(child)
    parent.kill()
    parent.wait()
    wait_until(lambda: not _alive(child), 10.0, 'the child of the killed supervisor to end')


def test_check_alive_reports_a_crashed_child() -> None:
    sup = Supervisor(out=io.StringIO())
    proc = sup.start(ProcessSpec('crasher', [PY, '-c', 'raise SystemExit(3)']))
    proc.wait(timeout=20)
    with pytest.raises(ChildExited, match='crasher .* exited with code 3'):
        sup.check_alive()
    sup.stop()
