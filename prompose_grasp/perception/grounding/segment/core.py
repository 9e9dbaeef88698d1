"""`segment_objects`: object candidates above the support plane, as a sequence of the package's steps."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from prompose_grasp.perception.grounding.segment.cells import _foreground, lab_image
from prompose_grasp.perception.grounding.segment.cluster import _grid_labels, _merge_small
from prompose_grasp.perception.grounding.segment.join import _join_hinged, _join_surfaces
from prompose_grasp.perception.grounding.segment.masks import Segment, _GridLabels, _paint_segments
from prompose_grasp.perception.grounding.segment.stacks import _split_stacked
from prompose_grasp.perception.grounding.segment.walls import _split_and_drop_walls
from prompose_grasp.perception.grounding.types import GroundingConfig, SupportPlane

__all__ = ["segment_objects"]


def segment_objects(
    rgb: np.ndarray,
    point_map: np.ndarray,
    f_px: float,
    plane: SupportPlane | None,
    config: GroundingConfig,
    support_hull: np.ndarray | None = None,
    plane_coords: Callable[[np.ndarray], np.ndarray] | None = None,
) -> list[Segment]:
    """Object candidates in an RGB-D frame.

    Args:
        rgb: (H, W, 3) uint8 colour image.
        point_map: (H, W, 3) float64 camera-frame points [m], NaN where there is no depth.
        f_px: mean focal length [px] (sets the expected spacing of neighbouring points).
        plane: the support plane (objects are above it), or None (every valid pixel is a candidate point).
        config: thresholds.
        support_hull: optional (M, 2) float32 polygon in plane (right, forward) coordinates; segments whose
            footprint centre lies outside it (by more than 5 cm) stand on something else and are dropped.
        plane_coords: callable (N, 3) points -> (N, 3) plane coordinates, needed with `support_hull`.

    Returns:
        Segments in raster order of their first grid cell.
    """
    s = config.segment_stride_px
    Pg = np.ascontiguousarray(point_map[::s, ::s])
    h, w = Pg.shape[:2]
    # colours of the grid cells: the s x s block means (less read noise than single pixels)
    small_rgb = cv2.resize(rgb[: h * s, : w * s], (w, h), interpolation=cv2.INTER_AREA) if s > 1 else rgb
    lab_g = lab_image(small_rgb[:h, :w])
    min_cells = max(1, int(np.ceil(config.min_segment_px / (s * s))))
    fg, flat_labels = _foreground(Pg, lab_g, plane, config)
    flat = flat_labels >= 0

    labels, geo = _grid_labels(Pg, lab_g, fg, f_px, s, config)
    heights = None
    if plane is not None:
        with np.errstate(invalid="ignore"):
            heights = np.nan_to_num(Pg @ plane.normal_cam + plane.offset_m, nan=-1.0)
    # cells of attached fragments: painted into their body's mask (the fit sees the handle), but left out of
    # the points that describe the body (footprint and shape family: a box's own stray cells at its far top
    # edge turned it "cylindrical" in a closed-loop episode, tabletop seed 739)
    labels, fragment = _merge_small(labels, geo, min_cells, Pg, heights)
    if np.any(flat):  # each flat object is one segment (`cells._flat_objects`)
        labels = np.where(flat, flat_labels + int(labels.max()) + 1, labels)
        _, relabel = np.unique(labels, return_inverse=True)
        labels = relabel.reshape(labels.shape) - (1 if np.any(labels < 0) else 0)

    if plane is not None:
        labels, background = _split_and_drop_walls(labels, Pg, lab_g, f_px, s, plane, config, min_cells)
    else:
        background = np.zeros(labels.shape, dtype=bool)
    labels = _join_surfaces(labels, Pg, lab_g, plane_coords if plane is not None else None, config)
    base = np.zeros(int(labels.max()) + 1)  # what each segment stands on [m above the plane]
    if plane_coords is not None:
        labels = _join_hinged(labels, Pg, plane_coords, lab_g, config)
        if plane is not None:
            labels, base = _split_stacked(labels, Pg, plane, plane_coords, config, min_cells)
    if int(labels.max()) + 1 == 0:
        return []

    grid = _GridLabels(labels, fragment, flat, background, base)
    return _paint_segments(rgb, point_map, Pg, lab_g, grid, plane, config, support_hull, plane_coords, f_px)
