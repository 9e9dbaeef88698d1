"""Ground: the place phrase of a command that names no fixture of the cell ("in the white bowl", "on the tea
box"), found in the image like the object and turned into a place target (`grasp.place_targets`)."""

from __future__ import annotations

from typing import cast

import numpy as np

from prompose_grasp.errors import AmbiguousObjectError, InvalidInputError, ObjectNotFoundError
from prompose_grasp.grasp.place import PlaceTarget
from prompose_grasp.grasp.place_targets import CONTAINERS, place_target_on
from prompose_grasp.pipeline.command import Command
from prompose_grasp.pipeline.describe import describe_contenders
from prompose_grasp.pipeline.loop import Loop
from prompose_grasp.pipeline.observe import Observation, to_base
from prompose_grasp.pipeline.record import Abort, RunRecord
from prompose_grasp.pipeline.seams import ObjectEstimate
from prompose_grasp.robot.interfaces import RGBDFrame

__all__ = ["ground_place_target"]

#: A place object whose centre is this close to the object to pick is that object itself [m].
_SAME_OBJECT_M = 0.02


def ground_place_target(
    loop: Loop, run: RunRecord, cmd: Command, frame: RGBDFrame, obs: Observation
) -> PlaceTarget:
    """The object the target phrase names, grounded in `frame`, as a place target: a bin when the command
    says "in" or the object is a container (bowl, cup, mug, bin, basket), else the surface of its top."""
    prompt = cmd.target_prompt
    with run.timed("estimate"):
        try:
            est = loop.estimator.estimate(frame, prompt)
        except AmbiguousObjectError as exc:
            T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
            fit = cast("tuple[ObjectEstimate, ...]", exc.estimates)  # the estimator's own estimates
            text = describe_contenders(prompt, fit, T_base_cam) if fit else str(exc)
            raise Abort("ambiguous", f"place target: {text}", fit, T_base_cam) from None
        except ObjectNotFoundError as exc:
            raise Abort("not_found", f"place target: {exc}") from None
        except InvalidInputError as exc:
            raise Abort("not_found", f"place target {prompt!r}: {exc}") from None
    T_base_cam = np.asarray(frame.T_base_cam, dtype=np.float64)
    obj, support = to_base(est, T_base_cam, "place target")
    if np.linalg.norm(obj.pose.t - obs.target.pose.t) < _SAME_OBJECT_M:
        raise Abort("not_found", f"the place {prompt!r} is the object to pick itself")
    target = place_target_on(obj, support, container=cmd.into or est.prior.name in CONTAINERS)
    where = np.round(target.T_base_surface[:3, 3], 3).tolist()
    loop.emit("estimate", f"place target {prompt!r}: {est.prior.name} ({target.kind}) at {where}", 0.25)
    return target
