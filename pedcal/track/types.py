"""The tracker's frame and output types, kept importable here; they live in :mod:`pedcal.follow_types`,
below both the simulator and the trackers that share them."""

from pedcal.follow_types import (
    TRACKER_STATES,
    EsparReading,
    FollowFrame,
    PersonDetection,
    Tracker,
    TrackerOutput,
    TrackEstimate,
)

__all__ = ["TRACKER_STATES", "EsparReading", "FollowFrame", "PersonDetection", "Tracker", "TrackerOutput",
           "TrackEstimate"]
