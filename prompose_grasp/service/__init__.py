"""A local perception service: the estimator kept loaded behind HTTP + JSON (`prompose-grasp serve`).

- `create_app` (`service.app`): the FastAPI application (extra `serve`): `GET /v1/health`,
  `POST /v1/estimate`, `POST /v1/track`, `DELETE /v1/track/{track_id}`; its OpenAPI schema at
  `/openapi.json`.
- `serve` (`service.app`): run it with uvicorn, bound to 127.0.0.1 unless told otherwise.
- `PerceptionClient` (`service.client`): a small client on the standard library (no extra needed), used by
  `prompose-grasp estimate --server URL`.

docs/service.md describes the requests, the limits and the measured round trip.
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.service.app import ServiceConfig, create_app, serve
    from prompose_grasp.service.client import PerceptionClient, ServiceError

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.service.app": ("ServiceConfig", "create_app", "serve"),
        "prompose_grasp.service.client": ("PerceptionClient", "ServiceError"),
    },
    submodules=("app", "client", "protocol"),
)

__all__ = ["PerceptionClient", "ServiceConfig", "ServiceError", "create_app", "serve"]
