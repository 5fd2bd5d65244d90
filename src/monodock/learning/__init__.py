"""From recordings to a model bundle: LiDAR labels, the dataset, the seven regressors, ONNX export, the fusion
tables."""

from __future__ import annotations

from typing import TYPE_CHECKING

from monodock.core.face import lazy_face

if TYPE_CHECKING:
    from monodock.learning.dataset import Dataset, label_recording, read_dataset, write_dataset
    from monodock.learning.pipeline import TrainOptions, train_bundle
    from monodock.learning.train import TrainingResult

__all__ = [
    "Dataset",
    "TrainOptions",
    "TrainingResult",
    "label_recording",
    "read_dataset",
    "train_bundle",
    "write_dataset",
]

__getattr__, __dir__ = lazy_face(__name__, __all__)
