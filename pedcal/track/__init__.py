"""Detection and tracking of people from a robot with 3D LIDAR and an ESPAR antenna (Misu and
Miura's method and pedcal's factor-graph tracker beside it).

- :mod:`pedcal.track.detection`: segment a LIDAR frame into clusters and score them with the
  RealAdaBoost person classifier (:func:`pedcal.track.detection.detect`); features in
  :mod:`~pedcal.track.features`, the classifier in :mod:`~pedcal.track.adaboost`, training in
  :mod:`~pedcal.track.train`, point-cloud files in :mod:`~pedcal.track.pointcloud_io`
- :mod:`pedcal.track.tracker`: the trackers (``paper``, ``lidar-only``, ``factorgraph``) that keep
  the target's identity, with the Kalman filters of :mod:`~pedcal.track.kalman`, the ESPAR bearing
  model of :mod:`~pedcal.track.espar`, appearance in :mod:`~pedcal.track.appearance` and the
  search after a loss in :mod:`~pedcal.track.recovery` / :mod:`~pedcal.track.grid_belief`
- :mod:`pedcal.track.follow`: run a tracker on a following episode and score it
  (:func:`pedcal.track.follow.run_follow`, also ``pedcal.follow``)

Submodules are imported on use; this package itself imports nothing.
"""
