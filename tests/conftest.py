"""Shared pytest set-up: every test process gets its own ROS domain, traffic stays local."""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import sys
import tempfile
import uuid
from contextlib import contextmanager
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]

# Each pytest process talks DDS on a domain of its own and only on this machine, so parallel
# runs and a user's running suite never see each other: derived from the pid, or under
# pytest-xdist (`make test` runs 2 workers) from the run's id plus the worker's number, so
# the workers of one run never share a domain (a test keeps its worker's domain).
# The same Fast DDS profile as ros2_ws/env.bash (loopback only, no multicast; LOCALHOST
# would make rmw_fastrtps add a transport bound beyond loopback): docs/safety.md, "Network".
os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(REPO_ROOT / 'ros2_ws' / 'fastdds_localhost.xml')
os.environ['FASTDDS_DEFAULT_PROFILES_FILE'] = os.environ['FASTRTPS_DEFAULT_PROFILES_FILE']
os.environ['SKIP_DEFAULT_XML_FILE'] = '1'
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SYSTEM_DEFAULT'
# Domains 0..101 keep the DDS ports below Linux's ephemeral range.
_WORKER = os.environ.get('PYTEST_XDIST_WORKER')    # 'gw0', 'gw1', ... under xdist
_RUN_ID = os.environ.get('PYTEST_XDIST_TESTRUNUID', '')
if _WORKER and _RUN_ID:
    _base = int(hashlib.sha256(_RUN_ID.encode()).hexdigest(), 16)
    os.environ['ROS_DOMAIN_ID'] = str(1 + (_base + int(_WORKER.lstrip('gw'))) % 100)
else:
    os.environ['ROS_DOMAIN_ID'] = str(1 + os.getpid() % 100)

# The ROS-free cores are importable straight from the source tree, even without the
# colcon overlay (it is a symlink install, so both are the same files).
for pkg in ('valve_model_pkg', 'valve_driver_pkg', 'valve_bringup'):
    path = str(REPO_ROOT / pkg)
    if path not in sys.path:
        sys.path.insert(0, path)


@pytest.hookimpl(tryfirst=True)   # the work units before anything else reads the items
def pytest_collection_modifyitems(config, items):  # noqa: ANN001 - pytest hook
    """Node and end-to-end tests may run once more after a failure (pytest-rerunfailures).

    They start real processes on a shared 2-core machine; a few of them still judge rates
    and windows of wall time (a known limit, see the README's notes), so a loaded machine
    can fail a run that a second run passes. A real fault fails every run. Unit tests are
    not rerun.
    """
    for item in items:
        if item.get_closest_marker('node') or item.get_closest_marker('e2e'):
            item.add_marker(pytest.mark.flaky(reruns=1, reruns_delay=2))
    if _WORKER:
        _distribute(items)


# --- pytest-xdist (`make test`: -n 2 --dist loadgroup --no-loadscope-reorder) -----------
# Work units: a test marked slow, e2e, spread or serial is a unit of its own (they are the
# long ones, worth spreading over the workers); the other tests of a file stay together
# (a module-scoped fixture is built once, not once per worker and again after every switch
# of module); an xdist_group mark puts its tests in one unit. Order: serial tests first
# (they run one at a time while nothing else runs, best before any long test has started),
# then the long units (the longest first keeps both workers busy to the end), then the
# files. xdist 3.8 groups by a suffix it appends to item._nodeid, which pytest 9 no longer
# reads, so the workers write the units to a file and the scheduler below reads it.

def _own_unit(item) -> bool:  # noqa: ANN001 - pytest item
    return any(item.get_closest_marker(m) for m in ('slow', 'e2e', 'spread', 'serial'))


def _unit(item) -> str:  # noqa: ANN001 - pytest item
    groups = sorted({str(m.args[0] if m.args else m.kwargs.get('name', 'default'))
                     for m in item.iter_markers('xdist_group')})
    if groups:
        return '@' + '_'.join(groups)
    return item.nodeid if _own_unit(item) else item.nodeid.split('::', 1)[0]


