"""Commissioning a gripper without ROS: what a lab with motor encoders, hose pressure and motor
torque (no endpoint encoder, no external force) measures of its own gripper, and the settings
it gets from that.

Modules (each lists its own public names in ``__all__``): :mod:`.errors` (one root,
:class:`~.errors.CommissioningError`), :mod:`.record` (one free-air excitation of one channel,
as the controller saw it), :mod:`.excitation` (the free-air excitation job:
:class:`~.excitation.FreeAirExcitation`, a motor-torque log chirp with online amplitude
adaptation and a model-free contact test), :mod:`.experiments` (that job in closed loop on
the core simulator: :func:`~.experiments.run_free_air_excitation`).

The package imports none of its modules: a caller loads only what it needs.
"""
__all__ = ["errors", "record", "excitation", "experiments"]
