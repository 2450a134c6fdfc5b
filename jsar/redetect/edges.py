"""Edge magnitude and orientation maps for EdgeBoxes (cv2.ximgproc).

Without the original's structured-edge forest the default map is built from smoothed gradients: Gaussian
smoothing, Sobel derivatives per colour channel, the strongest channel per pixel, magnitude normalised to
0..1 by its maximum over the given image, thinned by non-maximum suppression across the edge. With a
structured-edge model file (`StructuredEdges`), OpenCV's detector is used instead.

Conventions (`cv2.ximgproc.StructuredEdgeDetection.computeOrientation`'s, which EdgeBoxes expects): both
maps float32 HxW; orientation is the angle of the edge NORMAL (the gradient direction) in radians in
[0, pi), from +x (right) towards +y (down): a vertical step edge has 0, a horizontal one pi/2.
"""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np


def _as_float_channels(image: np.ndarray) -> np.ndarray:
    """uint8/float HxW or HxWx3 -> float32 HxWxC (C = 1 or 3), values unchanged (0..255 for uint8)."""
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3 or image.shape[2] not in (1, 3):
        raise ValueError(f"edge maps need an HxW or HxWx3 image, got shape {image.shape}")
    if image.shape[0] < 3 or image.shape[1] < 3:
        raise ValueError(f"edge maps need an image of at least 3x3 pixels, got shape {image.shape}")
    return image.astype(np.float32, copy=False)


def gradient_edges(image: np.ndarray, sigma: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Image HxW[x3] -> (magnitude float32 HxW in 0..1, orientation float32 HxW radians in [0, pi)).

    Gaussian (sigma in pixels) then 3x3 Sobel per channel; per pixel the channel with the largest
    gradient wins (so colour edges between equally bright regions count). Magnitude is divided by its
    maximum over the image: EdgeBoxes' thresholds (edgeMinMag 0.1, clusterMinMag 0.5) assume 0..1.
    A flat image gives all-zero maps.
    """
    if not sigma > 0:
        raise ValueError(f"edge smoothing sigma must be > 0 pixels, got {sigma}")
    channels = _as_float_channels(image)
    smoothed = cv2.GaussianBlur(channels, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REPLICATE)
    if smoothed.ndim == 2:
        smoothed = smoothed[:, :, None]
    gx = cv2.Sobel(smoothed, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(smoothed, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    if gx.ndim == 2:
        gx, gy = gx[:, :, None], gy[:, :, None]
    energy = gx * gx + gy * gy
    if energy.shape[2] == 1:
        best_energy, best_gx, best_gy = energy[:, :, 0], gx[:, :, 0], gy[:, :, 0]
    else:
        strongest = np.argmax(energy, axis=2)[:, :, None]
        best_energy = np.take_along_axis(energy, strongest, axis=2)[:, :, 0]
        best_gx = np.take_along_axis(gx, strongest, axis=2)[:, :, 0]
        best_gy = np.take_along_axis(gy, strongest, axis=2)[:, :, 0]
    magnitude = np.sqrt(best_energy)
    peak = float(magnitude.max())
    if peak > 0:
        magnitude *= 1.0 / peak
    orientation = np.arctan2(best_gy, best_gx)
    # Fold the gradient direction onto [0, pi): EdgeBoxes compares orientations modulo pi.
    orientation = np.where(orientation < 0, orientation + np.float32(math.pi), orientation)
    orientation[orientation >= np.float32(math.pi)] = 0.0
    return magnitude.astype(np.float32, copy=False), orientation.astype(np.float32, copy=False)


def non_maximum_suppression(magnitude: np.ndarray, orientation: np.ndarray, radius: int = 1) -> np.ndarray:
    """Thin edges: zero each pixel that is smaller than its neighbours at +-1..radius px along the normal.

    magnitude, orientation: float32 HxW (orientation = normal angle in radians, the module's
    convention). Neighbours are read with bilinear interpolation and border replication. Returns a new
    float32 HxW map; ties are kept (a plateau survives), so a one-pixel line is never erased.
    """
    if magnitude.shape != orientation.shape or magnitude.ndim != 2:
        raise ValueError(f"magnitude {magnitude.shape} and orientation {orientation.shape} must be equal HxW")
    if radius < 1:
        raise ValueError(f"NMS radius must be >= 1 pixel, got {radius}")
    magnitude = magnitude.astype(np.float32, copy=False)
    height, width = magnitude.shape
    cols, rows = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    normal_x = np.cos(orientation).astype(np.float32)
    normal_y = np.sin(orientation).astype(np.float32)
    keep = np.ones(magnitude.shape, dtype=bool)
    for step in range(1, radius + 1):
        for sign in (1.0, -1.0):
            neighbour = cv2.remap(
                magnitude,
                cols + np.float32(sign * step) * normal_x,
                rows + np.float32(sign * step) * normal_y,
                interpolation=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REPLICATE,
            )
            keep &= magnitude >= neighbour
    return np.where(keep, magnitude, np.float32(0.0)).astype(np.float32, copy=False)


def edge_maps(image: np.ndarray, sigma: float = 2.0, nms_radius: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Image HxW[x3] -> (thinned magnitude 0..1, orientation radians [0, pi)), float32 HxW, for EdgeBoxes."""
    magnitude, orientation = gradient_edges(image, sigma)
    return non_maximum_suppression(magnitude, orientation, nms_radius), orientation


class StructuredEdges:
    """Adapter over OpenCV's structured-edge forest (`createStructuredEdgeDetection(model_file)`).

    Same output convention as `edge_maps`. Raises FileNotFoundError naming the file when it is absent,
    ValueError when OpenCV cannot read it.
    """

    def __init__(self, model_file: str | Path, nms_radius: int = 2) -> None:
        path = Path(model_file)
        if not path.is_file():
            raise FileNotFoundError(f"structured-edge model file not found: {path}")
        try:
            self._detector = cv2.ximgproc.createStructuredEdgeDetection(str(path))
        except cv2.error as exc:
            raise ValueError(f"OpenCV could not load the structured-edge model {path}: {exc}") from exc
        self._nms_radius = nms_radius

    def __call__(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Image HxW[x3] uint8 (BGR) -> (thinned edge probability 0..1, orientation radians [0, pi))."""
        channels = _as_float_channels(image)
        if channels.shape[2] == 1:
            channels = np.repeat(channels, 3, axis=2)
        rgb = cv2.cvtColor(channels, cv2.COLOR_BGR2RGB)
        if image.dtype == np.uint8:
            rgb *= 1.0 / 255.0
        edges = self._detector.detectEdges(np.ascontiguousarray(rgb))
        orientation = self._detector.computeOrientation(edges)
        thinned = self._detector.edgesNms(edges, orientation, r=self._nms_radius, s=0, m=1.0)
        return thinned.astype(np.float32, copy=False), orientation.astype(np.float32, copy=False)
