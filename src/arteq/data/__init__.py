"""Body-scan data: pose sources, synthetic scans (noisy non-uniform clouds) and the LightningDataModule."""

from arteq.data.amass import AmassPoses, read_amass_npz
from arteq.data.datamodule import BodyScanDataModule, FpsCollate
from arteq.data.dataset import BodyScanDataset, EpochSampler, TensorDictDataset
from arteq.data.poses import (
    ID_FAMILIES,
    JOINT_LIMITS_DEG,
    PoseSource,
    SyntheticIDPoses,
    SyntheticOODPoses,
    measure_id_ood_gap,
    nearest_pose_distance,
)

__all__ = [
    "ID_FAMILIES",
    "JOINT_LIMITS_DEG",
    "AmassPoses",
    "BodyScanDataModule",
    "BodyScanDataset",
    "EpochSampler",
    "FpsCollate",
    "PoseSource",
    "SyntheticIDPoses",
    "SyntheticOODPoses",
    "TensorDictDataset",
    "measure_id_ood_gap",
    "nearest_pose_distance",
    "read_amass_npz",
]
