"""Single-view depth scans: what one depth camera sees of a body, as a point cloud with part labels.

A virtual pinhole depth camera (focal length ``focal_px`` pixels, square pixels) is put at a random
position around the body: ``distance_m`` from the pelvis, a heading (azimuth about the body's up axis,
0 = in front of it) and an elevation (0 = level with the pelvis, 90 = straight above the body), looking at
the pelvis with the body's up axis up in the image. By default the image is cropped to the body's
projection (the person is always fully in view; nothing is cut at the image border). With ``frame_px =
(width, height)`` the image is the sensor's, centred on the pelvis: what falls outside it is not seen, as
when a person stands too near a real camera (a 640 x 480 sensor at 500 px sees 1.3 x 1.0 m at 1 m: the head
and the lower legs are cut off; at 2 m 2.6 x 1.9 m). The ``near`` view (its own test set) does that.

The depth image is an exact z-buffer of the mesh: every triangle is rasterised at the pixel centres it
covers (vectorised: all (triangle, pixel) pairs of the triangles' bounding boxes at once), the nearest
surface wins each pixel, and the pixel's 3D point lies exactly on the surface along its ray (perspective-
correct barycentrics), so its part label is interpolated like the full-surface sampler's. At the default
500 px focal length (a 640 x 480 sensor with a 65 degree field of view) a pixel is 2 mm wide at 1 m and
8 mm at 4 m. Sensor effects, in this order:

* **grazing angles**: pixels whose surface is seen at more than ``grazing_deg`` from its normal return
  nothing (real sensors lose them);
* **edges**: a pixel next to a depth jump of more than ``edge_jump_m`` (or next to an empty pixel: the
  silhouette) is dropped with probability ``edge_dropout``; with probability ``flying`` it becomes a
  *flying pixel*, its depth mixed with the far side of the jump (at the silhouette, up to
  ``flying_max_m`` behind the surface);
* **missing pixels**: every other pixel is dropped with probability ``dropout``;
* **depth noise** along the ray: Gaussian with ``sigma(z) = noise_base_m + noise_quad * z^2`` (z the
  depth in metres; structured-light and time-of-flight sensors grow roughly quadratically), 2 mm at 1 m
  and 1.7 cm at 4 m by default.

Surfaces nearer to the camera than ``NEAR_M`` (0.1 m: depth sensors have a minimum range) return nothing: a
limb of a wide pose can reach the camera, 1 m from the pelvis, or pass behind it, and projecting such
vertices would give an unbounded image (the crop's size is capped at ``MAX_IMAGE_PX`` per side too).

The kept pixels are resampled to the full sampler's point count (without replacement when there are
enough, else every pixel plus repeats moved by 2 mm), so a single-view cloud has the shape of a full one.
Everything is vectorised torch and deterministic given the generator.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import torch

from arteq.data.dataset import BodyScanDataset, seeded_generator
from arteq.geometry.sampling import interpolate_labels

#: Camera placements of the cached view test sets: heading and elevation ranges in degrees (heading 0 =
#: in front of the body, 90 = its left side, 180 = behind it; a side view takes either side).
VIEWS: dict[str, dict[str, tuple[float, float]]] = {
    "front": {"heading": (-30.0, 30.0), "elevation": (-10.0, 30.0)},
    "side": {"heading": (60.0, 120.0), "elevation": (-10.0, 30.0)},
    "back": {"heading": (150.0, 210.0), "elevation": (-10.0, 30.0)},
    "top": {"heading": (0.0, 360.0), "elevation": (60.0, 90.0)},
    # a 640 x 480 sensor 1-2 m in front of the person, which it does not always hold whole (module docstring)
    "near": {
        "heading": (-45.0, 45.0),
        "elevation": (-10.0, 30.0),
        "distance_m": (1.0, 2.0),
        "frame_px": (640, 480),
    },
}
#: Names of the cached single-view test sets (``data.view_splits``), one per entry of :data:`VIEWS`.
VIEW_SPLITS = tuple(f"test_view_{v}" for v in VIEWS)


@dataclass
class SingleViewConfig:
    """The camera and sensor of :func:`single_view_scan` (module docstring); ``prob`` is the share of a
    training stream's clouds that are single-view scans (``data.single_view.prob``)."""

    prob: float = 0.0
    distance_m: tuple[float, float] = (1.0, 4.0)
    elevation_deg: tuple[float, float] = (-30.0, 90.0)  # random views: sin(elevation) uniform in this range
    focal_px: float = 500.0
    noise_base_m: float = 0.001
    noise_quad: float = 0.001  # metres of noise per square metre of depth
    dropout: float = 0.05
    grazing_deg: float = 80.0
    edge_jump_m: float = 0.05
    edge_dropout: float = 0.5
    flying: float = 0.1
    flying_max_m: float = 0.2
    #: the sensor's image (width, height) in pixels, centred on the pelvis; None: cropped to the body
    frame_px: tuple[int, int] | None = None
    #: with ``frame_px``: the share of single views in that frame (the others cropped to the body)
    frame_prob: float = 1.0

    def __post_init__(self) -> None:
        self.distance_m = tuple(float(x) for x in self.distance_m)
        self.elevation_deg = tuple(float(x) for x in self.elevation_deg)
        for name in ("prob", "dropout", "edge_dropout", "flying", "frame_prob"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"data.single_view.{name} is a probability in [0, 1], got {v}")
        lo, hi = self.distance_m
        if not 0.3 <= lo <= hi <= 20.0:
            raise ValueError(
                f"data.single_view.distance_m must be [near, far] in 0.3-20 m, got {self.distance_m}"
            )
        lo, hi = self.elevation_deg
        if not -90.0 <= lo <= hi <= 90.0:
            raise ValueError(f"data.single_view.elevation_deg must be [low, high] in -90..90, got {lo, hi}")
        if not self.focal_px > 0:
            raise ValueError(f"data.single_view.focal_px must be > 0, got {self.focal_px}")
        if self.noise_base_m < 0 or self.noise_quad < 0:
            raise ValueError("data.single_view.noise_base_m and noise_quad must be >= 0")
        if not 0.0 < self.grazing_deg <= 90.0:
            raise ValueError(f"data.single_view.grazing_deg must be in (0, 90], got {self.grazing_deg}")
        if self.frame_px is not None:
            frame = tuple(self.frame_px)
            if len(frame) != 2 or not all(float(x) == int(x) and 16 <= int(x) <= MAX_IMAGE_PX for x in frame):
                raise ValueError(
                    "data.single_view.frame_px must be [width, height] in "
                    f"16-{MAX_IMAGE_PX} px, got {self.frame_px}"
                )
            self.frame_px = (int(frame[0]), int(frame[1]))

    @classmethod
    def from_mapping(cls, cfg: Any) -> SingleViewConfig:
        """From ``data.single_view`` (a mapping, a config, or None: the defaults); unknown keys are errors."""
        from arteq.config import dataclass_from_mapping

        return dataclass_from_mapping(cls, cfg, "data.single_view")

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        if out["frame_px"] is None:  # the keys of the sets cached before the option existed stay as they were
            del out["frame_px"], out["frame_prob"]
        return out


