"""The ROS-free packages (core, bags, identification, commissioning, ethercat) are annotated and
type-check.

mypy runs with the configuration in setup.cfg (``[mypy]``: every function annotated, every
body checked, no module excepted). Its cache is the default
``.mypy_cache`` of the repository (ignored by git): a first run checks everything (5 s of CPU;
9-14 s wall on a loaded 2-core host), a later one only what changed (under 1 s).
"""
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent


def test_mypy_clean():
    result = subprocess.run(
        [sys.executable, '-m', 'mypy', '--config-file', str(ROOT / 'setup.cfg')],
        cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert result.returncode == 0, ('mypy found type errors:\n' + result.stdout
                                    + result.stderr)
