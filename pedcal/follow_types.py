"""What a person tracker consumes and returns, one frame at a time.

Every tracker (the paper's, LIDAR-only, the factor-graph recovery) implements :class:`Tracker`;
the following simulation and ``pedcal follow`` only speak to it through these types, so trackers
are interchangeable on the same frames. The simulator (``pedcal.sim``) and the trackers
(``pedcal.track``) both build on this module and on nothing of each other's.

Frames: ``robot`` is the robot's base frame (x forward, y left, z up, metres); ``world`` is the
map frame. Bearings are radians, counter-clockwise from the robot's x axis, in [-pi, pi).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

TRACKER_STATES = ("Initialize", "Tracking", "Lost", "Searching")


@dataclass(frozen=True)
class PersonDetection:
    """One LIDAR detection that passed the detector (gate + classifier), in the robot frame."""

    xy_robot_m: np.ndarray  # (2,) box centre
    height_m: float
    score: float  # the classifier's P(person)
    reflectance_hist: np.ndarray  # (B,) normalized reflectance histogram of the cluster's points (appearance)


@dataclass(frozen=True)
class EsparReading:
    """One direction-finding reading: the strongest of the antenna's 12 directions (30 deg apart)."""

    antenna: int  # which antenna on the robot (0 or 1)
    direction_index: int  # 0..11; direction k points at bearing k * 30 deg in the antenna's frame
    bearing_robot_rad: float  # the quantized direction expressed in the robot frame
    xy_antenna_robot_m: np.ndarray  # (2,) the antenna's position on the robot


@dataclass(frozen=True)
class FollowFrame:
    """Everything a tracker may use at one LIDAR frame."""

    t_s: float
    pose_world_robot: np.ndarray  # (3,) x_m, y_m, yaw_rad: the robot's localization estimate
    cov_world_robot: np.ndarray  # (3, 3) its covariance (x, y, yaw)
    detections: tuple[PersonDetection, ...]
    espar: tuple[EsparReading, ...]  # readings that arrived since the previous frame (may be empty)
    robot_stopped: bool  # the robot is standing still (the paper accumulates its grid then)


@dataclass
class TrackEstimate:
    """One person filter's state, in the world frame."""

    track_id: int
    xy_world_m: np.ndarray  # (2,)
    cov_xy_world: np.ndarray  # (2, 2)
    p_target: float  # probability that this track is the target (normalized over tracks + lost)
    detected: bool  # a detection updated this track in this frame


@dataclass
class TrackerOutput:
    """A tracker's answer for one frame, and what it wants the robot to do."""

    state: str  # one of TRACKER_STATES
    target_track_id: int | None  # the track it believes is the target (None when lost)
    target_xy_world_m: np.ndarray | None  # best estimate of the target, also while out of sight
    target_cov_world: np.ndarray | None  # (2, 2) its covariance, when the tracker has one
    tracks: list[TrackEstimate] = field(default_factory=list)
    stop_robot: bool = False  # the tracker asks the robot to stand still (the paper's Searching)
    goal_xy_world_m: np.ndarray | None = None  # where to drive when the target is not in view
    face_world_rad: float | None = None  # with stop_robot: turn in place to this heading (the antenna's bearing)


class Tracker(Protocol):
    """A person tracker that follows one target carrying the antenna's transmitter."""

    name: str

    def step(self, frame: FollowFrame) -> TrackerOutput:
        """Consume one frame and return the tracker's estimate for it."""
        ...
