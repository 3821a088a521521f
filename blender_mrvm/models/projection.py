"""Project sample points into reference views (OpenCV axes, pixel-centre convention).

The camera-frame coordinates of a point o + t d are computed as ``o_c + t d_c`` where
``o_c = R (o - C)`` and ``d_c = R d`` are formed per ray and view in float64 and only then cast:
a reference camera 1e4 units away loses no precision. Points behind a camera or on its plane
(z <= eps), or projecting outside the image, are masked; their coordinates are replaced by 0 so no
NaN/Inf ever reaches ``grid_sample``.

Several objects in one pass (:class:`ObjectBatch`, training on a GPU): the cameras hold every object's V views
in turn (B * V of them) and each ray names its object; the functions then use each ray's own object's views.
Without a batch (``batch=None``) they are what they were, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class RefCameras:
    """Reference cameras in the normalised frame."""

    w2c: torch.Tensor
    """(V, 4, 4) float64 world-to-camera, OpenCV axes."""
    K: torch.Tensor
    """(V, 3, 3) float64 intrinsics in pixels of each view's image."""
    width: int
    """Reference image width, pixels."""
    height: int
    """Reference image height, pixels."""

    @property
    def centres(self) -> torch.Tensor:
        """(V, 3) float64 camera centres."""
        R, t = self.w2c[:, :3, :3], self.w2c[:, :3, 3]
        return -(R.transpose(1, 2) @ t[..., None])[..., 0]

    def __len__(self) -> int:
        return self.w2c.shape[0]


@dataclass
class ObjectBatch:
    """The rays of B objects rendered in one pass: ray n belongs to object ``obj[n]`` and holds slot ``pos[n]``
    of that object's rays; the cameras (:class:`RefCameras`) hold object b's V views at rows b*V .. b*V+V-1.

    Per-object feature maps are sampled as one ``grid_sample`` call over all B * V maps, each object's rays
    padded to ``slots``: the same arithmetic per map as one object at a time."""

    obj: torch.Tensor
    """(N,) int64 object of each ray."""
    pos: torch.Tensor
    """(N,) int64 slot of each ray among its object's (unique per object, < ``slots``)."""
    groups: int
    """B, the number of objects."""
    views: int
    """V, reference views per object."""
    slots: int
    """Ray slots per object in the padded layout (the largest object's ray count)."""

    @classmethod
    def from_counts(cls, counts, views: int, device=None) -> "ObjectBatch":
        """Rays laid out object after object, ``counts[b]`` of object b."""
        c = torch.as_tensor(list(counts), dtype=torch.int64, device=device)
        obj = torch.repeat_interleave(torch.arange(len(c), device=device), c)
        start = torch.cumsum(c, 0) - c
        pos = torch.arange(len(obj), device=device) - start[obj]
        return cls(obj, pos, len(c), int(views), int(c.max()) if len(c) else 0)

    def select(self, idx) -> "ObjectBatch":
        """The same batch for a subset of its rays."""
        return ObjectBatch(self.obj[idx], self.pos[idx], self.groups, self.views, self.slots)

    def per_ray(self, x: torch.Tensor) -> torch.Tensor:
        """Per-camera rows (B * V, ...) -> each ray's own object's views (V, N, ...)."""
        return x.reshape(self.groups, self.views, *x.shape[1:])[self.obj].transpose(0, 1)


@dataclass(kw_only=True)
class ObjectRefs:
    """What an encoded context (every model kind's) knows of the objects its reference views belong to: its rows are
    ``groups`` objects' views in turn, and ``batch`` (set for a render) says which object each ray belongs to."""

    groups: int = 1
    """Objects whose views these are (B; ``RayModel.encode_batch``)."""
    batch: ObjectBatch | None = None
    """Which object each rendered ray belongs to (``RayModel.render_rays_batch``); None for one object."""

    @property
    def views(self) -> int:
        """Reference views per object."""
        return len(self.cams) // self.groups

    def rays_of(self, idx) -> ObjectBatch | None:
        """The object layout of the subset ``idx`` of the rays (None for one object)."""
        return None if self.batch is None else self.batch.select(idx)


