"""One camera's two views: the essential matrix of bearing pairs, for the front end's match check and the
per-camera rotations that start the gravity search (:mod:`nrmpc_ros.core.gravity_init`).

OpenCV's 5-point solver works on normalised image coordinates x = f_xy / f_z, so only bearings in front of
the camera take part. A bearing's angular error e appears there as about e / f_z^2: at ``MIN_BEARING_Z``
(0.05, about 87 deg off the optical axis) it is magnified 400 times, so a bearing farther out passes a
threshold set for the image centre only with an error hundreds of times smaller than the others': it adds
next to nothing and can only mislead the fit. Only fisheye cameras see that far. The same cut serves every
solver fed normalised coordinates (the resection's too).
"""

from __future__ import annotations

import cv2
import numpy as np

MIN_BEARING_Z = 0.05  # bearings with z at or below this (more than ~87 deg off the optical axis) are left out
# OpenCV's USAC, not its plain RANSAC, for every essential matrix: USAC ends with a local optimisation over
# the inliers, RANSAC returns the matrix of a minimal sample. Measured on synthetic rigs (3 and 4 cameras,
# 0.5 px noise, 10 % outliers) the per-camera rotations were 0.07 deg off (median; 0.30 at most) against
# 0.53 (2.0) with RANSAC, and on 200 noisy pairs with 20 % outliers it found 98 % of the inliers against
# 93 %, in less time. On the holds benchmark's cells the front end's links and the 4pt-bending results stay
# as they were (the match check always used USAC), and on the rendered three-camera rig with a fisheye, where
# USAC once put narrow cameras' rotations 8-15 deg off, the 6pt-bending gravity error stays as with RANSAC.
METHOD = cv2.USAC_DEFAULT


def in_front(f1: np.ndarray, f2: np.ndarray) -> np.ndarray:
    """Mask of the bearing pairs (N, 3) both of which are usable in normalised coordinates."""
    return (f1[:, 2] > MIN_BEARING_Z) & (f2[:, 2] > MIN_BEARING_Z)


def essential_matrix(f1: np.ndarray, f2: np.ndarray, threshold_rad: float, confidence: float = 0.999):
    """Essential matrix of bearing pairs (f1, f2) of one camera ((N, 3) each, all in front, at least
    five) by ``METHOD`` at ``threshold_rad`` (Sampson distance in normalised coordinates): (E, inlier
    mask (N,), x1, x2) with x1, x2 the normalised coordinates, or None when no matrix was found.

    E maps view 1 to view 2 in OpenCV's convention (x2^T E x1 = 0); on degenerate samples OpenCV may stack
    several 3x3 solutions.
    """
    x1 = f1[:, :2] / f1[:, 2:3]
    x2 = f2[:, :2] / f2[:, 2:3]
    E, mask = cv2.findEssentialMat(x1, x2, np.eye(3), method=METHOD, prob=confidence, threshold=threshold_rad)
    if E is None or mask is None:
        return None
    return E, mask.ravel()[: len(f1)] > 0, x1, x2


__all__ = ["MIN_BEARING_Z", "METHOD", "essential_matrix", "in_front"]
