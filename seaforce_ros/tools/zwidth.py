"""zwidth: endpoint impedance Z = F_e/V_e per controller mode and the Z-width (Fig. 5C).

From backdrive bags (one mode and drive frequency per bag; the mode is read from the bag's
``controller_status`` or given as ``MODE=BAG``)::

    zwidth hold=bags/hold_1rad dob_full_ff=bags/ff_1rad --channel pinch [--plot z.png]

Or by running the backdrive experiment offline on the core simulator (true plant = Table I
with Dahl hysteresis unless ``--true-params``; the controller uses ``--params``, e.g. the
output of ``identify``; ``--reference-params`` repeats it with a second controller parameter
set and compares the Z-widths)::

    zwidth --simulate --channel pinch --params PARAMS.yaml --reference-params TRUE.yaml

Tables: |Z| [dB re 1 N m s/rad] per mode at the DC limit (0.1 rad/s), 1, 3 and 10 rad/s and
the Z-width = |Z_hold| / |Z_min| in dB, Z_min the lowest-impedance mode at that frequency:
once on the fundamental |F_e/V_e|, once on the rms impedance rms(F_e)/rms(V_e); then the
harmonic distortion of F_e and the work loop's peak |F_e| over the stroke against the peak
within +-0.2 rad (:func:`seaforce_ros.core.analysis.impedance_figures`). On a nonlinear
gripper the fundamental can nearly cancel while the harmonics stay: judge a low impedance on
the rms. Each bag also gives the finger's four-bar ratio r(q) over the stroke it drove, from
the finger's encoder against the motor position and the pressure force
(:mod:`seaforce_ros.identification.finger_ratio`; a soft mode's bag shows it, a stiff one's
says why not), which no free-air record shows. Exit status 0 ok, 2 bad input (one line on
stderr).
"""

from __future__ import annotations

import argparse
import collections
import math
import os
import sys

import numpy as np

__all__ = ["main", "build_parser"]


def build_parser():
    from ..identification.output import positive_float
    p = argparse.ArgumentParser(prog="zwidth", description="Endpoint impedance per mode and "
                                "Z-width (minimum-impedance mode vs hold).")
    p.add_argument("bags", nargs="*", help="backdrive bags, BAG or MODE=BAG")
    p.add_argument("--channel", help="channel to read from the bags or the params files "
                   "(required with either; with --simulate and no params file the simulated "
                   "gripper is Table I's and it is not needed)")
    p.add_argument("--simulate", action="store_true", help="run the backdrive experiment "
                   "offline instead of reading bags")
    p.add_argument("--params", help="controller parameters (plant, dahl) for --simulate")
    p.add_argument("--reference-params", help="second controller parameter set to compare "
                   "with (e.g. the true values)")
    p.add_argument("--true-params", help="parameters of the simulated gripper (default "
                   "Table I, Dahl sigma 12.8 N m/rad, F_c 0.032 N m)")
    p.add_argument("--modes", default=None,
                   help="modes for --simulate (comma separated; hold is always added; "
                        "default: the passive (motor off) mode, hold, dob, dob_linear_ff, "
                        "dob_full_ff)")
    p.add_argument("--frequencies", default="dc,1,3,10",
                   help="drive frequencies [rad/s] for --simulate; dc = 0.1 rad/s")
    p.add_argument("--amplitude", type=positive_float, default=0.2,
                   help="drive amplitude [rad] for --simulate (default 0.2)")
    p.add_argument("--topic", default="actuator_state")
    p.add_argument("--plot", help="PNG file for the Fig. 5C-style plot")
    p.add_argument("--quiet", action="store_true")
    return p


#: drive frequencies --simulate accepts [rad/s]: below, one period takes hours of simulated
#: time; above, fewer than 10 samples of the simulation's 2 kHz per period
MIN_OMEGA, MAX_OMEGA = 0.01, 1000.0


