"""``python -m seaforce_ros.demos [grasp | commission] [options]``: the impedance demo (the
README's main job, :mod:`.impedance`), the grasping demo (``grasp``, :mod:`.grasp`) or the
commissioning demo (``commission``, :mod:`.commission`)."""
import sys


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ['grasp']:
        from .grasp import main as grasp_main
        return grasp_main(argv[1:])
    if argv[:1] == ['commission']:
        from .commission import main as commission_main
        return commission_main(argv[1:])
    from .impedance import main as impedance_main
    return impedance_main(argv)


if __name__ == '__main__':
    sys.exit(main())
