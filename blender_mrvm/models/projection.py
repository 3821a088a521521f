"""Project sample points into reference views (OpenCV axes, pixel-centre convention).

The camera-frame coordinates of a point o + t d are computed as ``o_c + t d_c`` where
``o_c = R (o - C)`` and ``d_c = R d`` are formed per ray and view in float64 and only then cast:
a reference camera 1e4 units away loses no precision. Points behind a camera or on its plane
(z <= eps), or projecting outside the image, are masked; their coordinates are replaced by 0 so no
NaN/Inf ever reaches ``grid_sample``.
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


def rays_in_cameras(cams: RefCameras, origins: torch.Tensor, dirs: torch.Tensor):
    """Per view: ray origins and directions in camera coordinates, (V, R, 3) float32 each."""
    R = cams.w2c[:, :3, :3].double()  # (V, 3, 3)
    C = cams.centres.double()
    o = origins.double()[None] - C[:, None, :]  # (V, R, 3)
    o_c = torch.einsum("vij,vrj->vri", R, o)
    d_c = torch.einsum("vij,rj->vri", R, dirs.double())
    return o_c.float(), d_c.float()


def project_samples(cams: RefCameras, o_c: torch.Tensor, d_c: torch.Tensor, t: torch.Tensor,
                    z_eps: float = 1e-6):
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


def sample_maps(maps: torch.Tensor, uv: torch.Tensor, mode: str = "bilinear") -> torch.Tensor:
    """Samples of (V, C, H, W) maps at (V, R, S, 2) -> (V, R, S, C); ``mode`` is ``grid_sample``'s
    ('bilinear', or 'bicubic': sharper, but it can overshoot the maps' range)."""
    V, R, S, _ = uv.shape
    out = torch.nn.functional.grid_sample(maps, uv.to(maps.dtype).view(V, R * S, 1, 2), mode=mode,
                                          padding_mode="border", align_corners=False)
    return out.view(V, -1, R, S).permute(0, 2, 3, 1)
