"""Discretised SE(3)-equivariant layers over the 60-element icosahedral group (EPN-style, pure PyTorch)."""

from .backbone import EquivariantBackbone
from .fast_ops import group_conv_fourier, reference_ops
from .group import (
    GROUP_SIZE,
    KERNEL_KINDS,
    cayley_table,
    element_orders,
    group_conv_index,
    group_neighbourhood,
    group_rotations,
    inverse_table,
    kernel_permutation,
    kernel_points,
    left_permutations,
    rotate_group_features,
    rotated_kernel_points,
    rotation_angles,
)
from .layers import SeparableConvBlock, group_conv, instance_norm, spatial_aggregate, spatial_aggregate_closed

__all__ = [
    "GROUP_SIZE",
    "KERNEL_KINDS",
    "EquivariantBackbone",
    "SeparableConvBlock",
    "cayley_table",
    "element_orders",
    "group_conv",
    "group_conv_fourier",
    "group_conv_index",
    "group_neighbourhood",
    "group_rotations",
    "instance_norm",
    "inverse_table",
    "kernel_permutation",
    "kernel_points",
    "left_permutations",
    "reference_ops",
    "rotate_group_features",
    "rotated_kernel_points",
    "rotation_angles",
    "spatial_aggregate",
    "spatial_aggregate_closed",
]