def rays_in_cameras(cams: RefCameras, origins: torch.Tensor, dirs: torch.Tensor, batch: ObjectBatch | None = None):
    """Per view: ray origins and directions in camera coordinates, (V, R, 3) float32 each."""
    if batch is not None:
        R = batch.per_ray(cams.w2c[:, :3, :3].double())  # (V, R, 3, 3)
        o = origins.double()[None] - batch.per_ray(cams.centres.double())
        return (torch.einsum("vrij,vrj->vri", R, o).float(),
                torch.einsum("vrij,rj->vri", R, dirs.double()).float())
    R = cams.w2c[:, :3, :3].double()  # (V, 3, 3)
    C = cams.centres.double()
    o = origins.double()[None] - C[:, None, :]  # (V, R, 3)
    o_c = torch.einsum("vij,vrj->vri", R, o)
    d_c = torch.einsum("vij,rj->vri", R, dirs.double())
    return o_c.float(), d_c.float()


def camera_to_world(cams: RefCameras, p: torch.Tensor, batch: ObjectBatch | None = None) -> torch.Tensor:
    """Camera-frame vectors (V, R, S, 3) of each view -> world frame (R^T p), float32."""
    Rw = cams.w2c[:, :3, :3].float()
    if batch is not None:
        return torch.einsum("vrji,vrsj->vrsi", batch.per_ray(Rw), p)
    return torch.einsum("vji,vrsj->vrsi", Rw, p)


def project_samples(cams: RefCameras, o_c: torch.Tensor, d_c: torch.Tensor, t: torch.Tensor,
                    z_eps: float = 1e-6, batch: ObjectBatch | None = None):
    """Project samples at distances ``t`` (R, S) of rays given in camera coordinates (V, R, 3).

    Returns ``uv`` (V, R, S, 2) in grid_sample coordinates ([-1, 1], align_corners=False),
    ``valid`` (V, R, S) bool, and the camera-frame points (V, R, S, 3).
    """
    p = o_c[:, :, None, :] + t[None, :, :, None] * d_c[:, :, None, :]  # (V, R, S, 3)
    z = p[..., 2]
    scale = p.detach().abs().amax(-1).clamp_min(1e-30)
    front = z > z_eps * scale
    zs = torch.where(front, z, torch.ones_like(z))
    K = cams.K.float()
    if batch is not None:  # each ray's own object's intrinsics, (V, R, 1)
        K = batch.per_ray(K)
        fx, fy, cx, cy, sk = (K[..., i, j][..., None] for i, j in ((0, 0), (1, 1), (0, 2), (1, 2), (0, 1)))
    else:
        fx, fy = K[:, 0, 0].view(-1, 1, 1), K[:, 1, 1].view(-1, 1, 1)
        cx, cy = K[:, 0, 2].view(-1, 1, 1), K[:, 1, 2].view(-1, 1, 1)
        sk = K[:, 0, 1].view(-1, 1, 1)
    u = (fx * p[..., 0] + sk * p[..., 1]) / zs + cx
    v = fy * p[..., 1] / zs + cy
    # Pixel coordinates (0..W with pixel centres at i + 0.5) -> [-1, 1] (align_corners=False).
    gu = 2.0 * u / cams.width - 1.0
    gv = 2.0 * v / cams.height - 1.0
    inside = (gu >= -1.0) & (gu <= 1.0) & (gv >= -1.0) & (gv <= 1.0)
    valid = front & inside & torch.isfinite(gu) & torch.isfinite(gv)
    uv = torch.stack([torch.where(valid, gu, torch.zeros_like(gu)), torch.where(valid, gv, torch.zeros_like(gv))], -1)
    return uv, valid, p


def sample_maps(maps: torch.Tensor, uv: torch.Tensor, mode: str = "bilinear",
                batch: ObjectBatch | None = None) -> torch.Tensor:
    """Samples of (V, C, H, W) maps at (V, R, S, 2) -> (V, R, S, C); ``mode`` is ``grid_sample``'s
    ('bilinear', or 'bicubic': sharper, but it can overshoot the maps' range). With a ``batch`` the maps are
    (B * V, C, H, W), and each ray samples its own object's."""
    V, R, S, _ = uv.shape
    if batch is not None:
        B, M = batch.groups, batch.slots
        grid = uv.new_zeros(V, B, M, S, 2, dtype=maps.dtype)
        grid[:, batch.obj, batch.pos] = uv.to(maps.dtype)
        grid = grid.transpose(0, 1).reshape(B * V, M * S, 1, 2)
        out = torch.nn.functional.grid_sample(maps, grid, mode=mode, padding_mode="border", align_corners=False)
        out = out.view(B, V, -1, M, S)[batch.obj, :, :, batch.pos]  # (R, V, C, S)
        return out.permute(1, 0, 3, 2)
    out = torch.nn.functional.grid_sample(maps, uv.to(maps.dtype).view(V, R * S, 1, 2), mode=mode,
                                          padding_mode="border", align_corners=False)
    return out.view(V, -1, R, S).permute(0, 2, 3, 1)
