"""Time to write the commissioning report and to render its page.

Prints, for the synthetic example report of the tests (every section filled): the wall time of
``write_report`` (four figures drawn with matplotlib Agg, report.json, report.html) per
repetition, the size of each file, and the wall time of a headless Chromium screenshot of the
page (``/usr/bin/chromium``, the render test's flags). Timing figures are printed, never
asserted.

Run:  PYTHONPATH=. python bench/report_render.py [--repeats 3] [--out DIR] [--quick]
(``--out`` keeps the last report and its screenshot there, for a look; ``--quick``: one
repetition, a smoke run.)
"""
import argparse
import pathlib
import statistics
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / 'test'))

from helpers.chromium import screenshot  # noqa: E402
from helpers.report_example import example_report  # noqa: E402
from seaforce_ros.commissioning.report import write_report  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--repeats', type=int, default=3)
    ap.add_argument('--out', type=pathlib.Path, default=None)
    ap.add_argument('--quick', action='store_true', help='smoke run: one repetition')
    args = ap.parse_args()
    if args.quick:
        args.repeats = 1
    data = example_report()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or pathlib.Path(tmp) / 'out'
        write_times, shot_times = [], []
        for i in range(args.repeats):
            t0 = time.perf_counter()
            page = write_report(out / 'report', data)
            write_times.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            screenshot(page, out / 'screenshot.png', tmp)
            shot_times.append(time.perf_counter() - t0)
        print(f'write_report (4 figures, json, html): median {statistics.median(write_times):.2f} s'
              f'  ({", ".join(f"{t:.2f}" for t in write_times)})')
        print(f'chromium screenshot 1280x6000:         median {statistics.median(shot_times):.2f} s'
              f'  ({", ".join(f"{t:.2f}" for t in shot_times)})')
        for p in sorted(page.parent.iterdir()):
            print(f'  {p.name:20s} {p.stat().st_size / 1024:8.1f} KiB')
        if args.out:
            print(f'kept in {out}')


if __name__ == '__main__':
    main()
