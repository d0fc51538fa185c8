"""The free-air excitation over random plants: what it does and how long it takes to simulate.

For N plants (every Table I parameter and the Dahl sigma, F_c log-uniform in 0.5x..2x; the
controller's model: Table I) one default excitation (0.2..800 Hz in 40 s after a 0.5 s rest)
in closed loop on the core simulator, printing per plant: the outcome, peak |X - x_0| [rad]
and its share of the room, peak |V| [rad/s] and its share of max_speed, peak |F_a| [N m],
the contact test's level (aborts above 1), the amplitude correction g at the end, and the
wall time of the simulation; then the job's own cost per sample (``FreeAirExcitation.update``
in the excitation phase, the contact test running), mean and p99 over chunks. Timing figures
are printed, never asserted.

Run:  PYTHONPATH=. python bench/commissioning_excitation.py [--draws 10] [--duration 40]
      [--quick]      (one 4 s draw and a short cost loop: a smoke run, figures meaningless)
"""

import argparse
import dataclasses
import math
import time

import numpy as np

from seaforce_ros.commissioning.excitation import ExcitationGoal, FreeAirExcitation
from seaforce_ros.commissioning.experiments import simulate_excitation
from seaforce_ros.core import ControllerConfig, DahlParams, PlantParams


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=10)
    parser.add_argument("--duration", type=float, default=40.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: one draw of 4 s, 10 chunks of the cost loop")
    args = parser.parse_args()
    if args.quick:
        args.draws, args.duration = 1, 4.0
    rng = np.random.default_rng(args.seed)
    model = ControllerConfig()
    c = model.commissioning
    room = min(-c.position_min, c.position_max)
    names = [f.name for f in dataclasses.fields(PlantParams)]
    print(f"{'draw':>4} {'outcome':>9} {'|X|max':>7} {'/room':>6} {'|V|max':>7} {'/vmax':>6} "
          f"{'|F_a|':>6} {'contact':>8} {'g':>5} {'sim s':>6}")
    times = []
    for draw in range(args.draws):
        factors = {n: float(np.exp(rng.uniform(math.log(0.5), math.log(2.0)))) for n in names}
        d = np.exp(rng.uniform(math.log(0.5), math.log(2.0), 2))
        plant = PlantParams.table_i().scaled(**factors)
        dahl = DahlParams(sigma=12.8 * d[0], coulomb_force=0.032 * d[1])
        start = time.perf_counter()
        run = simulate_excitation(plant, dahl, model, seed=draw, duration=args.duration)
        seconds = time.perf_counter() - start
        times.append(seconds)
        job, record = run.job, run.record
        torque = float(np.max(np.abs(record.command)))
        print(f"{draw:>4} {job.outcome:>9} {job.peak_position:7.3f} "
              f"{job.peak_position / room:6.2f} {job.peak_speed:7.2f} "
              f"{job.peak_speed / c.max_speed:6.2f} {torque:6.3f} {job.contact_level:8.2f} "
              f"{job.gain:5.2f} {seconds:6.2f}")
    print(f"simulation of {args.duration:g} s + rest: mean {np.mean(times):.2f} s, "
          f"max {np.max(times):.2f} s per record")
    job_cost(model, chunks=10 if args.quick else 100)


def job_cost(model: ControllerConfig, chunk: int = 200, chunks: int = 100) -> None:
    """The job's update alone, on a free finger's synthetic motion."""
    job = FreeAirExcitation(ExcitationGoal("bench", (20.0, 400.0), 20.0), model)
    x = [5e-3 * math.sin(0.3 * i) for i in range(chunk * (chunks + 10))]
    v = [3.0 * math.cos(0.3 * i) for i in range(len(x))]
    update = job.update
    for i in range(chunk * 10):         # the rest and the chirp's first periods
        update(x[i], v[i], -x[i], 0.0, 0.0, i)
    per_call = []
    for c in range(10, chunks + 10):
        start = time.perf_counter()
        for i in range(c * chunk, (c + 1) * chunk):
            update(x[i], v[i], -x[i], 0.0, 0.0, i)
        per_call.append((time.perf_counter() - start) / chunk * 1e6)
    print(f"FreeAirExcitation.update per sample [us]: mean {np.mean(per_call):.2f}, "
          f"p99 of chunks {np.percentile(per_call, 99):.2f}, floor {np.min(per_call):.2f} "
          f"({job.phase}, contact level {job.contact_level:.2f})")


if __name__ == "__main__":
    main()
