"""Commissioning a gripper without ROS: what a lab with motor encoders, hose pressure and motor
torque (no endpoint encoder, no external force) measures of its own gripper, and the settings
it gets from that.

Modules (each lists its own public names in ``__all__``): :mod:`.errors` (one root,
:class:`~.errors.CommissioningError`), :mod:`.record` (one free-air excitation of one channel,
as the controller saw it), :mod:`.loop_figures` (from such a record or a bag: the pressure
sensor's noise, the motor encoder's resolution, the control loop's delay and its misses),
:mod:`.report` (the report a run ends with: its data model, one directory with
``report.json``, the figures and a self-contained ``report.html``, and the plain-text
summary).

The package imports none of its modules: a caller loads only what it needs.
"""
__all__ = ["errors", "record", "loop_figures", "report"]
