"""Grasp candidates as a batch: `Candidates` (numpy arrays, one row per candidate) and its lazy `Reasons`.

Every generator (`parallel_jaw`, `suction`, `surface`) returns a `Candidates` batch in `base`: `T_base_tcp`
(N, 4, 4) with tcp +z the approach and tcp y the closing direction, the opening to pre-shape to, the object
width at the contacts, the contacts, a quality in [0, 1] and a reason in words.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import overload

import numpy as np

from prompose_grasp.geometry.distance import cross
from prompose_grasp.grasp.types import Plane

__all__ = ["Candidates", "Reasons", "stack_transforms", "support_up", "tcp_frames"]


class Reasons(Sequence[str]):
    """The reasons of a batch of candidates, formatted when read.

    Hundreds of candidates are generated and a handful returned, so each generator stores a format function
    and one argument per row (its own row index) instead of formatting every text; `take` and `concat`
    follow the rows. Reads like a list of strings (`len`, indexing, iteration, `==` with a list).
    """

    __slots__ = ("_arg", "_fns", "_which")

    def __init__(self, fns: Sequence[Callable[[int], str]], which: np.ndarray, arg: np.ndarray):
        self._fns = list(fns)
        self._which = np.asarray(which, dtype=np.int64)
        self._arg = np.asarray(arg, dtype=np.int64)

    @classmethod
    def of(cls, texts: Sequence[str] | Reasons) -> Reasons:
        """`Reasons` of a list of ready strings (or the same `Reasons`)."""
        if isinstance(texts, Reasons):
            return texts
        texts = list(texts)
        return cls([texts.__getitem__], np.zeros(len(texts)), np.arange(len(texts)))

    @classmethod
    def lazy(cls, fn: Callable[[int], str], n: int) -> Reasons:
        """n reasons, row r's text being fn(r)."""
        return cls([fn], np.zeros(n), np.arange(n))

    def __len__(self) -> int:
        return len(self._arg)

    @overload
    def __getitem__(self, i: int) -> str: ...

    @overload
    def __getitem__(self, i: slice) -> list[str]: ...

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        return self._fns[int(self._which[i])](int(self._arg[i]))

    def __eq__(self, other: object) -> bool:
        if isinstance(other, (Reasons, list, tuple)):
            return len(self) == len(other) and all(a == b for a, b in zip(self, other))
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]

    def take(self, idx: np.ndarray) -> Reasons:
        return Reasons(self._fns, self._which[idx], self._arg[idx])

    @classmethod
    def concat(cls, parts: Sequence[Reasons]) -> Reasons:
        fns: list[Callable[[int], str]] = []
        which: list[np.ndarray] = []
        arg: list[np.ndarray] = []
        for p in parts:
            which.append(p._which + len(fns))
            arg.append(p._arg)
            fns += p._fns
        empty = np.zeros(0, dtype=np.int64)
        return cls(fns, np.concatenate(which or [empty]), np.concatenate(arg or [empty]))


@dataclass
class Candidates:
    """A batch of grasp candidates (rows), in `base`.

    Attributes:
        T_base_tcp: (N, 4, 4) tcp poses.
        opening_m: (N,) pad distance to open to [m] (0 for suction).
        width_m: (N,) object width at the contacts [m] (0 for suction).
        contacts: (N, 2, 3) contact points [m] (suction: the cup centre twice).
        quality: (N,) in [0, 1].
        method: (N,) "box" / "antipodal" / "suction".
        reason: N strings (a `Reasons`: formatted when read).
        check_target: (N,) bool: collide the gripper with the target too (mesh grasps: the fingers may meet
            the mesh elsewhere; box grasps keep clear of the box by construction).
        pre_rejected: (N,) "" or the reason a generator already knows the candidate fails ("stroke", ...).
    """

    T_base_tcp: np.ndarray
    opening_m: np.ndarray
    width_m: np.ndarray
    contacts: np.ndarray
    quality: np.ndarray
    method: np.ndarray
    reason: Sequence[str] = field(default_factory=list)
    check_target: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    pre_rejected: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))

    def __len__(self) -> int:
        return int(self.T_base_tcp.shape[0])

    @classmethod
    def empty(cls) -> Candidates:
        return cls(
            np.zeros((0, 4, 4)),
            np.zeros(0),
            np.zeros(0),
            np.zeros((0, 2, 3)),
            np.zeros(0),
            np.zeros(0, dtype=object),
            [],
            np.zeros(0, dtype=bool),
            np.zeros(0, dtype=object),
        )

    @classmethod
    def concat(cls, parts: list[Candidates]) -> Candidates:
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        return cls(
            np.concatenate([p.T_base_tcp for p in parts]),
            np.concatenate([p.opening_m for p in parts]),
            np.concatenate([p.width_m for p in parts]),
            np.concatenate([p.contacts for p in parts]),
            np.concatenate([p.quality for p in parts]),
            np.concatenate([p.method for p in parts]),
            Reasons.concat([Reasons.of(p.reason) for p in parts]),
            np.concatenate([p.check_target for p in parts]),
            np.concatenate([p.pre_rejected for p in parts]),
        )

    def take(self, idx: np.ndarray) -> Candidates:
        idx = np.asarray(idx, dtype=np.int64)
        return Candidates(
            self.T_base_tcp[idx],
            self.opening_m[idx],
            self.width_m[idx],
            self.contacts[idx],
            self.quality[idx],
            self.method[idx],
            Reasons.of(self.reason).take(idx),
            self.check_target[idx],
            self.pre_rejected[idx],
        )


def tcp_frames(approach: np.ndarray, closing: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations, columns x = y cross z, y = closing, z = approach (both (N, 3), unit, normal)."""
    x = cross(closing, approach)
    return np.stack([x, closing, approach], axis=-1)


def stack_transforms(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N, 4, 4) rigid transforms from rotations R (N, 3, 3) and translations p (N, 3)."""
    T = np.zeros((R.shape[0], 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    T[:, 3, 3] = 1.0
    return T


def support_up(support: Plane | None) -> np.ndarray:
    """(3,) the support's normal, or base +z without a support."""
    return np.array([0.0, 0.0, 1.0]) if support is None else np.asarray(support.normal)
