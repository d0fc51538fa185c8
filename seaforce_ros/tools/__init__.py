"""Command-line tools. Offline (no ROS running needed): ``identify`` (:mod:`.identify`: the
plant and the Dahl hysteresis from a bag), ``zwidth`` (:mod:`.zwidth`: endpoint impedance per
mode and the Z-width from bags, or predicted from a params file) and ``bag_reindex``
(:mod:`.bag_reindex`: repair a bag a kill or a full disk left incomplete). Against running
nodes: ``commission`` (:mod:`.commission`: the ``~/commission`` action with a progress bar)."""
__all__ = ["identify", "zwidth", "bag_reindex", "commission"]
