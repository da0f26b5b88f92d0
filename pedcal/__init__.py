"""pedcal: factor-graph calibration of ceiling depth-sensor networks with a localized robot,
and detection and tracking of a specific person with 3D LIDAR and an ESPAR antenna.

Public entry points (each CLI command is one of these):
    pedcal.io.read_log / write_log / read_sensors_yaml / write_sensors_yaml
    pedcal.sim.simulate
    pedcal.calib.calibrate
    pedcal.metrics.evaluate
"""

__version__ = "0.1.0"
