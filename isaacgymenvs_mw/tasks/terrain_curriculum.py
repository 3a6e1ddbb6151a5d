"""The ground a legged task walks on: flat, or a generated terrain with legged_gym's curriculum.

``ground_from_config(env.terrain)`` gives ``FlatGround`` (no ``env.terrain``, or ``type: plane``), which adds nothing
and changes nothing, or ``TerrainCurriculum`` (``type: heightfield``): a grid of sub-terrains (sim/terrain.py; rows
are difficulty levels, columns types) in which each env owns a cell (level, column) and spawns on its platform. At
reset legged_gym's curriculum moves an env a level up when it walked farther than half a cell, a level down when it
walked less than half of what its command asked for, and to a random level once past the top. A grid of height
samples around the base (the height scan) goes to the critic, and to the policy with ``env.terrain.measureHeights``.
Both have the same methods, so LeggedTask (tasks/legged_task.py) never asks which one it has.
"""

from __future__ import annotations

from typing import Callable

import torch

from isaacgymenvs_mw.sim import HeightScan, ModelRequest, Terrain, generate_terrain, parse_terrain_config
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, Metric
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.utils.errors import ConfigError

# The terrain curriculum's mean level, the terrain tasks' success (their target is a level: a robot is promoted for
# walking its terrain).
TERRAIN_LEVEL = Metric("terrain_level", EPISODE_SUM, success=True)

# env.terrain keys the task reads (the generator's are in sim/terrain.TerrainConfig), with their defaults
TASK_TERRAIN_KEYS = {
    "curriculum": True, "maxInitLevel": 5, "spawnJitter": 0.5, "measureHeights": True,
    "scanLength": 1.6, "scanWidth": 1.0, "scanPointsX": 17, "scanPointsY": 11, "scanHeightOffset": 0.5,
}


class FlatGround:
    """The ground plane: no cells, no curriculum, no height scan; heights are world z."""

    terrain: Terrain | None = None

    def add_to(self, request: ModelRequest) -> None:
        """Nothing to add to the model: the plane is ``env.plane``'s."""

    def bind(self, task) -> None:
        """No per-env state."""

    def place(self, task, mask: torch.Tensor, root_pos: torch.Tensor) -> torch.Tensor:
        """Where the resetting envs start: the base's initial position, as given."""
        return root_pos

    def observation_terms(self, scales: dict, for_policy: bool) -> list[ObsTerm]:
        """The ground's observation terms for the policy (``for_policy``) or the critic; ``scales``: the task's
        ``env.obsScales`` by term."""
        return []

    def metrics(self) -> list[Metric]:
        return []

    def evaluation_groups(self) -> dict[str, torch.Tensor]:
        return {}

    def height_above(self, pos: torch.Tensor) -> torch.Tensor:
        """Height (m) of points (..., 3) above the ground under them."""
        return pos[..., 2]


