"""Tracking a specific person from a robot with 3D LIDAR and an ESPAR antenna (Misu and Miura's
method and pedcal's factor-graph tracker beside it). The person detector that feeds them lives in
:mod:`pedcal.detect`.

- :mod:`pedcal.track.tracker`: the trackers (``paper``, ``lidar-only``, ``factorgraph``) that keep
  the target's identity, with the Kalman filters of :mod:`~pedcal.track.kalman`, the ESPAR bearing
  model of :mod:`~pedcal.track.espar`, appearance in :mod:`~pedcal.track.appearance` and the
  search after a loss in :mod:`~pedcal.track.recovery` / :mod:`~pedcal.track.grid_belief`
- :mod:`pedcal.track.follow`: run a tracker on a following episode and score it
  (:func:`pedcal.track.follow.run_follow`, also ``pedcal.follow``); :mod:`pedcal.track.follow_bench`
  runs every long-present person of the real recordings as the target

Submodules are imported on use; this package itself imports nothing.
"""
