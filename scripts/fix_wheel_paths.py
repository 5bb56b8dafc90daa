"""Rewrite the build machine's Python paths baked into the ROS 2 wheels' CMake files.

Some ros-jazzy-* wheels were built under /opt/python/cp311-cp311 and their exported CMake
targets name that interpreter's include and site-packages directories. CMake refuses a
target whose INTERFACE_INCLUDE_DIRECTORIES do not exist, so building any message package
(valve_msgs) fails until those paths point at this interpreter. Idempotent: a second run
finds nothing to rewrite.

Usage: python scripts/fix_wheel_paths.py PREFIX   (PREFIX = the venv, which is the ROS prefix)
"""
from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

BUILD_INCLUDE = '/opt/python/cp311-cp311/include/python3.11'
BUILD_SITE = '/opt/python/cp311-cp311/lib/python3.11/site-packages'


def main() -> int:
    prefix = Path(sys.argv[1] if len(sys.argv) > 1 else sys.prefix).resolve()
    include = sysconfig.get_paths()['include']
    site = str(prefix / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}'
               / 'site-packages')
    if not Path(include, 'Python.h').is_file():
        print(f'fix_wheel_paths: no Python.h in {include}; install the Python headers '
              '(Debian: python3-dev)', file=sys.stderr)
        return 1
    changed = 0
    for path in (prefix / 'share').rglob('*.cmake'):
        text = path.read_text(encoding='utf-8', errors='surrogateescape')
        if BUILD_INCLUDE not in text and BUILD_SITE not in text:
            continue
        text = text.replace(BUILD_INCLUDE, include).replace(BUILD_SITE, site)
        path.write_text(text, encoding='utf-8', errors='surrogateescape')
        changed += 1
    print(f'fix_wheel_paths: rewrote {changed} CMake file(s) to {include} and {site}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
