"""Demos of the package over ROS 2 (``scripts/demo``): :mod:`.impedance` (the main job: the
impedance of every mode against the paper's position drive, and what a friction calibration
recovers) and :mod:`.grasp` (three objects felt, measured and held); :mod:`.common` holds
what they share."""
__all__ = ["common", "impedance", "grasp"]
