"""Datasets of the MDGS scenes: recording, file format, generation (paper section 4.1).

Public API:

- :func:`generate`, :class:`GenerateConfig` (``mdgs generate``), :data:`PRESETS`;
- :func:`open_dataset`, :class:`Dataset`, :class:`DatasetError` (reading, checked);
- :func:`model_from_dataset` (the dataset's MuJoCo model, rebuilt from the file alone);
- :data:`SCHEMA_VERSION`, :data:`FRAME_ARRAYS`, :data:`STATIC_ARRAYS` (the format);
- :func:`load_scene`, :func:`simulate` (trajectories in memory, no files).
"""

from mdgs.data.engine import load_scene, simulate
from mdgs.data.generate import GenerateConfig, GenerateResult, generate
from mdgs.data.io import Dataset, model_from_dataset, open_dataset
from mdgs.data.presets import PRESETS, Preset
from mdgs.data.schema import FRAME_ARRAYS, SCHEMA_VERSION, STATIC_ARRAYS, DatasetError

__all__ = [
    "GenerateConfig",
    "GenerateResult",
    "generate",
    "Dataset",
    "open_dataset",
    "model_from_dataset",
    "DatasetError",
    "PRESETS",
    "Preset",
    "SCHEMA_VERSION",
    "FRAME_ARRAYS",
    "STATIC_ARRAYS",
    "load_scene",
    "simulate",
]
