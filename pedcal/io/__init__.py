"""Readers and writers: log directories (LOG_FORMAT.md), sensors YAML, people CSV.

ROS bags and ``rostopic echo -p`` CSV live in :mod:`pedcal.io.ros`, recorded pedestrian datasets
in :mod:`pedcal.io.pedestrians`, occupancy maps in :mod:`pedcal.io.maps`; all convert to the same
model, never a second code path.
"""

from pedcal.io.logdir import read_log, validate, write_log
from pedcal.io.people import read_people_csv, write_people_csv
from pedcal.io.sensors_yaml import read_sensors_yaml, write_sensors_yaml

__all__ = ["read_log", "write_log", "validate", "read_sensors_yaml", "write_sensors_yaml", "read_people_csv",
           "write_people_csv"]
