"""Fleet identification: many valves from a manifest, in parallel, into one table.

ROS-free. :func:`read_manifest` checks the manifest, :func:`run_fleet` runs the valves on a
local process pool or a Dask cluster (resuming an interrupted run) and writes
``fleet.csv``/``fleet.parquet``; :func:`flag_outliers` is the fleet's outlier rule.
``valve_identify_batch`` (:mod:`valve_model_pkg.cli.identify_batch`) is the command line;
docs/fleet.md the user's guide.
"""
from .manifest import ManifestError, ValveJob, read_manifest
from .outliers import MIN_VALVES, THRESHOLD, OutlierVerdict, flag_outliers, robust_z
from .runner import FleetResult, SchedulerError, default_workers, run_fleet
from .store import FleetStore, StoreBusyError

__all__ = ['ManifestError', 'ValveJob', 'read_manifest', 'MIN_VALVES', 'THRESHOLD',
           'OutlierVerdict', 'flag_outliers', 'robust_z', 'FleetResult', 'SchedulerError',
           'default_workers',
           'run_fleet', 'FleetStore', 'StoreBusyError']
