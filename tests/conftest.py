"""Shared pytest set-up: every test process gets its own ROS domain, traffic stays local."""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import sys
import tempfile
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from node_harness import NodeStarter, RosHarness

REPO_ROOT = Path(__file__).resolve().parents[1]

# Each pytest process talks DDS on a domain of its own and only on this machine, so parallel
# runs and a user's running suite never see each other. The same Fast DDS profile as
# ros2_ws/env.bash (loopback only, no multicast; LOCALHOST would make rmw_fastrtps add a
# transport bound beyond loopback): docs/safety.md, "Network".
os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(REPO_ROOT / 'ros2_ws' / 'fastdds_localhost.xml')
os.environ['FASTDDS_DEFAULT_PROFILES_FILE'] = os.environ['FASTRTPS_DEFAULT_PROFILES_FILE']
os.environ['SKIP_DEFAULT_XML_FILE'] = '1'
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SYSTEM_DEFAULT'
_WORKER = os.environ.get('PYTEST_XDIST_WORKER')    # 'gw0', 'gw1', ... under xdist
_RUN_ID = os.environ.get('PYTEST_XDIST_TESTRUNUID', '')
#: Domains the tests may take: 1..100 keeps the DDS ports below Linux's ephemeral range;
#: 42 is env.bash's default, the domain of a suite a user started by hand.
TEST_DOMAINS = [d for d in range(1, 101) if d != 42]
_DOMAIN_LOCK_DIR = Path(tempfile.gettempdir()) / 'valve-ros-domains'


def _claim_domain(start: int) -> tuple[int, object]:
    """The first free domain from ``start`` on (cyclic), held by a lock for this process.

    Every pytest process of every run on the machine (xdist workers included) holds an
    exclusive flock on ``<tmp>/valve-ros-domains/<domain>.lock`` while it lives, so no two
    of them share a domain; the lock goes with the process, however it ends.
    """
    _DOMAIN_LOCK_DIR.mkdir(exist_ok=True)
    for k in range(len(TEST_DOMAINS)):
        domain = TEST_DOMAINS[(start + k) % len(TEST_DOMAINS)]
        handle = open(_DOMAIN_LOCK_DIR / f'{domain}.lock', 'a+')
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            continue
        return domain, handle
    raise RuntimeError(f'all {len(TEST_DOMAINS)} test ROS domains are in use on this machine')


_seed = (int(hashlib.sha256(_RUN_ID.encode()).hexdigest(), 16) + int(_WORKER.lstrip('gw'))
         if _WORKER and _RUN_ID else os.getpid())
_DOMAIN, _DOMAIN_LOCK = _claim_domain(_seed)
os.environ['ROS_DOMAIN_ID'] = str(_DOMAIN)

# The ROS-free cores are importable straight from the source tree, even without the
# colcon overlay (it is a symlink install, so both are the same files).
for pkg in ('valve_model_pkg', 'valve_driver_pkg', 'valve_bringup'):
    path = str(REPO_ROOT / pkg)
    if path not in sys.path:
        sys.path.insert(0, path)


@pytest.hookimpl(tryfirst=True)   # the work units before anything else reads the items
def pytest_collection_modifyitems(config, items):  # noqa: ANN001 - pytest hook
    """Under pytest-xdist, order the tests and write their work units (below)."""
    if _WORKER:
        _distribute(items)


# --- processes and rclpy, shared by tests/node, tests/robustness and tests/e2e ----------

@pytest.fixture
def start_node(tmp_path: Path) -> Iterator[NodeStarter]:
    """Start node processes on the test's ROS domain; all are stopped after the test.

    ``start_node(*argv, env=None, name=None)`` returns a ``node_harness.NodeProcess``.
    """
    starter = NodeStarter(tmp_path)
    yield starter
    starter.stop_all()


@pytest.fixture(scope='module')
def start_module_node(tmp_path_factory: pytest.TempPathFactory) -> Iterator[NodeStarter]:
    """Start node processes shared by a module's tests; all are stopped after the module."""
    starter = NodeStarter(tmp_path_factory.mktemp('nodes'))
    yield starter
    starter.stop_all()


@pytest.fixture
def ros() -> Iterator[RosHarness]:
    """rclpy initialised in the test process (on the test's own ROS_DOMAIN_ID)."""
    pytest.importorskip('rclpy')
    harness = RosHarness()
    yield harness
    harness.close()


@pytest.fixture(scope='module')
def ros_module() -> Iterator[RosHarness]:
    """rclpy for a module whose tests share their node processes (and their discovery)."""
    pytest.importorskip('rclpy')
    harness = RosHarness()
    yield harness
    harness.close()


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
