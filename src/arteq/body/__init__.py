"""Body models: SMPL-format LBS, SMPL/SMPL-H loaders and the free default body ``anny22``."""

from arteq.body.lbs import lbs, pose_features, skin
from arteq.body.model import BodyModel, BodyOutput, load_body_model
from arteq.body.smpl_io import BodyModelFileError, SafeModelUnpickler, read_model_file, to_body22

__all__ = [
    "BodyModel",
    "BodyModelFileError",
    "BodyOutput",
    "SafeModelUnpickler",
    "lbs",
    "load_body_model",
    "pose_features",
    "read_model_file",
    "skin",
    "to_body22",
]
