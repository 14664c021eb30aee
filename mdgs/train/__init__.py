"""Training of any learned model of the registry on the HDF5 datasets (``mdgs train``).

:func:`train` is generic over the :class:`~mdgs.models.base.Simulator` contract; see
:mod:`mdgs.train.loop` and, for the run folder, :mod:`mdgs.runs`.
"""

from mdgs.train.loop import TrainConfig, TrainingError, train

__all__ = ["TrainConfig", "TrainingError", "train"]
