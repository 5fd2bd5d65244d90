"""From recordings to a model bundle: LiDAR labels, the dataset, the seven regressors, ONNX export, the fusion
tables."""
