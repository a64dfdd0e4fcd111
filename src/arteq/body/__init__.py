"""Body models: SMPL-format LBS, SMPL/SMPL-H loaders, the free bodies ``anny22`` (default) and
``anny_allages``, and :func:`create_body`, the one factory every command uses."""

from arteq.body.factory import create_body
from arteq.body.lbs import lbs, pose_features, shape_blend, skin
from arteq.body.model import BodyModel, BodyOutput, load_body_model
from arteq.body.smpl_io import BodyModelFileError, SafeModelUnpickler, read_model_file, to_body22

__all__ = [
    "BodyModel",
    "BodyModelFileError",
    "BodyOutput",
    "SafeModelUnpickler",
    "create_body",
    "lbs",
    "load_body_model",
    "pose_features",
    "read_model_file",
    "shape_blend",
    "skin",
    "to_body22",
]
