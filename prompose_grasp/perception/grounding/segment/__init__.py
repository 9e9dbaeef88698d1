"""Object candidates above the support plane: graph clustering on a pixel grid, then full-resolution masks.

Clustering works on every `segment_stride_px`-th pixel. Two 4-neighbours on that grid join when both are
above the plane, their 3D distance is small for their depth (the sensor's noise plus the spacing a steep
surface shows) and their colours are close (a colour edge splits touching objects of different colour).
Tiny segments (specular highlights, speckle) merge into the segment they touch geometrically, or vanish.
Each segment is then painted at full resolution: the pixels of its grid cells that are above the plane,
grown by the grid spacing into above-plane pixels, plus pixels without depth (occlusion shadows, holes)
around it whose colour matches it.

Modules, in the order `segment_objects` (`core`) runs them: `cells` (which grid cells stand on the support),
`cluster` (the grid graph and small segments), `walls` (background segments), `join` (surfaces of one object
joined), `masks` (full-resolution masks).
"""

from prompose_grasp.perception.grounding.segment.cells import concave_creases, lab_image
from prompose_grasp.perception.grounding.segment.core import segment_objects
from prompose_grasp.perception.grounding.segment.masks import Segment

__all__ = ["Segment", "concave_creases", "lab_image", "segment_objects"]
