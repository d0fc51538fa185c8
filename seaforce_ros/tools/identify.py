"""identify: plant and Dahl identification from rosbag2 bags (offline, no ROS graph needed).

    identify CHIRP_BAG --channel pinch --out PARAMS.yaml [--plots DIR]
    identify CHIRP_BAG --channel pinch --out PARAMS.yaml --dahl-bag LOOP_BAG
    identify --plant-params PARAMS.yaml --dahl-bag LOOP_BAG --channel pinch --out PARAMS.yaml

CHIRP_BAG: ``actuator_state`` of a torque-chirp experiment (sim ``torque_chirp`` environment
or the bonded-finger rig with the motor off; or the controller's ``chirp`` mode); a rosbag2
directory (mcap or sqlite3), a storage file, or a directory of split bags. Prints the
Blackman-Tukey/fit table (parameter, value, 1-sigma, fit error), writes PARAMS.yaml
(``/**: ros__parameters: <channel>: plant: {...}`` and, with ``--dahl-bag``, ``dahl: {...}``)
for ``--ros-args --params-file``, and Fig. 4 / Fig. 6-style PNGs into ``--plots``.

``--external-force auto`` (the default) fits the endpoint with the recorded F_e held over the
sample (a drive's command, the sim) and sampled at its instant (a force sensor), keeps the
one with the smaller misfit, and says which and both misfits (table, progress, the params
file's header).

Exit status: 0 ok, 2 bad input (a one-line reason on stderr, no stack trace).
"""

from __future__ import annotations

import argparse
import math
import sys

__all__ = ["main", "build_parser"]


def build_parser():
    from ..identification.output import positive_float
    p = argparse.ArgumentParser(
        prog="identify",
        description="Identify the eight linear plant parameters (Table I) from a chirp bag, "
                    "and the Dahl hysteresis from a work-loop bag.")
    p.add_argument("bag", nargs="?", help="chirp bag (rosbag2 dir, .mcap/.db3, or a "
                   "directory of split bags)")
    p.add_argument("--channel", required=True, help="channel name in actuator_state")
    p.add_argument("--out", required=True, help="parameter file to write (YAML)")
    p.add_argument("--plots", help="directory for the PNG figures")
    p.add_argument("--dahl-bag", help="work-loop bag (position drive, e.g. 0.5 rad at "
                   "1 rad/s) for the Dahl fit")
    p.add_argument("--plant-params", help="use the plant parameters of this params file "
                   "instead of a chirp bag (for --dahl-bag alone)")
    p.add_argument("--topic", default="actuator_state", help="state topic (default "
                   "actuator_state)")
    p.add_argument("--band", nargs=2, type=positive_float, default=(0.5, 400.0),
                   metavar=("LO", "HI"), help="fit band of plants A-C [rad/s] (default 0.5 400)")
    p.add_argument("--rational-band", nargs=2, type=positive_float, default=None,
                   metavar=("LO", "HI"), help="band of the 2-zero/4-pole X_e/F_e fit [rad/s] "
                   "(default: --band; the paper: 0-400)")
    p.add_argument("--excitation", choices=("auto", "external", "motor"), default="auto",
                   help="which torque was chirped (auto: the larger of F_e and F_a)")
    p.add_argument("--external-force", choices=("auto", "held", "instant"), default="auto",
                   help="how the recorded F_e relates to its sample. held: held over the "
                        "sample interval after it (the sim's environment, a drive's "
                        "command); instant: a sampled force sensor; auto: fit both, keep "
                        "the one with the smaller endpoint misfit and print both "
                        "(default: auto)")
    p.add_argument("--dahl-force", choices=("continuous", "held"), default="continuous",
                   help="continuous: the endpoint's friction follows its position (hardware); "
                        "held: held over each sample interval (bags from sim_node or the core "
                        "simulator)")
    p.add_argument("--rate", type=positive_float, help="sample rate [Hz] (default: from the "
                   "stamps)")
    p.add_argument("--no-dahl", action="store_true", help="fit the endpoint as purely "
                   "linear (as the paper did; hysteresis then biases m_e, b_e, k_e)")
    p.add_argument("--fit-exponent", action="store_true", help="fit the Dahl exponent n too")
    p.add_argument("--truth", help="params file with the true values (simulation): adds "
                   "error columns")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def _identify_chirp(args, progress):
    from ..bags import read_channel
    from ..identification.plant_id import identify_plant
    from ..identification.timeseries import prepare

    progress("reading " + args.bag, 0.0)
    record = read_channel(args.bag, args.channel, args.topic, progress.stage(0.0, 0.25))
    for note in record.notes:
        print("note: " + note)
    series = prepare(record, ("x", "f_p", "x_e"),
                     dt=None if args.rate is None else 1.0 / args.rate,
                     optional=("f_e", "f_a"))
    progress(f"{series.n} samples, {series.duration:.1f} s at {1 / series.dt:.0f} Hz", 0.25)
    for note in series.notes():
        print("note: " + note)
    result = identify_plant(
        series, band=tuple(args.band),
        rational_band=tuple(args.rational_band or args.band),
        excitation=args.excitation,
        external_force=args.external_force,
        dahl=not args.no_dahl, dahl_delay=0.5 if args.dahl_force == "held" else 0.0,
        progress=progress.stage(0.25, 0.95))
    if result.external_force is not None:
        progress(result.external_force.summary(), None)
    return record, series, result


