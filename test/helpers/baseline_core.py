"""The control core of another git revision, importable beside the working tree's.

Used by bench/core_sim_speed.py (``--baseline``: before/after rows in one run) and by
test/core/test_per_sample_exact.py (the same floats as before a speed-up).
"""

import importlib.util
import io
import subprocess
import sys
import tarfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


class BaselineUnavailable(Exception):
    """The revision cannot be exported (no git, a shallow clone) or imported."""


def load_core(rev, directory):
    """The ``seaforce_ros.core`` of git revision ``rev``, exported into ``directory`` (which
    must outlive its use) and imported as the package ``_baseline_core_<rev>`` (it imports
    itself relatively only)."""
    try:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "seaforce_ros/core"],
                                 capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as err:
        detail = getattr(err, "stderr", b"") or b""
        raise BaselineUnavailable(f"{rev}: git archive failed: "
                                  f"{detail.decode(errors='replace').strip() or err}") from err
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        # (extraction filters came with Python 3.11.4; git archive's members are plain files)
        if hasattr(tarfile, "data_filter"):
            tar.extractall(directory, filter="data")
        else:
            tar.extractall(directory)
    core = Path(directory) / "seaforce_ros" / "core"
    for path in core.glob("*.py"):
        if "from seaforce_ros" in path.read_text() or "import seaforce_ros" in path.read_text():
            raise BaselineUnavailable(f"{rev}: {path.name} imports seaforce_ros by name; its "
                                      "core cannot be loaded beside the working tree's")
    name = "_baseline_core_" + "".join(c if c.isalnum() else "_" for c in rev)
    spec = importlib.util.spec_from_file_location(name, core / "__init__.py",
                                                  submodule_search_locations=[str(core)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
