"""Person detection in 3-D point clouds: point-cloud files, segmentation, Kidono features, RealAdaBoost,
training and the ``pedcal detect`` / ``detect-eval`` / ``train-detector`` commands."""