def _print_plant_table(result, truth, series, record):
    from ..identification.output import format_table

    # a 1-sigma that is zero or undefined is a degenerate covariance: not identified
    rows = [r[:4] + ((format(r[4], ".2g") if math.isfinite(r[4]) and r[4] > 0
                      else "not identified"),) + r[5:] for r in result.rows(truth)]
    headers = ["parameter", "symbol", "unit", "value", "1-sigma", "fit error", "plant"]
    formats = [None, None, None, ".5g", None, ".2%", None]
    if truth is not None:
        headers += ["true", "error"]
        formats += [".5g", "+.2f"]
        rows = [r[:-1] + (f"{r[-1]:+.2f} %",) for r in rows]
        formats[-1] = None
    print(f"channel {record.channel}: {series.n} samples ({series.duration:.1f} s), "
          f"{result.excitation} excitation over {result.excited_band[0]:.3g}-"
          f"{result.excited_band[1]:.3g} rad/s; fits over {result.band[0]:g}-"
          f"{result.band[1]:g} rad/s")
    print(format_table(headers, rows, formats))
    if result.external_force is not None:
        print(result.external_force.summary())
    for line in hysteresis_lines(result.hysteresis, result.fits["B"].extra):
        print(line)
    if "D" in result.fit_error:
        print(f"X_e/F_e from the identified parameters vs the measured response: "
              f"{result.fit_error['D']:.2%} rms")
    if result.rational is not None:
        r = result.rational
        poles = ", ".join(f"{p.real:.2f}{p.imag:+.2f}j" if abs(p.imag) > 1e-9
                          else f"{p.real:.2f}" for p in r.poles)
        print(f"2-zero/4-pole fit of X_e/F_e over {r.band[0]:g}-{r.band[1]:g} rad/s: poles "
              f"{poles} rad/s, fit error {r.fit_error:.2%}")
    for note in result.notes:
        print("note: " + note)


def hysteresis_lines(h, extra):
    """What the chirp showed of the endpoint hysteresis: values with 1-sigma where identified,
    ``not identified (reason)`` where not -- never a value with a zero 1-sigma."""
    if h is None:
        return []
    if h.model == "none":
        return [f"endpoint hysteresis: {h.coulomb_force_reason}; endpoint fitted as linear"]
    head = {"dahl": "endpoint hysteresis seen in the chirp (Dahl force removed before fitting B)",
            "coulomb": "endpoint hysteresis seen in the chirp (Coulomb limit of the Dahl model "
                       "removed before fitting B)",
            "spring": "endpoint hysteresis: not separable from the endpoint stiffness"}[h.model]
    lines = [f"{head}: misfit {h.cost_linear:.4g} (linear only) -> {h.cost:.4g}"]
    for name, unit, value, one, reason in (
            ("sigma", "N m/rad", h.sigma, h.sigma_1s, h.sigma_reason),
            ("F_c", "N m", h.coulomb_force, h.coulomb_force_1s, h.coulomb_force_reason)):
        if reason:
            lines.append(f"  {name}: not identified ({reason})")
        else:
            lines.append(f"  {name} = {value:.4g} +- {one:.2g} {unit}")
    return lines


