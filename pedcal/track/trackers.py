"""The trackers by name: the paper's, the LIDAR-only follower, and the factor-graph tracker built on
the paper's (:mod:`pedcal.track.tracker` knows nothing of :mod:`pedcal.track.recovery`)."""

from __future__ import annotations

from collections.abc import Callable

from pedcal.follow_types import Tracker
from pedcal.track.recovery import FactorGraphTracker
from pedcal.track.tracker import LidarOnlyTracker, PaperTracker

TRACKERS: dict[str, Callable[..., Tracker]] = {"paper": PaperTracker, "lidar-only": LidarOnlyTracker,
                                              "factorgraph": FactorGraphTracker}


def make_tracker(name: str, **options) -> Tracker:
    """A tracker by name (``TRACKERS``: "paper", "lidar-only", "factorgraph") built with ``options``
    (TrackerConfig fields, or the tracker's own keywords)."""
    try:
        factory = TRACKERS[name]
    except KeyError:
        raise ValueError(f"unknown tracker {name!r}; expected one of {sorted(TRACKERS)}") from None
    return factory(**options)


__all__ = ["TRACKERS", "make_tracker"]
