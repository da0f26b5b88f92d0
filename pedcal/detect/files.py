"""People in a point-cloud file: read, thinned to the trained density, put into the sensor's body
frame with the floor at z = 0 (``pedcal.detect.ground``), detected.

Below both ``pedcal detect`` (pedcal.detect.detect_cli) and the real-frame evaluation
(pedcal.detect.real_eval), which use it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedcal.detect.detection import Detection, detect
from pedcal.detect.ground import FLOOR_MODES, FRAMES, GroundEstimate, detector_frame
from pedcal.detect.pointcloud_io import CloudRead, read_point_cloud_report
from pedcal.errors import PedcalInputError


@dataclass
class FileDetections:
    """What ``detect_file`` found and how it read the file."""

    detections: list[Detection]
    points: np.ndarray  # (N, 4) floor-referenced points the detector saw, in the sensor's body frame
    raw_points: np.ndarray  # (N, 4) the valid points in the file's frame
    floor_shift_m: float  # added to the file's z (under the sensor) to put the floor at z = 0
    read: CloudRead
    ground: GroundEstimate | None = None  # the local ground (``floor="auto"``)

    @property
    def warnings(self) -> list[str]:
        """The points dropped while reading (``CloudRead.summary``), then what the ground estimate
        found implausible (``pedcal.detect.ground``)."""
        summary = self.read.summary()
        return ([summary] if summary else []) + (list(self.ground.warnings) if self.ground is not None else [])


def detect_file(path: str | Path, model=None, *, sensor: str | None = None, sensor_pose: str | None = None,
                floor: str = "auto", frame: str = "body") -> FileDetections:
    """Detections in a .pcd/.ply/.bin/.npy file.

    The cloud is first thinned to the trained density when its sensor is denser
    (``pedcal.detect.sensors.normalize_density``; ``sensor`` names it, else its ray spacing is
    estimated). A cloud in a camera's optical frame (``frame="optical"``: x right, y down, z
    forward) is turned into the sensor's body frame (x forward, y left, z up), where detections are
    reported. Then the floor goes to z = 0 (``pedcal.detect.ground.detector_frame``): with
    ``sensor_pose`` ("x,y,z,roll,pitch,yaw" of the body frame, m and deg) the points are mapped
    into the base frame, whose z = 0 is the floor; otherwise ``floor`` "auto" subtracts the local
    ground height (``ground_referenced``: sloped streets, kerbs, ramps; stray returns below the
    road ignored; implausible ground logged), "plane" one RANSAC floor plane
    (``floor_referenced``), "none" takes the file's z as it is.
    """
    from pedcal.detect.sensors import normalize_density

    if floor not in FLOOR_MODES:
        raise PedcalInputError(f"--floor {floor!r}: expected one of {', '.join(FLOOR_MODES)}", column="floor")
    if frame not in FRAMES:
        raise PedcalInputError(f"--frame {frame!r}: expected one of {', '.join(FRAMES)}", column="frame")
    read = read_point_cloud_report(path)
    pts = normalize_density(read.points, sensor)
    prepared = detector_frame(pts, frame=frame, floor=floor, sensor_pose=sensor_pose)
    height = {} if prepared.sensor_height_m is None else dict(sensor_height_m=prepared.sensor_height_m)
    dets = detect(prepared.points, model, sensor=sensor, sensor_xy_m=prepared.sensor_xy_m, **height)
    return FileDetections(dets, prepared.points, read.points, prepared.floor_shift_m, read, prepared.ground)