def loop_lines(fit, bag, fit_exponent):
    """The work-loop Dahl fit: values with 1-sigma, or ``not identified (reason)``."""
    def value(name, v, one, unit, reason, fmt=".4g"):
        if reason:
            return f"{name} not identified ({reason})"
        return f"{name} = {v:{fmt}} +- {one:.2g}{unit}"
    parts = [value("sigma", fit.sigma, fit.sigma_1s, " N m/rad", fit.sigma_reason),
             value("F_c", fit.coulomb_force, fit.coulomb_force_1s, " N m",
                   fit.coulomb_force_reason)]
    if fit_exponent:
        parts.append(value("n", fit.exponent, fit.exponent_1s, "", fit.exponent_reason, ".3g"))
    else:
        parts.append(f"n = {fit.exponent:.3g} (fixed)")
    return [f"Dahl fit (work loop {bag}): " + ", ".join(parts)
            + f"; loop residual rms {fit.rms:.3g} N m (linear terms only: "
              f"{fit.rms_linear_only:.3g} N m)"]


def _dahl(args, plant, progress):
    from ..bags import read_channel
    from ..identification.dahl_fit import fit_dahl_loop
    from ..identification.timeseries import prepare

    progress("reading " + args.dahl_bag, None)
    record = read_channel(args.dahl_bag, args.channel, args.topic)
    for note in record.notes:
        print("note (Dahl bag): " + note)
    series = prepare(record, ("x_e", "f_e", "f_p"),
                     dt=None if args.rate is None else 1.0 / args.rate)
    for note in series.notes():
        print("note (Dahl bag): " + note)
    progress("fitting the Dahl model to the work loop", None)
    fit = fit_dahl_loop(series, plant, fit_exponent=args.fit_exponent,
                        external_force_delay=0.0)
    return fit


def check_arguments(args):
    """Combinations and values argparse cannot check (UsageError naming the option)."""
    from ..identification.errors import UsageError
    if args.bag is not None and args.plant_params:
        raise UsageError("--plant-params replaces the chirp bag: give one of them, not both")
    if args.bag is None and not (args.plant_params and args.dahl_bag):
        raise UsageError("give a chirp bag, or --plant-params with --dahl-bag")
    for option, band in (("--band", args.band), ("--rational-band", args.rational_band)):
        if band is not None and not band[0] < band[1]:
            raise UsageError(f"{option}: LO must be below HI, got {band[0]:g} {band[1]:g}")