class TerrainCurriculum(FlatGround):
    """A generated heightfield terrain, each env on a cell, moved between levels by legged_gym's curriculum."""

    def __init__(self, terrain: Terrain, settings: dict) -> None:
        cfg = terrain.config
        top = cfg.numLevels - 1
        if not 0 <= int(settings["maxInitLevel"]) <= top:
            raise ConfigError(f"env.terrain.maxInitLevel={settings['maxInitLevel']} must be in [0, {top}] "
                              f"(numLevels={cfg.numLevels})")
        half = 0.5 * cfg.platformSize
        if not 0.0 <= float(settings["spawnJitter"]) < half:
            raise ConfigError(f"env.terrain.spawnJitter={settings['spawnJitter']} must be in [0, platformSize/2 = "
                              f"{half}): robots spawn on the cell's flat platform")
        for key in ("scanPointsX", "scanPointsY"):
            if int(settings[key]) < 1:
                raise ConfigError(f"env.terrain.{key}={settings[key]} must be >= 1")
        self.terrain, self.settings = terrain, settings
        self.num_levels, self.cell_length = cfg.numLevels, cfg.mapLength
        self.curriculum = bool(settings["curriculum"])
        self.spawn_jitter = float(settings["spawnJitter"])
        self.measure_heights = bool(settings["measureHeights"])
        self.scan_offset = float(settings["scanHeightOffset"])

    def add_to(self, request: ModelRequest) -> None:
        """The heightfield replaces the plane (and takes its friction); the height scan becomes a sensor."""
        if request.ground is None:
            raise ConfigError("env.terrain.type: heightfield replaces the ground plane and takes its friction: set "
                              "env.plane.enabled: True (env.plane.friction is the terrain's friction)")
        request.terrain = self.terrain
        s = self.settings
        scan = HeightScan(s["scanLength"], s["scanWidth"], s["scanPointsX"], s["scanPointsY"])
        request.declared_sensors = (*request.declared_sensors, scan)

    def bind(self, task) -> None:
        """Per-env cells and curriculum levels, the device height map and the height-scan points."""
        n, dev, cfg = task.num_envs, task.device, self.terrain.config
        self._root_pos: Callable[[], torch.Tensor] = lambda: task.sim.root_pos
        # What MuJoCo collides with, read back from the model: the height scan's lookup of any point (sim/sensors.py).
        self.height_map = task.sim.sensors.get("height_scan").height_map
        self.terrain_origins = torch.tensor(self.terrain.origins, device=dev, dtype=torch.float)
        init_top = int(self.settings["maxInitLevel"]) if self.curriculum else cfg.numLevels - 1
        self.terrain_levels = torch.randint(0, init_top + 1, (n,), device=dev)
        # Envs spread evenly over the columns (types), legged_gym's assignment.
        self.terrain_types = torch.div(torch.arange(n, device=dev) * cfg.numTerrains, n, rounding_mode="floor")
        self.env_origins = self.terrain_origins[self.terrain_levels, self.terrain_types].clone()
        # Terrain heights under the scan points, refreshed by the step's sense phase (sim/sensors.py, HeightScan).
        self.measured_heights = task.sim.sensor("height_scan")
        self._started = False  # the first (full) reset places envs; later resets move them

    def update_curriculum(self, mask: torch.Tensor, commands: torch.Tensor, episode_s: float,
                          nonfinite: torch.Tensor) -> None:
        """legged_gym's rule for the resetting envs of ``mask``: up past half a cell, down under half the distance
        ``commands`` asked for over ``episode_s``, a random level once past the top."""
        if not self.curriculum:
            return
        if not self._started:  # the envs' first placement is no episode: nothing walked yet
            self._started = True
            return
        walked = torch.norm(self._root_pos()[:, :2] - self.env_origins[:, :2], dim=1)
        up = walked > 0.5 * self.cell_length
        asked = torch.norm(commands[:, :2], dim=1) * episode_s * 0.5
        down = (walked < asked) & ~up
        level = self.terrain_levels + up.long() - down.long()
        level = torch.where(level >= self.num_levels, torch.randint_like(level, self.num_levels), level.clamp(min=0))
        # A blown-up world's position is the model's initial one, not where it walked: its level stays.
        self.terrain_levels[:] = torch.where(mask & ~nonfinite, level, self.terrain_levels)
        self.env_origins[:] = self.terrain_origins[self.terrain_levels, self.terrain_types]

    def place(self, task, mask: torch.Tensor, root_pos: torch.Tensor) -> torch.Tensor:
        """Move the resetting envs on the curriculum, then start each on its cell's platform, jittered; record the
        mean level, weighted by the episodes ending now (the learner divides by their count)."""
        self.update_curriculum(mask, task.commands, task.max_episode_length_s, task.nonfinite_buf)
        jitter = self.spawn_jitter * (2.0 * torch.rand(task.num_envs, 2, device=task.device) - 1.0)
        root_pos = root_pos + self.env_origins
        task.metrics.record(TERRAIN_LEVEL, self.terrain_levels.float().mean() * mask.sum())
        return torch.cat((root_pos[:, :2] + jitter, root_pos[:, 2:]), dim=1)

    def observation_terms(self, scales: dict, for_policy: bool) -> list[ObsTerm]:
        """The height scan (scaled by ``heightMeasurements``): the policy's with ``measureHeights``, else the
        critic's."""
        if for_policy != self.measure_heights:
            return []
        return [ObsTerm("height_scan", self.measured_heights.shape[1], scales["heightMeasurements"],
                        compute=self._height_scan)]

    def _height_scan(self) -> torch.Tensor:
        """Base height above each scan point minus scanHeightOffset, clipped to ±1 m (legged_gym's measurement)."""
        return (self._root_pos()[:, 2:3] - self.scan_offset - self.measured_heights).clamp(-1.0, 1.0)

    def metrics(self) -> list[Metric]:
        return [TERRAIN_LEVEL]

    def evaluation_groups(self) -> dict[str, torch.Tensor]:
        # Test mode reports survival and tracking per curriculum level (eval.json's per_terrain_level).
        return {"terrain_level": self.terrain_levels}

    def height_above(self, pos: torch.Tensor) -> torch.Tensor:
        return pos[..., 2] - self.height_map(pos[..., 0], pos[..., 1])


def ground_from_config(raw) -> FlatGround:
    """``env.terrain``: None (or type plane) keeps the flat ground; heightfield generates the terrain now, before the
    model is built."""
    if raw is None:
        return FlatGround()
    raw = dict(raw)
    settings = {k: raw.pop(k, default) for k, default in TASK_TERRAIN_KEYS.items()}
    cfg = parse_terrain_config(raw)
    if cfg.type == "plane":
        return FlatGround()
    return TerrainCurriculum(generate_terrain(cfg), settings)
