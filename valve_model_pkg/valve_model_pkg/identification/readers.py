"""Which reader for which path: CSV records, bag directories, bag files.

:func:`read_measurements` is the one entry for a list of paths as a user gives them
(``valve_identify --fit A B C``): a directory or a storage file (``.mcap``, ``.db3``, also
``.zstd``-compressed) is a rosbag2 bag (:func:`~.bag_reader.read_bag`), anything else a CSV
record of the measured-data format (:func:`~.csv_reader.read_csv`). Each record's current
quantisation step is set (:func:`~.measurement.with_current_lsb`).
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

from valve_model_pkg.interface import TOPIC_STATE

from .bag_reader import read_bag
from .csv_reader import read_csv
from .measurement import Measurement, with_current_lsb
from .topic_map import FieldSpecOrValue

__all__ = ['BAG_FILE_SUFFIXES', 'read_measurements']

#: Names of rosbag2 storage files (with rosbag2's file compression).
BAG_FILE_SUFFIXES = ('.mcap', '.db3', '.mcap.zstd', '.db3.zstd')


def read_measurements(paths: Iterable[str | Path], *, topic: str = '/' + TOPIC_STATE,
                      valve: str | None = None,
                      mapping: Mapping[str, FieldSpecOrValue] | None = None
                      ) -> list[Measurement]:
    """Read CSV files and bags (chosen by what each path is).

    Parameters
    ----------
    paths : iterable of str or pathlib.Path
        CSV files, bag directories, or storage files of a bag.
    topic, valve, mapping
        Passed to :func:`~.bag_reader.read_bag` for bags: the suite's valve state topic
        and valve, or a user's own topics by role.

    Returns
    -------
    list of Measurement
        In the order given, with ``current_lsb_a`` set.

    Raises
    ------
    MeasurementFormatError
        A file that cannot be read or is malformed (one line naming it).
    """
    out = []
    for p in paths:
        path = Path(p)
        if path.name.endswith(BAG_FILE_SUFFIXES) and (path.parent / 'metadata.yaml').is_file():
            path = path.parent  # a file of a complete bag: the whole bag, named by its dir
        if path.is_dir() or path.name.endswith(BAG_FILE_SUFFIXES):
            m = read_bag(path, topic=topic, valve=valve, mapping=mapping)
        else:
            m = read_csv(path)
        out.append(with_current_lsb(m))
    return out
