"""A synthetic commissioning report shaped like a real run on the Table I plant: every section
filled, 1-sigma bands, a parameter not identified, drift against a previous run, measured
points, a binding constraint. For the report's tests and its render bench."""
from __future__ import annotations

import numpy as np

from seaforce_ros.core.analysis import impedance_figures

from seaforce_ros.commissioning.report import (MODES, CommissioningReport, LoopFigure,
                                               ModeImpedance, ModelClass, NoiseSweep,
                                               ParameterRow, PortResponse, ReportMeta, Tuning,
                                               TuningRow, WallBoundary, WorkLoop, ZWidthChart)

__all__ = ['example_report']

# Table I (motor frame): m, b, k, b_s, k_s
M, B, K, BS, KS = 1.1116e-3, 2.9814e-2, 0.1642, 0.06, 13.0782
T_DELAY = 1.5e-3   # loop delay [s]


def _port_responses(rng):
    w = np.logspace(0, np.log10(600), 80)
    s = 1j * w
    adm = 1 / (M * s**2 + B * s + K + BS * s + KS)        # X/(F_a+F_p) with the hose
    hose = BS * s + KS                                     # F_p/X
    out = []
    for name, unit, h in (('X/(F_a+F_p)', 'rad/(N m)', adm), ('F_p/X', 'N m/rad', hose)):
        coh = np.clip(0.98 - 0.5 * (w / 600) ** 2 - 0.3 * np.exp(-w), 0.05, 1)
        sigma = np.abs(h) * np.sqrt((1 - coh) / (2 * 8 * coh))
        meas = h * (1 + sigma / np.abs(h) * (rng.standard_normal(len(w))
                                             + 1j * rng.standard_normal(len(w))) / np.sqrt(2))
        out.append(PortResponse(name, unit, w, meas, sigma, coh, h * (1 + 0.02j)))
    return out


def _impedance(rng):
    w = np.logspace(-1, 2, 60)
    s = 1j * w
    shapes = {'passive': (KS, BS, M), 'hold': (400.0, 2.0, M), 'force_feedback': (KS / 8, .02, M),
              'dob': (0.8, 0.01, M / 3), 'dob_linear_ff': (0.3, 0.004, M / 4),
              'dob_full_ff': (0.05, 0.0015, M / 5), 'impedance': (5.0, 0.3, M)}
    out = []
    for mode in MODES:
        k, b, m = shapes[mode]
        z = k / s + b + m * s
        rel = 0.08 + 0.1 * (w / 100)
        pts = np.array([0.1, 1.0, 3.0, 10.0])
        zp = np.abs(k / (1j * pts) + b + m * 1j * pts) * (1 + 0.05 * rng.standard_normal(4))
        measured = {} if mode in ('force_feedback', 'impedance') else {
            'measured_omega': pts, 'measured_abs': zp}
        out.append(ModeImpedance(mode, w, z, np.abs(z) * (1 - rel), np.abs(z) * (1 + rel),
                                 **measured))
    return out


def _zwidth(impedance, rng):
    by = {m.mode: m for m in impedance}
    w = by['hold'].omega
    zmin = np.min([np.abs(m.z) for m in impedance], axis=0)
    zw = 20 * np.log10(np.abs(by['hold'].z) / zmin)
    band = 1.5 + 2.0 * (w / w[-1])
    pts = np.array([0.1, 1.0, 3.0, 10.0])
    meas = np.interp(np.log(pts), np.log(w), zw) - 2 + rng.standard_normal(4)
    b = np.linspace(0, 1.0, 60)
    k_pass = 2 * b / T_DELAY + 2.0                          # passivity with the loop delay
    k_quant = np.full_like(b, 600.0)                        # encoder quantisation
    wall = WallBoundary(b, k_pass, k_quant, chosen_damping=0.3, chosen_stiffness=300.0)
    return ZWidthChart(w, zw, zw - band, zw + band, pts, meas, np.full(4, 1.2), wall)


def _work_loops(rng):
    """Work loops at 1 rad/s, 0.5 rad: a linear finger with Coulomb friction per mode, the
    soft ones with a stroke-dependent stiffness that grows outside +-0.2 rad."""
    theta = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
    x = 0.5 * np.sin(theta)
    v = np.cos(theta)
    out = []
    for mode, k, b, fc in (('passive', 0.22, 0.04, 0.03), ('hold', 20.0, 0.5, 0.0),
                           ('dob', 0.05, 0.01, 0.02), ('dob_full_ff', 0.004, 0.002, 0.004)):
        f = k * x * (1.0 + 1.5 * x ** 2) + b * v + fc * np.tanh(v / 0.05)
        f = f + 0.02 * fc * rng.standard_normal(f.size)
        fig = impedance_figures(f, x, 1.0, 2.0 * np.pi / theta.size)
        out.append(WorkLoop(mode, 1.0, 0.5, x, f, fig.z_db, fig.z_rms_db, fig.distortion,
                            fig.peak, fig.peak_centre,
                            source='simulated on the identified model'))
    return out


