"""The control core, the identification, the commissioning and the bag packages must import
without ROS (rclpy, message packages) or pysoem."""
import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent


@pytest.mark.parametrize('package', ['core', 'identification', 'bags', 'commissioning'])
def test_package_imports_without_ros(package):
    code = ('import sys\n'
            f'import seaforce_ros.{package} as pkg\n'
            'import pkgutil, importlib\n'
            f'for m in pkgutil.walk_packages(pkg.__path__, "seaforce_ros.{package}."):\n'
            '    importlib.import_module(m.name)\n'
            'bad = sorted(n for n in sys.modules if n.split(".")[0] in '
            '("rclpy", "pysoem", "seaforce_msgs", "std_msgs", "sensor_msgs", "diagnostic_msgs"))\n'
            'assert not bad, bad\n'
            f'print("ok", len([m for m in sys.modules if m.startswith("seaforce_ros.{package}")]))\n')
    # A clean interpreter where rclpy is not even importable: no ROS paths at all.
    env = {k: v for k, v in os.environ.items()
           if k not in ('PYTHONPATH', 'AMENT_PREFIX_PATH', 'LD_LIBRARY_PATH')}
    env['PYTHONPATH'] = str(ROOT)
    blocker = ('import sys\n'
               'class _Block:\n'
               '    def find_spec(self, name, path=None, target=None):\n'
               '        if name.split(".")[0] in ("rclpy", "pysoem", "seaforce_msgs", "rosidl_runtime_py"):\n'
               '            raise ImportError("blocked for this test: " + name)\n'
               'sys.meta_path.insert(0, _Block())\n')
    out = subprocess.run([sys.executable, '-c', blocker + code], env=env, cwd=str(ROOT),
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith('ok')
