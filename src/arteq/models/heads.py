"""ArtEq heads: invariant part segmentation, soft part pooling, equivariant pose, invariant shape.

Feature layout everywhere: channels last, group axis before channels, ``[..., A, C]`` with A = 60.
"""

from __future__ import annotations

import roma
import torch
import torch.nn.functional as F
from torch import nn

from arteq.models.precision import full_precision, upcast


class ResFC(nn.Module):
    """Residual fully connected block ``x -> x' + fc2(relu(fc1(relu(x))))`` (per point)."""

    def __init__(self, d_in: int, d_out: int, d_hidden: int | None = None):
        super().__init__()
        d_hidden = d_hidden or min(d_in, d_out)
        self.fc1 = nn.Linear(d_in, d_hidden)
        self.fc2 = nn.Linear(d_hidden, d_out)
        self.skip = nn.Linear(d_in, d_out, bias=False) if d_in != d_out else nn.Identity()
        self.act = nn.ReLU()
        nn.init.zeros_(self.fc2.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.skip(x) + self.fc2(self.act(self.fc1(self.act(x))))


#: Invariant statistics over the group axis the segmenter may read (``segmenter.group_pool``).
GROUP_POOLS = {"mean": ("mean",), "mean_max": ("mean", "max"), "mean_max_std": ("mean", "max", "std")}


class PartSegmenter(nn.Module):
    """PointNet with skip connections and global context on SO(3)-invariant point features.

    ``[B, N, C * m] -> logits [B, N, K]``. Every block after the first sees its input concatenated with
    the max over points (global context), as in a ResNet-PointNet. Only per-point maps and pooling
    over points are used, so invariant inputs give invariant outputs and point order is irrelevant.

    ``group_pool`` (:data:`GROUP_POOLS`): which statistics over the 60 group elements of an equivariant
    point feature :meth:`invariant` makes its input of: ``mean`` (the paper's group mean; ``m = 1``), or
    also the max and the standard deviation over the group (``m = 2, 3``). A rotation permutes the group
    axis, so every such statistic is exactly invariant; the max and the spread keep what the mean averages
    away (how peaked a feature is over orientations), at no cost to locality.
    """

    def __init__(
        self,
        in_channels: int,
        num_parts: int = 22,
        hidden: int = 128,
        num_blocks: int = 4,
        group_pool: str = "mean",
    ):
        super().__init__()
        if group_pool not in GROUP_POOLS:
            raise ValueError(f"segmenter.group_pool must be one of {list(GROUP_POOLS)}, got {group_pool!r}")
        self.group_pool = GROUP_POOLS[group_pool]
        self.fc_in = nn.Linear(in_channels * len(self.group_pool), 2 * hidden)
        self.blocks = nn.ModuleList([ResFC(2 * hidden, hidden) for _ in range(num_blocks)])
        self.fc_out = nn.Linear(hidden, num_parts)
        self.act = nn.ReLU()

    def invariant(self, feats: torch.Tensor) -> torch.Tensor:
        """``[B, N, A, C]`` equivariant point features -> ``[B, N, C * m]`` invariant ones."""
        stats = {"mean": lambda: feats.mean(dim=2), "max": lambda: feats.amax(dim=2),
                 "std": lambda: feats.std(dim=2, unbiased=False)}  # fmt: skip
        if self.group_pool == ("mean",):
            return stats["mean"]()
        return torch.cat([stats[k]() for k in self.group_pool], dim=-1)

    def forward(self, feats: torch.Tensor) -> torch.Tensor:
        x = self.fc_in(feats)
        for i, block in enumerate(self.blocks):
            x = block(x)
            if i < len(self.blocks) - 1:
                x = torch.cat([x, x.max(dim=1, keepdim=True).values.expand_as(x)], dim=-1)
        return self.fc_out(self.act(x))


def pool_parts(feats: torch.Tensor, weights: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Soft part pooling: the weight-averaged point feature of each part.

    Args:
        feats: ``[B, N, A, C]`` equivariant point features.
        weights: ``[B, N, K]`` part membership (probabilities, or one-hot ground truth).
    Returns:
        ``[B, K, A, C]``: ``H[k] = sum_i w_ik F_i / sum_i w_ik``. A part with no mass gets zeros.
    """
    norm = weights / (weights.sum(dim=1, keepdim=True) + eps)
    b, n, a, c = feats.shape
    out = torch.bmm(norm.transpose(1, 2), feats.reshape(b, n, a * c))
    return out.reshape(b, -1, a, c)


class GroupSelfAttention(nn.Module):
    """Multi-head self-attention over tokens, no positional encoding (permutation-equivariant).

    The parameters are those of ``nn.MultiheadAttention`` (checkpoint keys ``attn.in_proj_weight``, ...);
    the product is written as two batched matrix products and a softmax, the same map to float rounding
    and about twice as fast on the CPU at the pose head's head width of 8 as the fused kernel
    (benchmarks/README.md)."""

    def __init__(self, dim: int, heads: int, residual: bool = True):
        super().__init__()
        self.attn = nn.MultiheadAttention(dim, heads, batch_first=True)
        self.heads = heads
        self.residual = residual

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, t, d = x.shape
        h = self.heads
        qkv = F.linear(x, self.attn.in_proj_weight, self.attn.in_proj_bias)
        q, k, v = qkv.reshape(b, t, 3, h, d // h).permute(2, 0, 3, 1, 4)  # each [B, H, T, D/H]
        a = torch.softmax((q * (d // h) ** -0.5) @ k.transpose(-1, -2), dim=-1)
        y = self.attn.out_proj((a @ v).transpose(1, 2).reshape(b, t, d))
        return x + y if self.residual else y


def part_geometry(
    points: torch.Tensor,
    weights: torch.Tensor,
    group_rotations: torch.Tensor,
    power: float = 4.0,
    eps: float = 1e-4,
) -> torch.Tensor:
    """Each part's point distribution seen from the frame of every group element: ``[B, K, A, 16]``.

    The part's second and third central moments (``C = E[d d^T]``, ``T = E[d (x) d (x) d]`` with
    ``d = x - c_k`` the offset from the part's weighted centroid), rotated into the frame of element
    ``a`` (``R_a^T C R_a`` and ``T`` contracted with ``R_a`` on each index) and made scale-free by the
    part's spread ``tr C``: the 6 distinct entries of the rotated ``C / tr C`` and the 10 of
    ``T / (tr C)^1.5``. The second moments give the part's principal axes, the third ones which way each
    axis points (hand end vs elbow end), so the tokens say how the part is oriented.

    Exactly what the pose head needs and nothing more: the descriptor of part k depends only on the
    points weighted to part k (so turning a limb about its joint changes it exactly as a group rotation
    of the limb does, whatever its neighbours do; with one-hot weights exactly), rotating the cloud by a
    group element ``g`` permutes its tokens as the backbone's features are permuted (token ``a`` of the
    rotated cloud is token ``b`` with ``R_b = R_g^T R_a``), and translation does not change it.

    Args:
        points: ``[B, N, 3]``; weights: ``[B, N, K]`` part membership (probabilities or one-hot), used
            as ``w^power`` (renormalised per part) so that the small probabilities a soft segmentation
            gives to far-away points do not swamp the part's moments; group_rotations: ``[A, 3, 3]``.
        eps: added to ``tr C`` (m^2): a part with no mass or a single point gets finite (zero) tokens.
    """
    w = weights.detach().to(points.dtype).clamp_min(0) ** power  # [B, N, K]
    w = w / (w.sum(dim=1, keepdim=True) + 1e-12)
    centroid = torch.einsum("bnk,bnx->bkx", w, points)  # [B, K, 3]
    d = points[:, None] - centroid[:, :, None]  # [B, K, N, 3]
    wd = w.transpose(1, 2)[..., None] * d  # [B, K, N, 3]
    c2 = torch.einsum("bknx,bkny->bkxy", wd, d)  # [B, K, 3, 3]
    c3 = torch.einsum("bknx,bkny,bknz->bkxyz", wd, d, d)  # [B, K, 3, 3, 3]
    scale = c2.diagonal(dim1=-2, dim2=-1).sum(-1) + eps  # [B, K]
    rt = group_rotations.to(points.dtype).transpose(1, 2)  # [A, 3, 3]: R_a^T
    c2a = torch.einsum("aix,bkxy,ajy->bkaij", rt, c2, rt)
    c3a = torch.einsum("aix,ajy,alz,bkxyz->bkaijl", rt, rt, rt, c3)
    iu = torch.triu_indices(3, 3)
    second = c2a[..., iu[0], iu[1]] / scale[:, :, None, None]
    i3 = [(i, j, k) for i in range(3) for j in range(i, 3) for k in range(j, 3)]
    third = torch.stack([c3a[..., i, j, k] for i, j, k in i3], dim=-1) / scale[:, :, None, None] ** 1.5
    return torch.cat([second, third], dim=-1)


#: Channels of :func:`part_geometry` tokens.
GEOMETRY_CHANNELS = 16


#: How the pose head sees a part's parent (``model.net.parent_conditioning``).
PARENT_MODES = ("invariant", "aligned", "none")


def parent_mode(value: bool | str | None) -> str:
    """The parent-conditioning mode of a config value: ``"invariant"`` (the parent's group-mean feature
    appended to each of the child's 60 tokens: unchanged when the child turns relative to its parent),
    ``"aligned"`` (the parent's token at the same group element appended: what ``true`` meant before the
    modes existed, equivariant only to rotations shared by parent and child) or ``"none"`` (``false``,
    the paper's "nc" ablation)."""
    if value is True:
        return "aligned"
    if value is False or value is None:
        return "none"
    if isinstance(value, str) and value.lower() in PARENT_MODES:
        return value.lower()
    modes = ", ".join(PARENT_MODES)
    raise ValueError(f"model.net.parent_conditioning must be one of {modes} (or true / false), got {value!r}")


class PoseHead(nn.Module):
    """Per-part global rotation as the weighted chordal L2 mean of the group's rotations.

    For part k the tokens are its 60 group-element features, each concatenated with its parent's
    (``parent_conditioning``, see :func:`parent_mode`: the parent's group-mean feature, or its feature
    at the same group element, or nothing); self-attention over those tokens and a per-token MLP give
    one logit per group element; the logits are standardised over the 60 elements (zero mean, unit
    variance: statistics over the tokens, hence permutation-invariant) and scaled by a learned
    sharpness ``s`` (initialised to ``sharpness``); the weights ``p = softmax(s * z)`` are convex, and
    ``M_k = sum_a p_a R_a``; the rotation is the SO(3) projection of ``M_k`` (SVD, the closed form of
    the weighted chordal mean). A learned per-part embedding (``part_embedding``) is added to all tokens
    of a part: the head is shared across parts and this tells it which one it reads. Permuting the
    tokens as a group rotation ``g`` does permutes ``p``, so ``M_k -> R_g M_k`` and the output
    rotation is left-multiplied by ``R_g``: equivariant.

    ``logit_eps``: the standardisation divides by ``sqrt(var + logit_eps)``. When a part's 60 tokens are
    (nearly) identical the logits' spread is (nearly) zero: a part with no points, whose pooled feature is
    0, and, with the invariant parent conditioning or none, nothing else to tell its tokens apart; or local
    features at 500 points whose balls hold one or two points. Dividing by the bare standard deviation then
    amplifies rounding noise without bound; its gradient is NaN at exactly zero (that killed training runs)
    and ~1e3-1e5 near it, so gradient clipping scaled every other gradient to nothing and the network did
    not learn (measured: total gradient norm 3e2-4e5 per step at initialisation, loss flat for 300 steps).
    ``None`` (the constructor default, what checkpoints made before the option hold) keeps the old
    ``std + 1e-6`` (the default config too); ``model=arteq_local`` sets ``1e-4``.

    ``geometry``: with ``True`` every token also carries the part's point distribution seen from its group
    element (:func:`part_geometry`, passed to ``forward``). Not in the paper: pooled features of a
    part-local backbone (``model=arteq_local``) at 500 points barely say how a part is turned (a ball of
    8 cm holds a handful of points), and its rotation loss stalled; the moments say it directly, depend
    on the part's own points only and keep the head exactly equivariant.

    Why not raw weights (the authors' code): the 60 group rotations sum to zero, so raw weights that
    start out nearly equal put ``M`` near zero, where the SVD derivative (``1 / (s_i + s_j)``)
    explodes (measured here with plain softmax weights at initialisation: singular values of ``M``
    around 1e-7, so the projection is rounding noise). Here (1) weights are convex and standardised
    before the softmax, so they are concentrated from the first step whatever the feature scale and
    ``M`` sits well inside the convex hull of the group, away from 0 (singular values 0.17-0.8 at
    initialisation); (2) the projection uses damped derivatives (``roma.special_procrustes`` with
    ``gradient_eps``), bounded even at ``M = 0``; (3) the training
    loss also supervises ``M`` itself (chordal distance, no SVD), which has well-behaved gradients
    from the first step and drives the weights to concentrate.
    """

    def __init__(
        self,
        in_channels: int,
        group_rotations: torch.Tensor,
        parents: tuple[int, ...],
        dim: int = 128,
        heads: int = 8,
        layers: int = 2,
        mlp_hidden: int = 128,
        parent_conditioning: bool | str = True,
        sharpness: float = 3.0,
        gradient_eps: float = 1e-3,
        part_embedding: bool = True,
        logit_eps: float | None = None,
        geometry: bool = False,
    ):
        super().__init__()
        self.parent_mode = parent_mode(parent_conditioning)
        self.parent_conditioning = self.parent_mode != "none"
        self.register_buffer("parents", torch.tensor([max(p, 0) for p in parents]), persistent=False)
        self.register_buffer("group_rotations", group_rotations.double().clone(), persistent=False)
        d_in = 2 * in_channels if self.parent_conditioning else in_channels
        # part_geometry tokens appended to every token (``forward(..., geometry=...)``)
        self.geometry = bool(geometry)
        d_in += GEOMETRY_CHANNELS if self.geometry else 0
        self.embed = nn.Linear(d_in, dim)
        # Which part the tokens belong to: one learned vector per part, added to all 60 of its tokens
        # alike (so group permutations of the tokens commute with it: equivariance is kept). Without
        # it the shared head must guess from local shape whether a limb-like feature is an arm (rest
        # pose horizontal) or a leg (rest pose vertical).
        self.part_embedding = nn.Parameter(torch.zeros(len(parents), dim)) if part_embedding else None
        # Residual connections on every layer: without one, attention that starts out near-uniform
        # replaces all 60 tokens by their mean and erases the group signal the weights are read from.
        self.attn = nn.ModuleList([GroupSelfAttention(dim, heads) for _ in range(layers)])
        self.mlp = nn.Sequential(
            nn.Linear(dim, mlp_hidden), nn.ReLU(), nn.Linear(mlp_hidden, mlp_hidden), nn.ReLU(),
            nn.Linear(mlp_hidden, 1),
        )  # fmt: skip
        self.log_sharpness = nn.Parameter(torch.tensor(float(sharpness)).log())
        self.gradient_eps = gradient_eps
        if logit_eps is not None and not float(logit_eps) > 0:
            raise ValueError(f"PoseHead: logit_eps must be > 0 or None, got {logit_eps}")
        self.logit_eps = None if logit_eps is None else float(logit_eps)

    def forward(
        self,
        part_feats: torch.Tensor,
        geometry: torch.Tensor | None = None,
        parts: tuple[int, ...] | None = None,
    ) -> dict[str, torch.Tensor]:
        """``part_feats [B, K, A, C]`` (and, for a head built with ``geometry=True``, the
        :func:`part_geometry` tokens ``[B, K, A, 16]``) -> ``weights [B, K, A]``, ``mean [B, K, 3, 3]``
        (before projection) and ``rotmats [B, K, 3, 3]`` (global rotation of each part).

        ``parts``: compute only these parts (outputs ``[B, len(parts), ...]``, in that order). A part's
        output depends on its own tokens and its parent's only, so each is exactly what the full call
        gives for it."""
        if self.geometry != (geometry is not None):
            need = "needs" if self.geometry else "was built without"
            raise ValueError(f"PoseHead {need} part_geometry tokens (geometry={self.geometry})")
        # The whole head runs in float32 at least, also under mixed precision: which of the 60 group
        # elements a part's rotation is read from depends on small differences between its 60 tokens,
        # which bfloat16 products (3 significant digits) would round away, and the attention over the
        # tokens would no longer be (near-)exactly permutation-equivariant. It is small next to the backbone.
        with full_precision(part_feats):
            return self._forward(upcast(part_feats), None if geometry is None else upcast(geometry), parts)

    def _forward(
        self, part_feats: torch.Tensor, geometry: torch.Tensor | None, parts: tuple[int, ...] | None = None
    ) -> dict[str, torch.Tensor]:
        x = part_feats
        if self.parent_mode == "aligned":
            x = torch.cat([x, x[:, self.parents]], dim=-1)
        elif self.parent_mode == "invariant":
            inv = x[:, self.parents].mean(dim=2, keepdim=True).expand_as(x)
            x = torch.cat([x, inv], dim=-1)
        if geometry is not None:
            x = torch.cat([x, geometry.to(x.dtype)], dim=-1)
        emb = self.part_embedding
        if parts is not None:
            x = x[:, list(parts)]
            emb = None if emb is None else emb[list(parts)]
        b, k, a, _ = x.shape
        x = self.embed(x)
        if emb is not None:
            x = x + emb[:, None, :]
        x = x.reshape(b * k, a, -1)
        for layer in self.attn:
            x = layer(x)
        logits = self.mlp(x).reshape(b, k, a)
        centred = logits - logits.mean(-1, keepdim=True)
        if self.logit_eps is None:  # networks saved before logit_eps: the old form, kept for their weights
            z = centred / (logits.std(-1, keepdim=True) + 1e-6)
        else:
            z = centred * torch.rsqrt(logits.var(-1, keepdim=True) + self.logit_eps)
        weights = torch.softmax(z * self.log_sharpness.exp(), dim=-1)
        mean = torch.einsum("bka,aij->bkij", weights, self.group_rotations.to(weights.dtype))
        rotmats = roma.special_procrustes(mean, gradient_eps=self.gradient_eps)
        return {"weights": weights, "mean": mean, "rotmats": rotmats}


class ShapeHead(nn.Module):
    """Betas from rotation-invariant part features: self-attention across parts, then an MLP.

    ``[B, K, C] -> [B, num_betas]``. Parts have an identity (left knee is not head), so a learned
    part embedding is added before attention; this does not touch rotation invariance.
    """

    def __init__(
        self,
        in_channels: int,
        num_parts: int = 22,
        num_betas: int = 10,
        dim: int = 64,
        heads: int = 4,
        layers: int = 2,
        token_out: int = 6,
        mlp_hidden: int = 128,
    ):
        super().__init__()
        self.embed = nn.Linear(in_channels, dim)
        self.part_embedding = nn.Parameter(torch.zeros(num_parts, dim))
        self.attn = nn.ModuleList([GroupSelfAttention(dim, heads) for _ in range(layers)])
        self.reduce = nn.Linear(dim, token_out)
        self.mlp = nn.Sequential(
            nn.Linear(num_parts * token_out, mlp_hidden), nn.ReLU(), nn.Linear(mlp_hidden, num_betas)
        )

    def forward(self, part_feats_inv: torch.Tensor) -> torch.Tensor:
        x = self.embed(part_feats_inv) + self.part_embedding
        for layer in self.attn:
            x = layer(x)
        return self.mlp(self.reduce(x).flatten(1))
