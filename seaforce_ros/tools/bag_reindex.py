"""``bag_reindex BAG_DIR``: make a bag that a kill or a full disk left incomplete readable by
every tool (like ``ros2 bag reindex``; what it repairs: :mod:`seaforce_ros.bags.repair`)."""
from __future__ import annotations

import argparse
import sys

from ..bags.errors import BagError
from ..bags.repair import reindex_bag


def main(argv=None):
    """``bag_reindex BAG_DIR``: exit 0 when the bag is readable, 2 on bad input (one line)."""
    parser = argparse.ArgumentParser(
        prog="bag_reindex",
        description="Repair a rosbag2 bag directory left incomplete by a killed recorder or a "
                    "full disk: give cut-short mcap files their summary, recover sqlite3 "
                    "files left with their WAL, and rewrite metadata.yaml from the files.")
    parser.add_argument("bag", help="bag directory (holds metadata.yaml and the .mcap/.db3 "
                                    "files)")
    args = parser.parse_args(argv)
    try:
        report = reindex_bag(args.bag)
    except (BagError, OSError) as exc:
        print(f"bag_reindex: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bag_reindex: interrupted", file=sys.stderr)
        return 130
    for line in report.lines:
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
