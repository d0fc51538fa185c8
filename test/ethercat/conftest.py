"""Fixtures of the EtherCAT emulator tests (defined in ethercat/fixtures.py)."""
from ethercat.fixtures import _shared_line, ecat_bus, ecat_emulator, soem_master  # noqa: F401
