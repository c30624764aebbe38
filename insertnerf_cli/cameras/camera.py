"""The one camera type of insertnerf, and the only place where axis conventions are converted.

Convention everywhere inside the package: pinhole intrinsics ``K`` and camera-to-world ``c2w`` in
**OpenCV axes** (x right, y down, z forward). The centre of pixel (col, row) is at (col + 0.5, row + 0.5)
in the image plane, as in COLMAP. Readers and writers of other conventions (OpenGL/Blender/nerfstudio,
LLFF) call the converters in this file and nowhere else.

Glossary (docs/conventions.md): N cameras, P points, H, W image height and width.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

# Flipping the y and z camera axes maps OpenGL (y up, z back) to OpenCV (y down, z forward) and back:
# the matrix is its own inverse.
_GL_CV_FLIP = (1.0, -1.0, -1.0, 1.0)


def check_shape(name: str, tensor: Tensor, shape: Sequence[int | None]) -> None:
    """Raise ValueError unless ``tensor.shape`` matches ``shape`` (None = any size)."""
    if tensor.dim() != len(shape) or any(s is not None and s != t for s, t in zip(shape, tensor.shape)):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise ValueError(f"{name} must have shape {want}, got {list(tensor.shape)}")


def opengl_to_opencv(c2w: Tensor) -> Tensor:
    """Camera-to-world [..., 4, 4] from OpenGL camera axes to OpenCV camera axes (and back: an involution).

    Blender, NeRF-Synthetic, nerfstudio and instant-ngp store OpenGL c2w; flipping the camera's y and z
    columns re-expresses the same pose with OpenCV axes.
    """
    flip = torch.tensor(_GL_CV_FLIP, dtype=c2w.dtype, device=c2w.device)
    return c2w * flip  # scales columns: c2w @ diag(flip)


opencv_to_opengl = opengl_to_opencv


def llff_to_opencv(poses: Tensor) -> Tensor:
    """LLFF ``poses_bounds`` rotation+centre [N, 3, 4] with axes [down, right, back] -> OpenCV c2w [N, 4, 4].

    LLFF inherited its column order from an old COLMAP-to-OpenGL script; OpenCV x = right = column 1,
    y = down = column 0, z = forward = -back = -column 2.
    """
    check_shape("poses", poses, (None, 3, 4))
    c2w = torch.zeros(poses.shape[0], 4, 4, dtype=poses.dtype, device=poses.device)
    c2w[:, :3, 0] = poses[:, :, 1]
    c2w[:, :3, 1] = poses[:, :, 0]
    c2w[:, :3, 2] = -poses[:, :, 2]
    c2w[:, :3, 3] = poses[:, :, 3]
    c2w[:, 3, 3] = 1.0
    return c2w


def w2c_to_c2w(w2c: Tensor) -> Tensor:
    """Rigid inverse [..., 4, 4] (world-to-camera, as COLMAP and DTU store it, to camera-to-world)."""
    rot = w2c[..., :3, :3]
    out = torch.zeros_like(w2c)
    out[..., :3, :3] = rot.transpose(-1, -2)
    out[..., :3, 3] = -(rot.transpose(-1, -2) @ w2c[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


c2w_to_w2c = w2c_to_c2w


def intrinsics(fx: float, fy: float, cx: float, cy: float, dtype: torch.dtype = torch.float64) -> Tensor:
    """A pinhole K [3, 3]."""
    return torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=dtype)


@dataclass(frozen=True)
class Cameras:
    """N pinhole cameras sharing one image size.

    Attributes:
        K: intrinsics [N, 3, 3], in pixels of a ``height`` x ``width`` image.
        c2w: camera-to-world [N, 4, 4], OpenCV axes.
        height, width: image size in pixels.
    """

    K: Tensor  # [N, 3, 3]
    c2w: Tensor  # [N, 4, 4]
    height: int
    width: int

    def __post_init__(self) -> None:
        check_shape("K", self.K, (None, 3, 3))
        check_shape("c2w", self.c2w, (self.K.shape[0], 4, 4))
        if self.height <= 0 or self.width <= 0:
            raise ValueError(f"image size must be positive, got {self.height}x{self.width}")

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_opengl(cls, K: Tensor, c2w_gl: Tensor, height: int, width: int) -> "Cameras":
        """Build from OpenGL c2w [N, 4, 4] (Blender/nerfstudio/instant-ngp)."""
        return cls(K=K, c2w=opengl_to_opencv(c2w_gl), height=height, width=width)

    @classmethod
    def from_w2c(cls, K: Tensor, w2c: Tensor, height: int, width: int) -> "Cameras":
        """Build from OpenCV world-to-camera [N, 4, 4] (COLMAP, DTU)."""
        return cls(K=K, c2w=w2c_to_c2w(w2c), height=height, width=width)

    # ------------------------------------------------------------------ views
    def __len__(self) -> int:
        return self.K.shape[0]

    @property
    def device(self) -> torch.device:
        return self.c2w.device

    @property
    def dtype(self) -> torch.dtype:
        return self.c2w.dtype

    @property
    def w2c(self) -> Tensor:
        """World-to-camera [N, 4, 4]."""
        return c2w_to_w2c(self.c2w)

    @property
    def c2w_opengl(self) -> Tensor:
        """Camera-to-world [N, 4, 4] in OpenGL axes, for writers of Blender/nerfstudio files."""
        return opencv_to_opengl(self.c2w)

    @property
    def centers(self) -> Tensor:
        """Camera centres [N, 3] in world units."""
        return self.c2w[:, :3, 3]

    @property
    def forward(self) -> Tensor:
        """Optical axes [N, 3] (unit camera +z in world)."""
        return self.c2w[:, :3, 2]

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> "Cameras":
        return Cameras(self.K.to(device=device, dtype=dtype), self.c2w.to(device=device, dtype=dtype),
                       self.height, self.width)

    def subset(self, index: Sequence[int] | Tensor | slice) -> "Cameras":
        """The cameras at ``index`` (a list/tensor of indices or a slice), same image size."""
        if not isinstance(index, slice):
            index = torch.as_tensor(index, dtype=torch.long, device=self.K.device).reshape(-1)
        return Cameras(self.K[index], self.c2w[index], self.height, self.width)

    __getitem__ = subset

    @staticmethod
    def cat(cameras: Sequence["Cameras"]) -> "Cameras":
        """Concatenate cameras of one image size."""
        sizes = {(c.height, c.width) for c in cameras}
        if len(sizes) != 1:
            raise ValueError(f"cannot concatenate cameras of different image sizes: {sorted(sizes)}")
        return Cameras(torch.cat([c.K for c in cameras]), torch.cat([c.c2w for c in cameras]),
                       cameras[0].height, cameras[0].width)

    def rescale(self, height: int, width: int) -> "Cameras":
        """The same cameras for images resized to ``height`` x ``width``.

        With pixel centres at +0.5 a resize scales the image plane uniformly, so fx, cx scale by
        width ratio and fy, cy by height ratio, with no half-pixel correction.
        """
        sx, sy = width / self.width, height / self.height
        scale = torch.tensor([sx, sy, 1.0], dtype=self.K.dtype, device=self.K.device)
        return Cameras(self.K * scale[:, None], self.c2w, height, width)

    def transform(self, rotation: Tensor, translation: Tensor, scale: float) -> "Cameras":
        """Apply the world similarity x' = scale * R x + t (R [3, 3], t [3]) to every camera."""
        c2w = self.c2w.clone()
        c2w[:, :3, :3] = rotation.to(c2w) @ self.c2w[:, :3, :3]
        c2w[:, :3, 3] = scale * (self.c2w[:, :3, 3] @ rotation.to(c2w).T) + translation.to(c2w)
        return Cameras(self.K, c2w, self.height, self.width)

    # ------------------------------------------------------------------ geometry
    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Project world points into every camera.

        Args:
            points: [N, P, 3] (points per camera) or [P, 3] (the same points for all cameras).
        Returns:
            uv: [N, P, 2] pixel coordinates (pixel (0, 0) spans [0, 1] x [0, 1]).
            depth: [N, P] z in the camera frame (positive in front).
        """
        if points.dim() == 2:
            points = points.expand(len(self), -1, -1)
        check_shape("points", points, (len(self), None, 3))
        w2c = self.w2c.to(points)
        cam = points @ w2c[:, :3, :3].transpose(1, 2) + w2c[:, None, :3, 3]  # [N, P, 3]
        depth = cam[..., 2]
        pix = cam @ self.K.to(points).transpose(1, 2)  # [N, P, 3]
        uv = pix[..., :2] / _safe(depth)[..., None]
        return uv, depth

    def unproject(self, uv: Tensor, depth: Tensor) -> Tensor:
        """Inverse of :meth:`project`: pixels uv [N, P, 2] at camera depth z [N, P] -> world points [N, P, 3]."""
        check_shape("uv", uv, (len(self), None, 2))
        check_shape("depth", depth, (len(self), uv.shape[1]))
        ones = torch.ones_like(uv[..., :1])
        rays_cam = torch.cat([uv, ones], dim=-1) @ torch.linalg.inv_ex(self.K.to(uv))[0].transpose(1, 2)  # z = 1
        cam = rays_cam * depth[..., None]
        c2w = self.c2w.to(uv)
        return cam @ c2w[:, :3, :3].transpose(1, 2) + c2w[:, None, :3, 3]

    def pixel_grid(self) -> Tensor:
        """Pixel-centre coordinates [H, W, 2] (u, v); add half a pixel to shoot rays through pixel centres."""
        v, u = torch.meshgrid(torch.arange(self.height, dtype=self.dtype, device=self.device),
                              torch.arange(self.width, dtype=self.dtype, device=self.device), indexing="ij")
        return torch.stack([u, v], dim=-1) + 0.5

    def ray_directions(self, uv: Tensor) -> Tensor:
        """World-space ray directions [N, P, 3] through pixels uv [N, P, 2], scaled so camera-z = 1.

        Keeping z = 1 (not unit length) makes the ray parameter t equal to the camera depth.
        """
        check_shape("uv", uv, (len(self), None, 2))
        ones = torch.ones_like(uv[..., :1])
        rays_cam = torch.cat([uv, ones], dim=-1) @ torch.linalg.inv_ex(self.K.to(uv))[0].transpose(1, 2)
        return rays_cam @ self.c2w.to(uv)[:, :3, :3].transpose(1, 2)


def _safe(depth: Tensor) -> Tensor:
    """Depth with its sign kept but magnitude at least 1e-8, so points on the camera plane do not divide by 0."""
    return torch.where(depth.abs() < 1e-8, torch.full_like(depth, 1e-8), depth)