def run(args):
    from ..identification.errors import IdentificationError
    from ..identification.output import (Progress, check_output_dir, check_params_update,
                                        read_plant, write_params_file)

    progress = Progress("identify", quiet=args.quiet)
    check_arguments(args)
    # every input file and the output are checked before the long work
    truth = read_plant(args.truth, args.channel, "--truth") if args.truth else None
    plant = (read_plant(args.plant_params, args.channel, "--plant-params")
             if args.plant_params else None)
    check_params_update(args.out, args.channel, plant=args.bag is not None,
                        dahl=bool(args.dahl_bag), option="--out")
    plots = check_output_dir(args.plots) if args.plots else None
    comments = []
    if args.bag is not None:
        record, series, result = _identify_chirp(args, progress)
        plant = result.params
        _print_plant_table(result, truth, series, record)
        comments.append(f"{args.channel}.plant: chirp bag {args.bag} ({series.duration:.1f} s, "
                        f"{result.excitation} excitation, fits over {result.band[0]:g}-"
                        f"{result.band[1]:g} rad/s)")
        if result.external_force is not None:
            comments.append(f"{args.channel}.plant: {result.external_force.summary()}")
        if plots is not None:
            from ..identification.plots import bode_fig4
            path = bode_fig4(result, plots / f"{args.channel}_fig4_bode.png",
                             f"channel {args.channel}: identification ({args.bag})")
            print(f"wrote {path}")
    dahl = None
    if args.dahl_bag:
        fit = _dahl(args, plant, progress)
        for line in loop_lines(fit, args.dahl_bag, args.fit_exponent):
            print(line)
        if not fit.identified:
            if args.bag is None:
                raise IdentificationError(
                    f"the work loop {args.dahl_bag} does not identify the Dahl model (see "
                    "above); record a larger or slower loop (e.g. 0.5 rad at 1 rad/s)")
            print(f"note: {args.channel}.dahl not written: the work loop does not identify it")
        else:
            dahl = {"sigma": fit.sigma, "coulomb_force": fit.coulomb_force,
                    "exponent": fit.exponent}
            comments.append(f"{args.channel}.dahl: work-loop bag {args.dahl_bag}")
        if plots is not None:
            from ..identification.plots import dahl_fig6
            path = dahl_fig6(fit, plots / f"{args.channel}_fig6_dahl.png",
                             f"channel {args.channel}: Dahl fit ({args.dahl_bag})")
            print(f"wrote {path}")
    out = write_params_file(args.out, args.channel,
                            plant=plant if args.bag is not None else None, dahl=dahl,
                            comments=comments, option="--out")
    print(f"wrote {out}")
    print(_free_finger_line(out, args.channel))
    progress("done", 1.0)
    return 0


def _free_finger_line(path, channel):
    """What ``controller_node`` started with the written file would say of ``channel``'s free
    finger, as one line: whether the file's ``feedforward.damping_reserve`` (or the default)
    holds it over the written model's band (its start-up check,
    :func:`~seaforce_ros.commissioning.free_finger.reserve_verdict`, at the file's ``rate``
    and ``loop``), or why the node would not start on the file. Only the sections the node
    ``/controller`` reads count."""
    from ..commissioning.free_finger import band_spreads, reserve_verdict
    from ..core.errors import SeaforceError
    from ..core.params import ControllerConfig
    from ..core.schema import BRINGUP, CONTROLLER, node_rows
    from ..identification.errors import IdentificationError
    from ..identification.params_file import controller_view, load, where
    keys = [spec.name for spec in ControllerConfig.rows()]
    # the node's rate and the bringup's loop, checked by their own schema rows
    node = {s.name: s for s in node_rows(CONTROLLER, per_channel=False)
            + node_rows(BRINGUP, per_channel=False) if s.name in ("rate", "loop")}
    try:
        view = controller_view(load(path), channel, where(path), keys)
        if view.misspelt:
            name, meant = view.misspelt[0]
            raise SeaforceError(f"{name}: no such parameter (did you mean {meant}?)")
        config = ControllerConfig.from_dict(view.values)
        settings = {k: s.default for k, s in node.items()}
        for k, value in view.node.items():
            reason = node[k].reason(value)
            if reason:
                raise SeaforceError(reason)
            settings[k] = node[k].coerce(value)
    except (SeaforceError, IdentificationError) as exc:
        return f"warning: controller_node would not start on this file: {channel}: {exc}"
    rate = float(settings["rate"])
    direct = settings["loop"] == "direct"
    try:
        verdict = reserve_verdict(config, delay=1 if direct else 2, dt=1.0 / rate)
    except (SeaforceError, ArithmeticError, ValueError) as exc:
        return f"warning: free finger: not checked ({exc})"
    if verdict:
        return f"warning: free finger: {verdict}"
    spread = 100 * max(band_spreads(config).values())
    return (f"free finger: feedforward.damping_reserve = "
            f"{config.feedforward.damping_reserve:.3g} N m s/rad holds a free finger in "
            f"dob_full_ff over this model's band (+-{spread:.0f} %) at {rate:g} Hz in the "
            f"{'direct' if direct else 'topics'} layout")


def main(argv=None):
    from ..identification.output import run_cli
    return run_cli("identify", run, build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
