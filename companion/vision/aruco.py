"""The pad's pose from its ArUco board (sitl/pad_marker.py), for precision landing.

Why a second detector: the colour detector gives a pixel position and a radius, which is what the
paper's policy observes; an autopilot's precision landing wants the target's position in metres.
A marker board gives that directly: each decoded marker's four corners are known points of the
pad, so one ``cv2.solvePnP`` over all decoded corners gives the pad's pose in the camera frame
with the camera's intrinsics (our renderer's: ``sitl.camera.camera_matrix``).

Camera frame: OpenCV's, x right in the image, y down in the image, z along the optical axis.
Stateless: each frame is judged alone, as the colour detector's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from sitl import pad_marker

_MIN_POINTS = 4  # one whole marker


@dataclass(frozen=True)
class PadPose:
    """The pad seen in one image: its centre and orientation in the camera frame.

    ``rotation_cam_pad`` turns pad-frame vectors (north, east, down of the roof) into camera-frame
    ones; ``corners_px`` are every decoded corner (for the target's angular size)."""

    position_cam_m: tuple[float, float, float]
    rotation_cam_pad: tuple[tuple[float, ...], ...]
    marker_ids: tuple[int, ...]
    corners_px: tuple[tuple[float, float], ...]
    reprojection_px: float

    def __post_init__(self) -> None:
        values = [*self.position_cam_m, *np.ravel(self.rotation_cam_pad), *np.ravel(self.corners_px), self.reprojection_px]
        if not all(math.isfinite(float(v)) for v in values):
            raise ValueError(f"pad pose must be finite, got {self}")
        if self.position_cam_m[2] <= 0:
            raise ValueError(f"the pad must be in front of the camera (z > 0), got z = {self.position_cam_m[2]}")
        if not self.marker_ids:
            raise ValueError("a pad pose needs at least one decoded marker")

    @property
    def rotation(self) -> np.ndarray:
        return np.array(self.rotation_cam_pad, dtype=float)


class ArucoPadDetector:
    """Decodes the board's markers and solves for the pad's pose in one grey image."""

    def __init__(self, camera_matrix: np.ndarray, image_size_px: tuple[int, int],
                 distortion: np.ndarray | None = None, board: str = "aruco") -> None:
        """``board``: which of sitl/pad_marker.py's boards the pad carries (``[sitl.camera]
        pad_marker``); its markers' ids differ from the other's, so the wrong one reads nothing."""
        k = np.asarray(camera_matrix, dtype=float)
        if k.shape != (3, 3) or not np.isfinite(k).all() or k[0, 0] <= 0 or k[1, 1] <= 0:
            raise ValueError(f"camera_matrix must be a finite 3x3 pinhole matrix with positive focal lengths, got {k}")
        self.camera_matrix = k
        self.image_size_px = (int(image_size_px[0]), int(image_size_px[1]))
        self.distortion = np.zeros(5) if distortion is None else np.asarray(distortion, dtype=float)
        self.board = pad_marker.board(board)
        self._known = frozenset(m.marker_id for m in pad_marker.markers(board))
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX  # sub-pixel corners: cm at 3 m
        params.minMarkerPerimeterRate = 0.03  # about 10 px around at 320 px: the smallest readable
        self._detector = cv2.aruco.ArucoDetector(pad_marker.dictionary(), params)

    def detect(self, image_bgr: np.ndarray) -> PadPose | None:
        """The pad's pose, or None when no marker of the board is decoded (or the pose fails)."""
        if image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
            raise ValueError(f"expected an HxWx3 uint8 BGR image, got {image_bgr.dtype} {image_bgr.shape}")
        size = (image_bgr.shape[1], image_bgr.shape[0])
        if size != self.image_size_px:
            raise ValueError(f"image is {size[0]}x{size[1]} px, the intrinsics are for "
                             f"{self.image_size_px[0]}x{self.image_size_px[1]}; give the detector this camera's matrix")
        grey = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
        corners, ids, _ = self._detector.detectMarkers(grey)
        if ids is None or len(ids) == 0:
            return None
        obj, img = self.board.matchImagePoints(corners, ids)
        if obj is None or len(obj) < _MIN_POINTS:
            return None
        return self._solve(obj.reshape(-1, 3), img.reshape(-1, 2), ids.ravel())

    def _solve(self, obj: np.ndarray, img: np.ndarray, ids: np.ndarray) -> PadPose | None:
        """PnP over every decoded corner: IPPE for one planar marker (its two-fold ambiguity is
        resolved by reprojection), SQPnP for more, then Levenberg-Marquardt refinement."""
        flags = cv2.SOLVEPNP_IPPE if len(obj) == _MIN_POINTS else cv2.SOLVEPNP_SQPNP
        ok, rvec, tvec = cv2.solvePnP(obj, img, self.camera_matrix, self.distortion, flags=flags)
        if not ok:
            return None
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, self.camera_matrix, self.distortion, rvec, tvec)
        projected, _ = cv2.projectPoints(obj, rvec, tvec, self.camera_matrix, self.distortion)
        error = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - img) ** 2, axis=1))))
        rotation, _ = cv2.Rodrigues(rvec)
        t = tvec.ravel()
        if not (np.isfinite(t).all() and np.isfinite(rotation).all()) or t[2] <= 0:
            return None
        return PadPose(
            position_cam_m=(float(t[0]), float(t[1]), float(t[2])),
            rotation_cam_pad=tuple(tuple(float(v) for v in row) for row in rotation),
            marker_ids=tuple(sorted(int(i) for i in ids if int(i) in self._known)),
            corners_px=tuple((float(u), float(v)) for u, v in img),
            reprojection_px=error,
        )
