"""Core of nrmpc_ros: rig, deformation model, residuals, solvers and estimators (no rclpy here)."""

from .deformation import (
    deformed_extrinsics,
    gravity_from_accelerometer,
    gravity_from_camera,
    plucker_lines,
    rays,
)
from .estimators import METHODS, Estimate, EstimateInfo, EstimatorOptions, estimate
from .matches import Matches, load_matches, save_matches
from .metrics import pose_errors
from .residuals import generalized_epipolar_residuals, two_view_angular_errors
from .rig import Camera, ImuMount, Rig, load_rig, rig_from_dict, save_rig

__all__ = [
    "METHODS", "Camera", "Estimate", "EstimateInfo", "EstimatorOptions", "ImuMount", "Matches", "Rig",
    "deformed_extrinsics", "estimate", "generalized_epipolar_residuals", "gravity_from_accelerometer",
    "gravity_from_camera", "load_matches", "load_rig", "plucker_lines", "pose_errors", "rays", "rig_from_dict",
    "save_matches", "save_rig", "two_view_angular_errors",
]
