"""Loop closure and relocalization for an odometry (VINS-Mono's ``pose_graph`` node): keyframes
from the odometry interface, place recognition (:mod:`quadnav.place`) and a pose graph
(:mod:`quadnav.posegraph`)."""

from quadnav.loop.closer import (
    LOOP_GRAPH,
    LoopClosure,
    LoopConfig,
    LoopStats,
    PlaceEvent,
    local_map,
)

__all__ = ["LOOP_GRAPH", "LoopClosure", "LoopConfig", "LoopStats", "PlaceEvent", "local_map"]