def _distribute(items: list) -> None:
    def rank(item) -> int:  # noqa: ANN001 - pytest item
        if item.get_closest_marker('serial'):
            return 0
        return 1 if _own_unit(item) or item.get_closest_marker('xdist_group') else 2
    items.sort(key=rank)    # stable: the files' own order is kept within each rank
    units = {item.nodeid: _unit(item) for item in items}
    _LOCK_DIR.mkdir(exist_ok=True)
    tmp = _LOCK_DIR / f'units.{_WORKER}.json'
    tmp.write_text(json.dumps(units))
    tmp.replace(_LOCK_DIR / 'units.json')   # every worker writes the same content


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):  # noqa: ANN001, ANN201 - xdist hook
    """With ``--dist loadgroup``: xdist's scope scheduling over the units of _distribute."""
    if config.getvalue('dist') != 'loadgroup':
        return None
    from xdist.scheduler import LoadScopeScheduling
    lock_dir = _lock_dir(config.option.testrunuid)

    class UnitScheduling(LoadScopeScheduling):
        units: dict[str, str] | None = None

        def _split_scope(self, nodeid: str) -> str:
            if self.units is None:   # first called once every worker has collected
                self.units = json.loads((lock_dir / 'units.json').read_text())
            return self.units.get(nodeid, nodeid)

        def _reschedule(self, node) -> None:  # noqa: ANN001 - xdist's WorkerController
            # xdist tops a worker up while it has 2 tests pending; a long test then holds
            # units back that the other worker could run. A worker needs only the test it
            # runs and the next one (pytest's teardown looks at the next item).
            if node.shutting_down:
                return
            if not self.workqueue:
                node.shutdown()
                return
            if self._pending_of(self.assigned_work[node]) <= 1:
                self._assign_work_unit(node)
    return UnitScheduling(config, log)


def pytest_configure(config):  # noqa: ANN001, ANN201 - pytest hook
    """The controller of an xdist run fixes the run's id (its workers get it) up front."""
    if getattr(config.option, 'numprocesses', None) and not hasattr(config, 'workerinput') \
            and getattr(config.option, 'testrunuid', None) is None:
        config.option.testrunuid = uuid.uuid4().hex


def _lock_dir(run_id: str) -> Path:
    return Path(tempfile.gettempdir()) / f'valve-pytest-{run_id}'


_LOCK_DIR = _lock_dir(_RUN_ID or str(os.getpid()))
_locks: dict[str, object] = {}


def _lock(name: str):  # noqa: ANN202 - an open file
    if name not in _locks:
        _LOCK_DIR.mkdir(exist_ok=True)
        _locks[name] = open(_LOCK_DIR / name, 'a+')
    return _locks[name]


@contextmanager
def _running(serial: bool):
    """A readers-writer lock over the workers of one run (flock, writer first).

    A serial test takes the gate, then the run lock exclusively: it waits for the test the
    other worker is running and no other test starts until it ends. Any other test takes
    the run lock shared, passing the gate (so a waiting serial test is not starved).
    """
    gate, run = _lock('gate'), _lock('run')
    if serial:
        fcntl.flock(gate, fcntl.LOCK_EX)
        fcntl.flock(run, fcntl.LOCK_EX)
    else:
        fcntl.flock(gate, fcntl.LOCK_SH)
        fcntl.flock(run, fcntl.LOCK_SH)
        fcntl.flock(gate, fcntl.LOCK_UN)
    try:
        yield
    finally:
        fcntl.flock(run, fcntl.LOCK_UN)
        if serial:
            fcntl.flock(gate, fcntl.LOCK_UN)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):  # noqa: ANN001, ANN201 - pytest hook
    """Tests marked ``serial`` run alone: nothing else runs on the other xdist workers.

    They start CPU hogs on purpose or judge a rate in wall time (a node at 1 kHz, a
    throughput) that a CPU-bound test beside them would starve. Setup and teardown of the
    test's fixtures are inside the lock. Without xdist this does nothing.
    """
    if not _WORKER:
        return (yield)
    with _running(bool(item.get_closest_marker('serial'))):
        return (yield)


def pytest_sessionfinish(session, exitstatus):  # noqa: ANN001, ANN201 - pytest hook
    """The controller of an xdist run removes the run's lock folder (workers are done)."""
    config = session.config
    run_id = getattr(config.option, 'testrunuid', None)
    if run_id and not hasattr(config, 'workerinput'):
        import shutil
        shutil.rmtree(_lock_dir(run_id), ignore_errors=True)
