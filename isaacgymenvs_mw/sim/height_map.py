"""Terrain height lookup on the device (the height scan's, sim/sensors.py): torch only, no host sync."""

from __future__ import annotations

import torch


class HeightMap:
    """Heights on a regular grid (heights[a, b] at x0 + a * spacing, y0 + b * spacing), interpolated the way MuJoCo
    triangulates a heightfield: each grid square is two triangles split along its (a, b)-(a+1, b+1) diagonal, so
    the lookup is the surface the robot collides with. Points off the grid take the nearest edge's height."""

    def __init__(self, heights, x0: float, y0: float, spacing: float, device: str) -> None:
        self.heights = torch.as_tensor(heights, dtype=torch.float32, device=device).contiguous()
        self.x0, self.y0, self.spacing = float(x0), float(y0), float(spacing)
        self.nx, self.ny = self.heights.shape

    def __call__(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        gx = ((x - self.x0) / self.spacing).clamp(0.0, self.nx - 1.0)
        gy = ((y - self.y0) / self.spacing).clamp(0.0, self.ny - 1.0)
        a = gx.floor().clamp(max=self.nx - 2).long()
        b = gy.floor().clamp(max=self.ny - 2).long()
        u, v = gx - a, gy - b
        h = self.heights
        h00, h10, h01, h11 = h[a, b], h[a + 1, b], h[a, b + 1], h[a + 1, b + 1]
        lower = h00 + u * (h10 - h00) + v * (h11 - h10)  # triangle (0,0) (1,0) (1,1): u >= v
        upper = h00 + v * (h01 - h00) + u * (h11 - h01)  # triangle (0,0) (0,1) (1,1): v > u
        return torch.where(u >= v, lower, upper)
