"""Sparse class ids (clicks, scribbles) grown over the image regions they fall in, before a field propagates them.

A click labels one pixel; the region of uniform colour around it is, far more often than not, the same thing. Each
segment of OpenCV's graph-based segmentation (Felzenszwalb and Huttenlocher) of the frame's image that holds labelled
pixels of a single class takes that class; segments holding two classes, or none, keep their pixels as they were.
"""

from __future__ import annotations

import cv2
import numpy as np
from jaxtyping import UInt8

from ssnerf_method.label_makers.encoding import SEMANTIC_IGNORE

SEGMENT_SCALE = 300.0
"""The segmentation's scale (its k) that `ssnerf-study propagation` grows clicks with: on the benchmark's 128x96
frames, one click per class per frame grows to about a fifth of the pixels, 91-93% of them the right class."""
SEGMENT_SIGMA = 0.5
"""Gaussian blur (pixels) of the image before it is segmented (the segmentation's own default)."""
SEGMENT_MIN_SIZE = 20
"""Smallest segment (pixels); smaller ones merge into a neighbour."""


def image_segments(image: UInt8[np.ndarray, "h w 3"], scale: float) -> np.ndarray:
    """(H, W) segment ids of `image`; larger `scale` (the method's k) makes larger segments."""
    segmentation = cv2.ximgproc.segmentation.createGraphSegmentation(sigma=SEGMENT_SIGMA, k=float(scale),
                                                                      min_size=SEGMENT_MIN_SIZE)
    return segmentation.processImage(np.ascontiguousarray(image[..., :3]))


def grow_in_segments(
    class_ids: np.ndarray, image: UInt8[np.ndarray, "h w 3"], scale: float
) -> np.ndarray:
    """`class_ids` (H, W; `SEMANTIC_IGNORE` = unlabelled) with every image segment that holds labelled pixels of one
    class only filled with it. Labelled pixels never change; a segment where two classes meet stays as it was."""
    segments = image_segments(image, scale).reshape(-1)
    flat = class_ids.reshape(-1)
    labelled = flat != SEMANTIC_IGNORE
    grown = flat.copy()
    if not labelled.any():
        return grown.reshape(class_ids.shape)
    pairs = np.unique(np.stack([segments[labelled], flat[labelled].astype(np.int64)]), axis=1)  # (segment, class)
    segment_ids, counts = np.unique(pairs[0], return_counts=True)
    one_class = np.isin(pairs[0], segment_ids[counts == 1])
    class_of = np.full(int(segments.max()) + 1, -1, dtype=np.int64)
    class_of[pairs[0][one_class]] = pairs[1][one_class]
    fill = ~labelled & (class_of[segments] >= 0)
    grown[fill] = class_of[segments[fill]]
    return grown.reshape(class_ids.shape)
