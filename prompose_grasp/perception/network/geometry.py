"""phi_G: a Point-Transformer-v2-style geometry encoder in plain PyTorch (runs on CPU, no custom CUDA ops).

Paper section 3.3: one encoder, weight-shared over the metric observation P_t, its canonicalised copy and the
canonical prior. Structure (after Wu et al., Point Transformer V2):

1. stem: a point-wise MLP of the coordinates (every input point);
2. per stage: a transition-down (farthest point sampling keeps N / stride centres; each centre max-pools an
   MLP of its k nearest input points' features and relative positions), then `geometry_blocks` grouped vector
   attention (GVA) blocks over the kNN graph of the centres;
3. output: the last stage's tokens, their positions, and their mean (the global feature g).

Grouped vector attention (PTv2 eq. 5-7): for point i and neighbour j, with p = position and
delta = MLP(p_j - p_i), relation r_ij = k_j - q_i + delta; weights w_ij = softmax_j(MLP(r_ij)) in G groups;
out_i = sum_j w_ij (v_j + delta), each group weighting its channel slice.

Permutation: FPS starts at the point farthest from the centroid (not at index 0), so the chosen centres and
the token order depend on the point set only, not on its order (exact ties aside). The tokens and g are
therefore invariant to a permutation of the input points.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from prompose_grasp.perception.network.config import NetworkConfig
from prompose_grasp.perception.network.layers import FeedForward, batched_gather

__all__ = ["GeometryEncoder", "farthest_point_indices", "knn_indices"]


@torch.no_grad()
def farthest_point_indices(points: Tensor, m: int) -> Tensor:
    """Farthest point sampling: (B, N, 3) -> (B, min(m, N)) long indices, the first farthest from the mean."""
    B, N, _ = points.shape
    m = min(int(m), N)
    centroid = points.mean(dim=1, keepdim=True)
    first = ((points - centroid) ** 2).sum(-1).argmax(dim=1)
    chosen = torch.empty(B, m, dtype=torch.long, device=points.device)
    chosen[:, 0] = first
    nearest = torch.full((B, N), float("inf"), dtype=points.dtype, device=points.device)
    rows = torch.arange(B, device=points.device)
    last = first
    for i in range(1, m):
        d = ((points - points[rows, last].unsqueeze(1)) ** 2).sum(-1)
        nearest = torch.minimum(nearest, d)
        last = nearest.argmax(dim=1)
        chosen[:, i] = last
    return chosen


@torch.no_grad()
def knn_indices(queries: Tensor, reference: Tensor, k: int) -> Tensor:
    """(B, M, 3) queries, (B, N, 3) reference -> (B, M, min(k, N)) long indices of the nearest references."""
    k = min(int(k), reference.shape[1])
    d = torch.cdist(queries, reference)
    return d.topk(k, dim=-1, largest=False, sorted=True).indices


class GroupedVectorAttention(nn.Module):
    """One GVA block with residuals: x + Linear(GVA(LN(x))), then a feed-forward block."""

    def __init__(self, dim: int, groups: int, mlp_ratio: int):
        super().__init__()
        self.groups = groups
        self.norm = nn.LayerNorm(dim)
        self.q = nn.Linear(dim, dim)
        self.k = nn.Linear(dim, dim)
        self.v = nn.Linear(dim, dim)
        self.pos = nn.Sequential(nn.Linear(3, dim), nn.LayerNorm(dim), nn.GELU(), nn.Linear(dim, dim))
        self.weight = nn.Sequential(
            nn.Linear(dim, groups), nn.LayerNorm(groups), nn.GELU(), nn.Linear(groups, groups)
        )
        self.out = nn.Linear(dim, dim)
        self.ffn = FeedForward(dim, mlp_ratio)

    def forward(self, x: Tensor, pos: Tensor, neighbors: Tensor) -> Tensor:
        """x (B, N, C), pos (B, N, 3), neighbors (B, N, k) long -> (B, N, C)."""
        B, N, C = x.shape
        h = self.norm(x)
        q, k, v = self.q(h), self.k(h), self.v(h)
        delta = self.pos(batched_gather(pos, neighbors) - pos.unsqueeze(2))  # (B, N, k, C)
        relation = batched_gather(k, neighbors) - q.unsqueeze(2) + delta
        w = torch.softmax(self.weight(relation), dim=2)  # (B, N, k, G)
        value = (batched_gather(v, neighbors) + delta).reshape(B, N, -1, self.groups, C // self.groups)
        agg = (w.unsqueeze(-1) * value).sum(dim=2).reshape(B, N, C)
        return self.ffn(x + self.out(agg))


class TransitionDown(nn.Module):
    """FPS to N // stride centres; each max-pools MLP([feature_j, p_j - p_centre]) over its k nearest."""

    def __init__(self, dim: int, stride: int, neighbors: int):
        super().__init__()
        self.stride = stride
        self.neighbors = neighbors
        self.mlp = nn.Sequential(nn.Linear(dim + 3, dim), nn.LayerNorm(dim), nn.GELU(), nn.Linear(dim, dim))

    def forward(self, x: Tensor, pos: Tensor) -> tuple[Tensor, Tensor]:
        """x (B, N, C), pos (B, N, 3) -> (B, M, C), (B, M, 3) with M = max(N // stride, 1)."""
        if self.stride == 1:
            return x, pos
        m = max(pos.shape[1] // self.stride, 1)
        centres = batched_gather(pos, farthest_point_indices(pos, m))
        idx = knn_indices(centres, pos, self.neighbors)
        grouped = torch.cat([batched_gather(x, idx), batched_gather(pos, idx) - centres.unsqueeze(2)], dim=-1)
        return self.mlp(grouped).amax(dim=2), centres


class GeometryEncoder(nn.Module):
    """phi_G: (B, N, 3) points -> tokens (B, M, geometry_dim), positions (B, M, 3), global (B, geometry_dim).

    One instance serves every point stream (weight sharing is by construction: the model holds one encoder).
    """

    def __init__(self, config: NetworkConfig):
        super().__init__()
        c = config.geometry_dim
        self.neighbors = config.geometry_neighbors
        self.stem = nn.Sequential(nn.Linear(3, c), nn.LayerNorm(c), nn.GELU(), nn.Linear(c, c))
        self.downs = nn.ModuleList(
            [TransitionDown(c, s, config.geometry_neighbors) for s in config.geometry_strides]
        )
        self.stages = nn.ModuleList(
            [
                nn.ModuleList(
                    [
                        GroupedVectorAttention(c, config.geometry_groups, config.mlp_ratio)
                        for _ in range(config.geometry_blocks)
                    ]
                )
                for _ in config.geometry_strides
            ]
        )
        self.norm = nn.LayerNorm(c)

    def forward(self, points: Tensor) -> dict[str, Tensor]:
        x = self.stem(points)
        pos = points
        for i, down in enumerate(self.downs):
            x, pos = down(x, pos)
            nbrs = knn_indices(pos, pos, self.neighbors)
            stage = self.stages[i]
            assert isinstance(stage, nn.ModuleList)
            for block in stage:
                x = block(x, pos, nbrs)
        x = self.norm(x)
        return {"tokens": x, "positions": pos, "global": x.mean(dim=1)}
