"""Offline system identification and Z-width, without ROS: the paper's Table I plant and the
Dahl hysteresis from recorded chirps and work loops, the endpoint impedance per mode.

Modules (each lists its own public names in ``__all__``): :mod:`.timeseries` (a record on its
cycle grid), :mod:`.spectral` (Blackman-Tukey frequency responses with 1-sigma),
:mod:`.fit` (Fig. 4's plant fits, the Dahl force removed), :mod:`.plant_id`
(:func:`~.plant_id.identify_plant`, the whole chirp pipeline), :mod:`.dahl_model` and
:mod:`.dahl_fit` (eq. 14 along a path, the work-loop fit), :mod:`.zwidth_lib` (impedance per
mode from a bag or simulated, Z-width rows), :mod:`.experiments` (chirp and work-loop runs on
the core simulator), :mod:`.params_file` and :mod:`.output` (params files, tables, the
command lines' error handling), :mod:`.plots` and :mod:`.errors` (one root,
:class:`~.errors.IdentificationError`).

The package imports none of its modules: ``identify`` and ``zwidth`` load only what a run
needs (scipy.signal alone takes about 0.4 s), so their usage errors answer at once.
"""
__all__ = ["timeseries", "spectral", "fit", "plant_id", "dahl_model", "dahl_fit", "zwidth_lib",
           "experiments", "params_file", "output", "plots", "errors"]