def _u(g: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * float(torch.rand((), generator=g, dtype=torch.float64))


def camera_direction(view: str, cfg: SingleViewConfig, g: torch.Generator) -> tuple[float, float]:
    """``(heading, elevation)`` in degrees of a camera for ``view`` (``any`` or a key of :data:`VIEWS`)."""
    if view == "any":
        s = _u(g, math.sin(math.radians(cfg.elevation_deg[0])), math.sin(math.radians(cfg.elevation_deg[1])))
        return _u(g, 0.0, 360.0), math.degrees(math.asin(max(-1.0, min(1.0, s))))
    if view not in VIEWS:
        raise ValueError(f"view must be 'any' or one of {list(VIEWS)}, got {view!r}")
    heading = _u(g, *VIEWS[view]["heading"])
    if view == "side" and float(torch.rand((), generator=g)) < 0.5:
        heading = -heading
    return heading, _u(g, *VIEWS[view]["elevation"])


def look_at(position: torch.Tensor, target: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """World-to-camera rotation ``[3, 3]`` (rows: image right, image down, viewing direction) of a camera
    at ``position`` looking at ``target`` with ``up`` up in the image (any roll when they are parallel)."""
    fwd = target - position
    fwd = fwd / fwd.norm()
    right = torch.linalg.cross(fwd, up)
    if right.norm() < 1e-6:  # looking along up: any roll
        alt = torch.tensor([1.0, 0.0, 0.0], dtype=fwd.dtype)
        right = torch.linalg.cross(fwd, alt if abs(float(fwd[0])) < 0.9 else alt.roll(1))
    right = right / right.norm()
    down = torch.linalg.cross(fwd, right)
    return torch.stack([right, down, fwd])


#: Nearest depth (metres) the camera measures; nearer triangles are not drawn.
NEAR_M = 0.1
#: Largest crop (pixels per side) of a single-view image; the body at 1 m and 500 px spans about 1000.
MAX_IMAGE_PX = 4096


def rasterize(
    verts_cam: torch.Tensor,
    faces: torch.Tensor,
    focal: float,
    width: int,
    height: int,
    cx: float,
    cy: float,
    cull: bool = True,
    near: float = NEAR_M,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Z-buffer of a mesh in camera coordinates (z > 0 in front of the camera; pinhole ``u = f x / z + cx``,
    pixel ``(i, j)`` has its centre at ``(j + 0.5, i + 0.5)``). ``cull``: skip the triangles turned away
    from the camera (seen clockwise in the image: the inside of a mesh whose triangles run
    counter-clockwise seen from outside, as the body models' do), which a closed surface hides anyway.
    ``near``: triangles with a vertex nearer than this depth (metres) are not drawn.

    Every triangle's barycentric coordinates divided by the vertex depths are linear in the pixel position
    (perspective-correct interpolation): they are evaluated for every (triangle, pixel of its bounding box)
    pair at once; their sum is one over the depth.

    Returns ``face [H, W]`` long (-1 where no surface), ``bary [H, W, 3]`` the 3D barycentric coordinates
    of the pixel's ray on that face, ``depth [H, W]`` (inf where no surface).
    """
    dtype = verts_cam.dtype
    z = verts_cam[:, 2]
    uv = verts_cam[:, :2] / z[:, None] * focal + torch.tensor([cx, cy], dtype=dtype)
    t = uv[faces]  # [F, 3, 2]
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep = (z[faces] > near).all(1) & ((area < -1e-12) if cull else (area.abs() > 1e-12))
    fid = torch.nonzero(keep)[:, 0]
    t, area, tz = t[fid], area[fid], z[faces[fid]]
    # lambda_i(u, v) = (k_i + u * du_i + v * dv_i) / area from the opposite edge (j, k), divided by z_i
    nxt, prv = t.roll(-1, dims=1), t.roll(-2, dims=1)  # vertex j and k opposite vertex i
    k0 = nxt[..., 0] * prv[..., 1] - nxt[..., 1] * prv[..., 0]
    coef = torch.stack([k0, nxt[..., 1] - prv[..., 1], prv[..., 0] - nxt[..., 0]], -1)  # [F, 3 (i), 3]
    coef = coef / (area[:, None, None] * tz[..., None])
    lo = torch.ceil(t.amin(1) - 0.5).long()
    hi = torch.floor(t.amax(1) - 0.5).long()
    lo[:, 0].clamp_(0, width - 1)
    lo[:, 1].clamp_(0, height - 1)
    hi[:, 0].clamp_(-1, width - 1)
    hi[:, 1].clamp_(-1, height - 1)
    size = (hi - lo + 1).clamp_min(0)  # [F, 2] pixels per axis of each bounding box
    count = size[:, 0] * size[:, 1]
    f = torch.repeat_interleave(torch.arange(len(fid)), count)
    off = torch.arange(len(f)) - torch.repeat_interleave(torch.cumsum(count, 0) - count, count)
    col = lo[f, 0] + off % size[f, 0]
    row = lo[f, 1] + torch.div(off, size[f, 0], rounding_mode="floor")
    cf = coef[f]  # [P, 3, 3]
    w = cf[..., 0] + cf[..., 1] * (col.to(dtype) + 0.5)[:, None] + cf[..., 2] * (row.to(dtype) + 0.5)[:, None]
    inside = (w >= 0).all(-1)
    f, w, pix = f[inside], w[inside], (row * width + col)[inside]
    depth = 1.0 / w.sum(-1)
    best = torch.full((height * width,), math.inf, dtype=dtype).scatter_reduce(0, pix, depth, "amin")
    win = depth <= best[pix]
    # one winner per pixel (ties: the lowest pair index), deterministic
    pair = torch.arange(len(f))
    chosen = torch.full((height * width,), len(f), dtype=torch.long).scatter_reduce(
        0, pix[win], pair[win], "amin"
    )
    hit = chosen < len(f)
    face = torch.full((height * width,), -1, dtype=torch.long)
    bary = torch.zeros(height * width, 3, dtype=dtype)
    face[hit] = fid[f[chosen[hit]]]
    bary[hit] = w[chosen[hit]] * depth[chosen[hit], None]
    return face.view(height, width), bary.view(height, width, 3), best.view(height, width)


def _edge_pixels(depth: torch.Tensor, jump: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``(edge [H, W] bool, far [H, W])``: pixels with a surface whose 4-neighbourhood holds an empty pixel or
    a depth more than ``jump`` away, and the farthest such neighbour depth (inf at the silhouette)."""
    pad = torch.nn.functional.pad(depth[None, None], (1, 1, 1, 1), value=math.inf)[0, 0]
    h, w = depth.shape
    nbrs = torch.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    valid = torch.isfinite(depth)
    jumps = (nbrs - depth).abs() > jump  # inf - finite is inf: the silhouette counts
    edge = valid & jumps.any(0)
    far = torch.where(jumps, nbrs, torch.full_like(nbrs, -math.inf)).amax(0)
    return edge, far


def single_view_scan(
    verts: torch.Tensor,
    faces: torch.Tensor,
    lbs_weights: torch.Tensor,
    pelvis: torch.Tensor,
    root_rot: torch.Tensor,
    num_points: int,
    generator: torch.Generator,
    config: SingleViewConfig | None = None,
    view: str = "any",
) -> dict[str, torch.Tensor]:
    """A single-view depth scan of a posed mesh (module docstring).

    Args:
        verts: ``[V, 3]`` posed vertices (metres, world frame); faces ``[F, 3]``; lbs_weights ``[V, K]``.
        pelvis: ``[3]`` the point the camera looks at; root_rot ``[3, 3]`` the pelvis's world rotation
            (its columns: the body's left, up and forward axes; views are relative to them).
        num_points: points returned (the kept pixels resampled).
        generator: the randomness (camera, noise, drop-outs, resampling).
        view: ``any`` (random heading and elevation) or a key of :data:`VIEWS`.
    Returns:
        ``points [n, 3]`` (world frame, float64), ``labels [n]`` long, ``camera [3]`` the camera's
        position (world frame), ``pixels`` the number of pixels kept (0-dim long).
    """
    cfg = config or SingleViewConfig()
    dtype = torch.float64
    verts = verts.double()
    g = generator
    heading, elevation = camera_direction(view, cfg, g)
    spec = VIEWS.get(view, {})
    dist = _u(g, *spec.get("distance_m", cfg.distance_m))
    frame = spec.get("frame_px", cfg.frame_px)
    some_framed = "frame_px" not in spec and frame is not None and cfg.frame_prob < 1.0
    if some_framed and _u(g, 0.0, 1.0) >= cfg.frame_prob:
        # this view cropped to the body (drawn only when some views are: the others' streams stay)
        frame = None
    hd, el = math.radians(heading), math.radians(elevation)
    # body axes: x = left, y = up, z = forward; heading 0 = in front, 90 = at the body's left
    local = torch.tensor(
        [math.cos(el) * math.sin(hd), math.sin(el), math.cos(el) * math.cos(hd)], dtype=dtype
    )
    root = root_rot.to(dtype)
    camera = pelvis.to(dtype) + dist * (root @ local)
    rot = look_at(camera, pelvis.to(dtype), root[:, 1])
    vc = (verts - camera) @ rot.T
    f = float(cfg.focal_px)
    front = vc[:, 2] > NEAR_M  # what a sensor can measure (and project: z -> 0 sends u, v to infinity)
    if not front.any():
        raise RuntimeError("single_view_scan: the whole body is nearer to the camera than its minimum range")
    uv = vc[front, :2] / vc[front, 2:3] * f
    # the crop: the body's projection, at most MAX_IMAGE_PX per side around the pelvis (the image centre), or
    # the part of it inside the sensor's frame
    half_px = [MAX_IMAGE_PX / 2] * 2 if frame is None else [frame[0] / 2, frame[1] / 2]
    half = torch.tensor(half_px, dtype=dtype)
    lo = torch.maximum(uv.amin(0), -half)
    hi = torch.minimum(uv.amax(0), half)
    if (hi <= lo).any():
        raise RuntimeError("single_view_scan: the body is outside the camera's frame")
    width, height = (int(x) + 2 for x in torch.ceil(hi - lo).tolist())
    cx, cy = 1.0 - float(lo[0]), 1.0 - float(lo[1])
    face, bary, depth = rasterize(vc, faces, f, width, height, cx, cy)
    valid = face >= 0
    if not valid.any():
        raise RuntimeError("single_view_scan: the camera sees no surface")

    # grazing angles: |cos| between the face normal and the pixel's ray
    tri = vc[faces]
    n = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    jj, ii = torch.meshgrid(
        torch.arange(width, dtype=dtype), torch.arange(height, dtype=dtype), indexing="xy"
    )
    ray = torch.stack([(jj + 0.5 - cx) / f, (ii + 0.5 - cy) / f, torch.ones_like(jj)], -1)
    ray = ray / ray.norm(dim=-1, keepdim=True)
    cosang = (n[face.clamp_min(0)] * ray).sum(-1).abs()
    keep = valid & (cosang >= math.cos(math.radians(cfg.grazing_deg)))

    edge, far = _edge_pixels(depth, cfg.edge_jump_m)
    r = torch.rand(height, width, generator=g, dtype=torch.float64)
    edge_drop = edge & (r < cfg.edge_dropout)
    flying = edge & ~edge_drop & (r < cfg.edge_dropout + cfg.flying)
    plain_drop = ~edge & (torch.rand(height, width, generator=g, dtype=torch.float64) < cfg.dropout)
    keep = keep & ~edge_drop & ~plain_drop
    mix = torch.rand(height, width, generator=g, dtype=torch.float64).to(dtype)
    far = torch.where(torch.isfinite(far), far, depth + cfg.flying_max_m)
    z = torch.where(flying, depth + mix * (far - depth), depth)
    sigma = cfg.noise_base_m + cfg.noise_quad * z.square()
    z = z + sigma * torch.randn(height, width, generator=g, dtype=torch.float64).to(dtype)

    idx = torch.nonzero(keep.reshape(-1))[:, 0]
    if len(idx) == 0:
        raise RuntimeError("single_view_scan: every pixel was dropped")
    if len(idx) >= num_points:
        pick = idx[torch.randperm(len(idx), generator=g)[:num_points].sort().values]
        jitter = torch.zeros(num_points, 3, dtype=dtype)
    else:
        extra = idx[torch.randint(len(idx), (num_points - len(idx),), generator=g)]
        pick = torch.cat([idx, extra])
        jitter = torch.zeros(num_points, 3, dtype=dtype)
        jitter[len(idx) :] = 0.002 * torch.randn(len(extra), 3, generator=g, dtype=torch.float64).to(dtype)
    zz = z.reshape(-1)[pick]
    pc = ray.reshape(-1, 3)[pick] / ray.reshape(-1, 3)[pick, 2:3] * zz[:, None]  # ray scaled to depth z
    points = pc @ rot + camera + jitter
    labels = interpolate_labels(lbs_weights, faces, face.reshape(-1)[pick], bary.reshape(-1, 3)[pick])
    return {"points": points, "labels": labels, "camera": camera, "pixels": torch.tensor(len(idx))}


class SingleViewDataset(BodyScanDataset):
    """:class:`BodyScanDataset` whose clouds are single-view depth scans (:func:`single_view_scan`).

    ``view``: ``any`` (random cameras) or a key of :data:`VIEWS`; a cloud is a single-view scan with
    probability ``config.prob`` (1 for the view test sets), else a full-surface one as the parent class
    draws it. ``stream``: the split name of the pose, shape and rotation streams (the view test sets share
    ``test_view``: the same bodies seen from every view); the camera has its own stream per view. Other
    arguments as :class:`BodyScanDataset`.
    """

    def __init__(self, *args: Any, config: SingleViewConfig | None = None, view: str = "any", **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.config = config or SingleViewConfig(prob=1.0)
        if view != "any" and view not in VIEWS:
            raise ValueError(f"view must be 'any' or one of {list(VIEWS)}, got {view!r}")
        self.view = view

    def view_spec(self) -> dict[str, Any]:
        """What defines the single-view part of a sample (for cache keys)."""
        return {"view": self.view, **self.config.to_dict()}

    def _surface_points(self, verts, faces, grot, pelvis, key) -> tuple[torch.Tensor, torch.Tensor]:
        if self.config.prob < 1.0:
            u = float(torch.rand((), generator=seeded_generator(*key, "view-mix"), dtype=torch.float64))
            if u >= self.config.prob:
                return super()._surface_points(verts, faces, grot, pelvis, key)
        g = seeded_generator(*key, "camera", self.view)
        scan = single_view_scan(
            verts, faces, self.body.lbs_weights, pelvis, grot[0], self.num_points, g, self.config, self.view
        )
        return scan["points"], scan["labels"]