def example_report(seed=0, channel='left_finger'):
    """A filled report (``seed`` draws the measurement noise)."""
    rng = np.random.default_rng(seed)
    ident = [
        ParameterRow('plant.motor_inertia', 'm', 'N m s^2/rad', 1.12e-3, 0.03e-3,
                     previous=1.10e-3, true=M),
        ParameterRow('plant.motor_damping', 'b', 'N m s/rad', 2.95e-2, 0.08e-2,
                     previous=2.99e-2, true=B),
        ParameterRow('plant.motor_stiffness', 'k', 'N m/rad', 0.171, 0.012, previous=0.160,
                     true=K),
        ParameterRow('plant.hose_damping', 'b_s', 'N m s/rad', 0.061, 0.004, previous=0.058,
                     true=BS),
        ParameterRow('plant.hose_stiffness', 'k_s', 'N m/rad', 13.02, 0.21, previous=12.1,
                     true=KS),
        ParameterRow('plant.endpoint_inertia', 'm_e', 'N m s^2/rad', float('nan'),
                     float('nan'), status='not identified (needs the endpoint encoder)',
                     true=2.5e-4),
        ParameterRow('dahl.coulomb_force', 'F_c', 'N m', float('nan'), float('nan'),
                     status='not identified (free-air excitation does not load the endpoint)'),
    ]
    loop = [LoopFigure('pressure noise (RMS)', 4.1e-3, 0.2e-3, 'N m'),
            LoopFigure('encoder resolution', 1.53e-4, float('nan'), 'rad'),
            LoopFigure('loop delay p50', 2.0, float('nan'), 'samples'),
            LoopFigure('loop delay p99', 3.0, float('nan'), 'samples'),
            LoopFigure('missed commands', 0.0, float('nan'), 'per 10^4 cycles')]
    impedance = _impedance(rng)
    lam = np.logspace(1, np.log10(2000), 25)
    rms = 1.5e-3 * (lam / 40) ** 0.6
    noise = NoiseSweep(lam, rms, 0.08 * rms, budget=0.01, chosen=2 * np.pi * 20)
    tuning = Tuning([
        TuningRow('dob.cutoff', 2 * np.pi * 20, 2 * np.pi * 20, 'rad/s',
                  'torque noise budget 0.01 N m'),
        TuningRow('dob.nominal_inertia', 1.1116e-3, 1.12e-3, 'N m s^2/rad',
                  'identified m'),
        TuningRow('dob.nominal_damping', 0.0, -0.01, 'N m s/rad',
                  'passivity k_n <= k + lambda b_n (eq. 28)'),
        TuningRow('hold.stiffness', 300.0, 420.0, 'N m/rad', 'K_max(B) passivity with delay'),
        TuningRow('impedance.damping', 0.2, 0.3, 'N m s/rad', 'quantisation limit cycle'),
    ], 'passivity with the 1.5 ms loop delay: K_hold <= 2 B / T (eq. 28 with delay)')
    return CommissioningReport(
        meta=ReportMeta(channel, '2026-12-03T11:20:00Z',
                        {'identification': 42.0, 'sensor figures': 6.5, 'prediction': 3.2,
                         'tuning': 1.1}, applied=False, seed=seed),
        identification=ident, responses=_port_responses(rng), loop=loop, impedance=impedance,
        zwidth=_zwidth(impedance, rng), noise=noise, tuning=tuning,
        work_loops=_work_loops(rng),
        model_class=ModelClass({'motor': 0.012, 'port': 0.085}, {'motor': 0.03, 'port': 0.025},
                               'the port misfit 8.5 % exceeds 2.5 %: the linear model does not '
                               'describe this gripper',
                               ['hose damping c |V| V: resolved, 4.1e-3 +- 0.3e-3 N m s^2/rad^2']),
        summary=['5 of 7 parameters identified; k_s drifted +7.6 % since the last '
                 'commissioning (4.4 sigma)',
                 'loop delay p99 3 samples; no missed commands',
                 'dry run: the tuned parameters were not applied'])
