"""Where a rerun recording goes (`RerunTarget`): a `.rrd` file, a viewer spawned on this machine, or a viewer
(or server) already running at a URL. Parsed and checked before any work, without importing rerun."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from prompose_grasp.errors import InvalidInputError

__all__ = ["USAGE", "RerunTarget"]

#: What `--rerun` takes, for help texts and errors.
USAGE = "FILE.rrd | spawn | connect [URL]"


@dataclass(frozen=True)
class RerunTarget:
    """`kind` "file" (`value`: the .rrd path), "spawn" (a local viewer; `value` None) or "connect" (`value`:
    the viewer's gRPC URL, e.g. rerun+http://127.0.0.1:9876/proxy; None: rerun's default)."""

    kind: str
    value: str | None = None

    @classmethod
    def parse(cls, words: Sequence[str], flag: str = "--rerun") -> RerunTarget:
        """`["episode.rrd"]`, `["spawn"]`, `["connect"]` or `["connect", URL]`; a file's folder must exist
        or be creatable (its nearest existing parent a writable folder)."""
        words = [str(w) for w in words]
        if words == ["spawn"]:
            return cls("spawn")
        if words[:1] == ["connect"] and len(words) <= 2:
            url = words[1] if len(words) == 2 else None
            if url is not None and "://" not in url:
                raise InvalidInputError(
                    f"{flag} connect {url}: not a URL (e.g. rerun+http://HOST:9876/proxy)"
                )
            return cls("connect", url)
        if len(words) != 1:
            raise InvalidInputError(f"{flag} takes {USAGE}; got {' '.join(words) or 'nothing'}")
        path = Path(words[0])
        if path.suffix.lower() != ".rrd":
            raise InvalidInputError(f"{flag} {words[0]}: a recording file ends in .rrd (or say {USAGE})")
        if path.is_dir():
            raise InvalidInputError(f"{flag} {words[0]}: is a folder; give a file path")
        parent = path.parent
        while not parent.exists():
            parent = parent.parent
        if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
            raise InvalidInputError(f"{flag} {words[0]}: {str(parent)!r} is not a writable folder")
        if path.exists() and not os.access(path, os.W_OK):
            raise InvalidInputError(f"{flag} {words[0]}: not writable")
        return cls("file", str(path))

    def __str__(self) -> str:
        return self.kind if self.value is None else f"{self.kind} {self.value}"