def _frequencies(text):
    from ..identification.errors import UsageError
    from ..identification.zwidth_lib import DC_OMEGA
    out = []
    for item in text.split(","):
        item = item.strip().lower()
        try:
            w = DC_OMEGA if item == "dc" else float(item)
        except ValueError:
            raise UsageError(f"--frequencies: bad frequency {item!r} (numbers in rad/s, or dc)") \
                from None
        if not MIN_OMEGA <= w <= MAX_OMEGA:
            raise UsageError(f"--frequencies: {item} is outside {MIN_OMEGA:g}-{MAX_OMEGA:g} "
                             "rad/s")
        out.append(w)
    return out


def _check_mode(mode, what):
    """``mode`` if it is a controller mode (core.params.MODES), else a UsageError."""
    from ..core.params import MODES
    from ..identification.errors import UsageError
    if mode not in MODES:
        raise UsageError(f"{what}: unknown mode {mode!r}; the modes are {', '.join(MODES)}")
    return mode


def _modes(text):
    """The --modes list: known modes, hold first if not given, no repeats, at least one mode
    besides hold (the Z-width compares the lowest-impedance mode with hold)."""
    from ..identification.errors import UsageError
    from ..identification.zwidth_lib import DEFAULT_MODES
    items = DEFAULT_MODES if text is None else [m.strip() for m in text.split(",")
                                                if m.strip()]
    modes = list(dict.fromkeys(_check_mode(m, "--modes") for m in items))
    if "hold" not in modes:
        modes.insert(0, "hold")
    if len(modes) < 2:
        raise UsageError("--modes: give at least one mode besides hold (the Z-width compares "
                         "the lowest-impedance mode with hold)")
    return modes


def _bag_item(item):
    """``(mode or '', path)`` of a positional BAG or MODE=BAG."""
    if "=" not in item or os.path.exists(item):
        return "", item
    mode, _, path = item.partition("=")
    if not path or not mode:
        from ..identification.errors import UsageError
        raise UsageError(f"{item}: no {'bag after' if mode else 'mode before'} '=' (give BAG "
                         "or MODE=BAG)")
    return _check_mode(mode, f"{item}"), path


def _mode_in_bag(path, channel):
    """Most common ``mode`` of ``channel`` in the bag's controller_status (None if absent)."""
    from ..bags import Bag, typestore
    status = "seaforce_msgs/msg/ControllerStatus"
    store = typestore()
    counts = collections.Counter()
    for i, (_t, _m, _ts, data) in enumerate(Bag(path).messages(
            lambda _topic, msgtype: msgtype == status)):
        msg = store.deserialize_cdr(data, status)
        names = list(msg.name)
        if channel in names:
            counts[msg.mode[names.index(channel)]] += 1
        if i > 200:
            break
    return counts.most_common(1)[0][0] if counts else None


def _from_bags(args, progress):
    from ..bags import read_channel
    from ..identification.errors import IdentificationError
    from ..identification.finger_ratio import fit_finger_ratio
    from ..identification.timeseries import prepare
    from ..identification.zwidth_lib import figure_lines, figures_from_record

    points = collections.defaultdict(list)     # mode -> [ImpedanceFigures]
    for mode, path in [_bag_item(item) for item in args.bags]:
        progress(f"reading {path}", None)
        record = read_channel(path, args.channel, args.topic)
        for note in record.notes:
            print(f"note ({path}): {note}")
        series = prepare(record, ("x_e", "f_e"))
        if not mode:
            mode = _mode_in_bag(path, args.channel)
            if mode is None:
                raise IdentificationError(f"{path}: no controller_status in the bag to tell "
                                          "the mode; give it as MODE=BAG")
        fig = figures_from_record(series)
        for note in series.notes():
            print(f"note ({path}): {note}")
        print(figure_lines(f"{path}: mode {mode}, drive {fig.omega:.4g} rad/s", fig))
        # (prepared on its own: the impedance does not need x and f_p, and a bag with gaps in
        # them still gives it)
        try:
            kinematic = prepare(record, ("x_e", "x", "f_p"))
        except IdentificationError as exc:
            print(f"  finger ratio: not fitted ({exc})")
        else:
            k = kinematic.signals
            print(f"  {fit_finger_ratio(k['x_e'], k['x'], k['f_p'], kinematic.dt).line()}")
        points[mode].append(fig)
    # common frequency grid (drive frequencies rounded to 3 significant digits)
    omegas = sorted({float(f"{f.omega:.3g}") for figs in points.values() for f in figs})
    by_mode = {}
    for mode, figs in points.items():
        row = [None] * len(omegas)
        for f in figs:
            row[omegas.index(float(f"{f.omega:.3g}"))] = f
        by_mode[mode] = row
    return omegas, by_mode


