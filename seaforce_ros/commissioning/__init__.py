"""Commissioning a gripper without ROS: what a lab with motor encoders, hose pressure and motor
torque (no endpoint encoder, no external force) measures of its own gripper, and the settings
it gets from that.

Modules (each lists its own public names in ``__all__``): :mod:`.errors` (one root,
:class:`~.errors.CommissioningError`), :mod:`.record` (one free-air excitation of one channel,
as the controller saw it; saved and loaded as ``.npz``), :mod:`.excitation` (the free-air
excitation job: :class:`~.excitation.FreeAirExcitation`, a motor-torque log chirp with online
amplitude adaptation and a model-free contact test), :mod:`.experiments` (that job in closed
loop on the core simulator: :func:`~.experiments.run_free_air_excitation`), :mod:`.free_air`
(:func:`~.free_air.identify_free_air`: the eight Table I parameters and the Dahl hysteresis,
each with its 1-sigma or why not, from one free-air excitation), :mod:`.loop_figures` (from
such a record or a bag: the pressure sensor's noise, the motor encoder's resolution, the
control loop's delay and its misses), :mod:`.predictor` (what each controller mode renders --
|Z| per mode from the sampled closed loop with the loop delay and the Dahl describing function,
its 1-sigma band and the Z-width, the DOB's torque noise, the hold's delay limit, impedance
mode's virtual-wall chart), :mod:`.tuning` (the DOB's lambda and nominal plant and the hold
gains that widen the predicted Z-width under eq. 28 with a margin, a torque-noise budget and
the loop delay), :mod:`.report` (the report a run ends with: its data model, one directory with
``report.json``, the figures and a self-contained ``report.html``, and the plain-text summary),
:mod:`.worker` (the analysis in a child process the node can cancel, with progress lines),
:mod:`.analyse` (one run's analysis from its record: identification, loop figures, tuning,
prediction, report, params and rollback files; run as ``python -m
seaforce_ros.commissioning.analyse RUN_DIR``).

The package imports none of its modules: a caller loads only what it needs.
"""
__all__ = ["errors", "record", "excitation", "experiments", "free_air", "loop_figures", "predictor", "tuning", "report", "worker", "analyse"]
