"""People in a point-cloud file: read, thinned to the trained density, floor at z = 0, detected.

Below both ``pedcal detect`` (pedcal.detect.detect_cli) and the real-frame evaluation
(pedcal.detect.real_eval), which use it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedcal.detect.detection import Detection, detect
from pedcal.detect.pointcloud_io import CloudRead, floor_referenced, ground_referenced, read_point_cloud_report
from pedcal.errors import PedcalInputError


@dataclass
class FileDetections:
    """What ``detect_file`` found and how it read the file."""

    detections: list[Detection]
    points: np.ndarray  # (N, 4) floor-referenced points the detector saw
    raw_points: np.ndarray  # (N, 4) the valid points in the file's frame
    floor_shift_m: float  # added to the file's z to put the floor at z = 0
    read: CloudRead


FLOOR_MODES = ("auto", "plane", "none")


def detect_file(path: str | Path, model=None, *, sensor: str | None = None, sensor_pose: str | None = None,
                floor: str = "auto") -> FileDetections:
    """Detections in a .pcd/.ply/.bin/.npy file.

    The cloud is first thinned to the trained density when its sensor is denser
    (``pedcal.detect.sensors.normalize_density``; ``sensor`` names it, else its ray spacing is
    estimated). Then the floor goes to z = 0: with ``sensor_pose`` ("x,y,z,roll,pitch,yaw", m and
    deg) the points are mapped into the base frame, whose z = 0 is the floor; otherwise ``floor``
    "auto" subtracts the local ground height (``ground_referenced``: sloped streets, kerbs),
    "plane" one RANSAC floor plane (``floor_referenced``), "none" takes the file's z as it is.
    """
    from pedcal.detect.sensors import normalize_density, parse_sensor_pose, to_base_frame

    if floor not in FLOOR_MODES:
        raise PedcalInputError(f"--floor {floor!r}: expected one of {', '.join(FLOOR_MODES)}", column="floor")
    read = read_point_cloud_report(path)
    pts = normalize_density(read.points, sensor)
    height = {}  # the sensor's height above the floor, where known
    if sensor_pose is not None:
        position_m, ypr_deg = parse_sensor_pose(sensor_pose)
        pts, dz = to_base_frame(pts, position_m, ypr_deg), float(position_m[2])
        height = dict(sensor_height_m=dz, sensor_xy_m=(float(position_m[0]), float(position_m[1])))
    elif floor in ("auto", "plane"):
        pts, dz = ground_referenced(pts) if floor == "auto" else floor_referenced(pts)
        height = dict(sensor_height_m=dz) if dz > 0 else {}
    else:
        dz = 0.0
    dets = detect(pts, model, sensor=sensor, **height)
    return FileDetections(dets, pts, read.points, dz, read)