def _arrays(figures):
    """(mode -> complex Z, mode -> rms |Z|) arrays of figures lists (None: NaN)."""
    z = {m: np.asarray([f.z if f is not None else np.nan + 0j for f in fs])
         for m, fs in figures.items()}
    rms = {m: np.asarray([f.z_rms if f is not None else np.nan for f in fs])
           for m, fs in figures.items()}
    return z, rms


def _print_rows(title, rows, modes, figures=None):
    """The fundamental table with its Z-width; with ``figures`` the rms table with its
    Z-width and the distortion and peaks table too."""
    from ..identification.output import format_table
    from ..identification.zwidth_lib import DC_OMEGA
    print(title)
    headers = ["mode"] + [("DC (0.1)" if abs(r.omega - DC_OMEGA) < 1e-12 else f"{r.omega:g}")
                          + " rad/s" for r in rows]

    def table(values, width, min_mode, label):
        out = [[m] + [f"{getattr(r, values)[m]:.2f}" if m in getattr(r, values) else "-"
                      for r in rows] for m in modes]
        out.append([f"Z-width{label} [dB]"] + [
            f"{getattr(r, width):.2f}" if getattr(r, width) is not None else "-" for r in rows])
        out.append(["  min mode"] + [getattr(r, min_mode) or "-" for r in rows])
        print(format_table(headers, out, [None] * len(headers)))
    print("fundamental |F_e/V_e|:")
    table("z_db", "width_db", "min_mode", "")
    if figures is None:
        return
    print("rms(F_e)/rms(V_e):")
    table("z_rms_db", "width_rms_db", "min_mode_rms", " rms")
    print("harmonic distortion of F_e [%]; peak |F_e| over the stroke / within +-0.2 rad:")
    out = []
    for m in modes:
        out.append([m] + [f"{100 * f.distortion:.0f} %; {f.peak:.3g}/{f.peak_centre:.3g}"
                          if f is not None else "-" for f in figures.get(m, [None] * len(rows))])
    print(format_table(headers, out, [None] * len(headers)))


def _plant_dahl(path, channel, option, plant, dahl):
    """``(PlantParams, DahlParams)`` of ``channel`` in a params file; a group the file does not
    have is the given default."""
    from ..identification.output import read_params_file
    from ..identification.params_file import dahl_params, plant_params, where
    p, d = read_params_file(path, channel, option)
    w = where(path, option)
    return (plant_params(p, w, channel) if p else plant,
            dahl_params(d, w, channel) if d else dahl)


def _config(path, channel, option, base):
    """ControllerConfig of ``base`` with the plant/dahl of ``channel`` in a params file."""
    from dataclasses import replace
    plant, dahl = _plant_dahl(path, channel, option, base.plant, base.dahl)
    return base.replace(plant=plant, dahl=dahl,
                        dob=replace(base.dob, nominal_inertia=plant.motor_inertia))


def _check_sources(args):
    """Bags or --simulate, each with its options, and --channel where something is read by it
    (a UsageError naming the first problem); a note to print once every option is checked,
    or None."""
    from ..identification.errors import UsageError
    files = [o for o, v in (("--params", args.params), ("--true-params", args.true_params),
                            ("--reference-params", args.reference_params)) if v is not None]
    if args.simulate and args.bags:
        raise UsageError("give bags or --simulate, not both")
    if not args.simulate:
        if not args.bags:
            raise UsageError("give backdrive bags (BAG or MODE=BAG) or --simulate")
        given = files + (["--modes"] if args.modes is not None else [])
        if given:
            raise UsageError(f"{given[0]} is for --simulate; the bags carry the mode and "
                             "parameters they were recorded with")
    if args.channel is not None and not args.channel.strip():
        raise UsageError("--channel: empty (give the channel's name, e.g. pinch)")
    if args.channel is None and (files or not args.simulate):
        raise UsageError("--channel is required: the channel to read from "
                         f"{files[0] if files else 'the bags'}")
    if args.channel is not None and args.simulate and not files:
        return (f"note: --channel {args.channel} names nothing here: no params file is given, "
                "so the simulated gripper and its controller are Table I's"
                + ("; it only labels the plot" if args.plot else ""))
    return None


