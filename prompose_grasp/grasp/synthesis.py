"""Grasp synthesis: all candidates of the gripper's kind, from the grasp families of its type.

Parallel jaw (`parallel_jaw`): analytic grasps on the 9-DoF box, antipodal pairs on the scaled mesh, grasps
across a container's rim, and for a target whose box is wider than the stroke, section grasps on its seen
surface (`surface`). Suction cup (`suction`): grasps on the box's faces where the cup seals. Each family
returns a `Candidates` batch (`candidates`); `generate_candidates` joins them and keeps the best
`GraspConfig.max_candidates`.
"""

from __future__ import annotations

import numpy as np

from prompose_grasp.grasp.candidates import Candidates
from prompose_grasp.grasp.grippers import ParallelJawGeometry, SuctionCupGeometry
from prompose_grasp.grasp.parallel_jaw import antipodal_grasps, box_grasps, rim_grasps
from prompose_grasp.grasp.suction import suction_grasps
from prompose_grasp.grasp.surface import needs_sections, section_grasps
from prompose_grasp.grasp.types import GraspConfig, ObjectModel, Plane

__all__ = ["generate_candidates"]


def generate_candidates(
    target: ObjectModel,
    gripper: ParallelJawGeometry | SuctionCupGeometry,
    config: GraspConfig,
    support: Plane | None = None,
) -> Candidates:
    """All candidates of the gripper's kind, capped at `config.max_candidates` (unrejected, best first)."""
    if isinstance(gripper, ParallelJawGeometry):
        parts = [
            box_grasps(target, gripper, config, support),
            antipodal_grasps(target, gripper, config, support),
            rim_grasps(target, gripper, config, support),
        ]
        if needs_sections(target, gripper, config):  # the box is wider than the stroke: its narrow parts
            parts.append(section_grasps(target, gripper, config, support))
        cands = Candidates.concat(parts)
    else:
        cands = suction_grasps(target, gripper, config, support)
    if len(cands) > config.max_candidates:
        order = np.lexsort((-cands.quality, cands.pre_rejected != ""))
        cands = cands.take(order[: config.max_candidates])
    return cands
