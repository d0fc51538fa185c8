#!/usr/bin/env python3
"""Repair the build-machine paths baked into the ROS 2 Jazzy PyPI wheels' CMake exports.

The ``ros-jazzy-*`` wheels ship ``share/*/cmake/*Export.cmake`` files whose imported targets
name ``/opt/python/cp311-cp311/include/python3.11`` and that machine's numpy include directory.
CMake refuses imported targets with non-existent include paths, so building any interface
package against the wheels fails. This rewrites those two paths to the running interpreter's
include directory and ``numpy.get_include()``. Running it again changes nothing.

Usage: python fix_cmake_paths.py PREFIX   (PREFIX = the virtual environment)
"""
import pathlib
import re
import sys
import sysconfig

import numpy

# Any manylinux build interpreter prefix, e.g. /opt/python/cp311-cp311.
_BUILD_PREFIX = r'/opt/python/cp3\d+-cp3\d+'
_PYTHON_INCLUDE = re.compile(_BUILD_PREFIX + r'/include/python3\.\d+')
_NUMPY_INCLUDE = re.compile(_BUILD_PREFIX + r'/lib/python3\.\d+/site-packages/numpy/(?:_core|core)/include')


def fix_prefix(prefix: pathlib.Path) -> int:
    """Rewrite every affected ``*.cmake`` file under ``prefix/share``; return how many changed."""
    python_include = sysconfig.get_paths()['include']
    numpy_include = numpy.get_include()
    for path, name in ((python_include, 'Python include'), (numpy_include, 'numpy include')):
        if not pathlib.Path(path).is_dir():
            raise SystemExit(f'fix_cmake_paths: the {name} directory {path} does not exist; '
                             'install the Python development headers (python3-dev).')
    changed = 0
    for cmake_file in (prefix / 'share').glob('*/cmake/*.cmake'):
        text = cmake_file.read_text()
        if '/opt/python/' not in text:
            continue
        fixed = _NUMPY_INCLUDE.sub(numpy_include, text)
        fixed = _PYTHON_INCLUDE.sub(python_include, fixed)
        if fixed != text:
            cmake_file.write_text(fixed)
            changed += 1
    return changed


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    prefix = pathlib.Path(sys.argv[1]).resolve()
    if not (prefix / 'share').is_dir():
        raise SystemExit(f'fix_cmake_paths: {prefix} has no share/ directory; is it the venv?')
    changed = fix_prefix(prefix)
    if changed:
        print(f'fix_cmake_paths: repaired {changed} CMake export file(s) under {prefix}/share')


if __name__ == '__main__':
    main()