def run(args):
    from ..core.params import ControllerConfig, DahlParams, PlantParams
    from ..identification.errors import UsageError
    from ..identification.output import Progress, check_output_file

    progress = Progress("zwidth", quiet=args.quiet)
    note = _check_sources(args)
    if args.plot:
        check_output_file(args.plot)
    curves = {}
    rms_curves = {}
    if args.simulate:
        # every option is checked before the first (long) simulation; the files first (the
        # simulation's modules take a second or two to import)
        if args.true_params:
            plant, dahl = _plant_dahl(args.true_params, args.channel, "--true-params",
                                      PlantParams.table_i(), DahlParams())
        else:
            plant, dahl = PlantParams.table_i(), DahlParams()
        truth_config = ControllerConfig(plant=plant, dahl=dahl)
        sets = []
        if args.params:
            sets.append(("params", _config(args.params, args.channel, "--params",
                                           truth_config)))
        else:
            sets.append(("true parameters", truth_config))
        if args.reference_params:
            sets.append(("reference", _config(args.reference_params, args.channel,
                                              "--reference-params", truth_config)))
        omegas = _frequencies(args.frequencies)
        modes = _modes(args.modes)
        if note:
            print(note)
        from ..identification.zwidth_lib import simulate_figures, zwidth_rows
        results = []
        for i, (label, cfg) in enumerate(sets):
            figs = simulate_figures(plant, dahl, cfg, modes, omegas, amplitude=args.amplitude,
                                    progress=progress.stage(i / len(sets), (i + 1) / len(sets)))
            z, rms = _arrays(figs)
            rows = zwidth_rows(omegas, z, rms_by_mode=rms)
            _print_rows(f"|Z| [dB re 1 N m s/rad], controller with {label} "
                        f"({args.params if label == 'params' else args.reference_params or ''})"
                        .replace(" ()", ""), rows, modes, figs)
            results.append(rows)
            curves[label] = z
            rms_curves[label] = rms
        if len(results) == 2:
            print("Z-width difference (params - reference) [dB]: " + ", ".join(
                f"{a.omega:g} rad/s {a.width_db - b.width_db:+.2f}"
                for a, b in zip(*results) if a.width_db is not None and b.width_db is not None)
                + "; on the rms: " + ", ".join(
                f"{a.omega:g} rad/s {a.width_rms_db - b.width_rms_db:+.2f}"
                for a, b in zip(*results)
                if a.width_rms_db is not None and b.width_rms_db is not None))
        z_plot = curves[sets[0][0]]
        rms_plot = rms_curves[sets[0][0]]
    else:
        for item in args.bags:
            _bag_item(item)
        from ..identification.zwidth_lib import zwidth_rows
        omegas, figs = _from_bags(args, progress)
        z_plot, rms_plot = _arrays(figs)
        modes = list(z_plot)
        rows = zwidth_rows(omegas, z_plot, rms_by_mode=rms_plot)
        _print_rows("|Z| [dB re 1 N m s/rad] from the bags", rows, modes, figs)
    if args.plot:
        from ..identification.plots import zwidth_fig5c
        markers = {m: (np.asarray(omegas), z) for m, z in z_plot.items()}
        lines = dict(z_plot)
        if args.simulate and len(curves) == 2:
            for m, z in curves["reference"].items():
                lines[f"{m} (reference)"] = z
        path = zwidth_fig5c(np.asarray(omegas), lines, args.plot,
                            f"{f'channel {args.channel}' if args.channel else 'Table I'}: "
                            "endpoint impedance per mode",
                            markers=markers, rms={m: (np.asarray(omegas), r)
                                                  for m, r in rms_plot.items()})
        print(f"wrote {path}")
    progress("done", 1.0)
    return 0


def main(argv=None):
    from ..identification.output import run_cli
    return run_cli("zwidth", run, build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
