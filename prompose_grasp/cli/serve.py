"""`serve`: the perception service (`prompose_grasp.service`), one warm estimator behind HTTP."""

from __future__ import annotations

import argparse
import os
import sys

from prompose_grasp.cli.arguments import check_at_least
from prompose_grasp.errors import InvalidInputError


def add_serve(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "serve",
        help="keep the estimator loaded and answer estimate / track / health over HTTP (extra `serve`)",
        description="A local perception service (FastAPI + uvicorn): POST /v1/estimate, POST /v1/track, "
        "GET /v1/health; the OpenAPI schema at /openapi.json. See docs/service.md.",
    )
    p.add_argument(
        "--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)"
    )
    p.add_argument("--port", type=int, default=8765, help="TCP port (default 8765; 0 picks a free one)")
    p.add_argument(
        "--token", default=None, help="require this bearer token (default: $PROMPOSE_GRASP_TOKEN when set)"
    )
    p.add_argument("--max-body-mb", type=float, default=32.0, help="largest request body [MiB] (default 32)")
    p.add_argument(
        "--max-queue", type=int, default=32, help="requests that may wait (default 32); more get 503"
    )
    p.add_argument("--device", default="cpu", help="torch device of the estimator (default cpu)")
    p.set_defaults(func=_run_serve)


def _run_serve(args: argparse.Namespace) -> int:
    from prompose_grasp.service.app import ServiceConfig, serve

    check_at_least(args.max_queue, "--max-queue", 1)
    if not args.max_body_mb > 0:
        raise InvalidInputError(f"--max-body-mb must be > 0, got {args.max_body_mb}")
    config = ServiceConfig(
        host=args.host,
        port=args.port,
        token=args.token or os.environ.get("PROMPOSE_GRASP_TOKEN") or None,
        max_body_bytes=int(args.max_body_mb * 2**20),
        max_queue=args.max_queue,
        device=args.device,
    )

    def ready(url: str) -> None:
        print(f"prompose-grasp serve: listening on {url}", file=sys.stderr, flush=True)

    serve(config, ready=ready)
    return 0
