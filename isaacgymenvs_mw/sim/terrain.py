"""Rough-terrain generator: a grid of sub-terrains (rows = difficulty levels, columns = terrain types) as one height
map, the way legged_gym lays out its curriculum terrain. numpy only; the same seed gives the same terrain.

Coordinates: cell (level i, column j) covers x in [i * mapLength, (i + 1) * mapLength) and y in
[j * mapWidth, (j + 1) * mapWidth); a flat border of ``borderSize`` metres surrounds the grid. Height sample
[a, b] sits at x = a * horizontalScale - borderSize, y = b * horizontalScale - borderSize.

Every cell has a flat square platform of ``platformSize`` metres at its centre, where robots spawn. The types,
with difficulty d = level / numLevels (legged_gym's rule):
  smooth_slope       pyramid rising (or, in the first half of its columns, sinking) from the cell's edge to the
                     platform with slope ``d * maxSlope``: h = +-slope * min(e, e_platform), e = distance to the edge
  rough_slope        the same pyramid plus uniform noise in [-roughHeight, roughHeight], quantised to roughStep
  stairs_up          pyramid of steps: h = stepHeight(d) * floor(min(e, e_platform) / stepWidth)
  stairs_down        the same, negative
  discrete_obstacles numObstacles rectangles (sides U(obstacleSize)) raised or sunk by
                     one of {-1, -1/2, 1/2, 1} * obstacleHeight(d); the platform is cleared to 0
  stepping_stones    square stones (side stoneSize(d)) at height 0 on a grid of pitch side + stoneGap(d), from the
                     cell's corner, over a pit ``pitDepth`` deep; the platform is at 0. Off (proportion 0) by default
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from isaacgymenvs_mw.utils.errors import ConfigError

TERRAIN_TYPES = ("smooth_slope", "rough_slope", "stairs_up", "stairs_down", "discrete_obstacles", "stepping_stones")
GROUND_TYPES = ("plane", "heightfield")


@dataclass
class TerrainConfig:
    """``env.terrain`` of the task YAML (docs/config.md "Terrain")."""

    type: str = "plane"
    seed: int = 1
    mapLength: float = 8.0           # m, cell size along x (the level axis)
    mapWidth: float = 8.0            # m, cell size along y (the type axis)
    numLevels: int = 10
    numTerrains: int = 20            # columns, split among the types by proportions
    borderSize: float = 25.0         # m of flat ground around the grid
    horizontalScale: float = 0.1     # m between height samples
    platformSize: float = 3.0        # m, flat square at each cell's centre
    proportions: Mapping[str, float] | None = None
    maxSlope: float = 0.4            # rise over run at the top level
    roughHeight: float = 0.05        # m, +- noise on rough slopes
    roughStep: float = 0.005         # m, noise quantum
    stepHeight: tuple = (0.05, 0.23)  # m at level 0 and at difficulty 1
    stepWidth: float = 0.31          # m
    obstacleHeight: tuple = (0.05, 0.25)
    obstacleSize: tuple = (1.0, 2.0)  # m, rectangle side range
    numObstacles: int = 20
    stoneSize: tuple = (1.575, 0.075)  # m, stone side at difficulty 0 and 1 (legged_gym: 1.5 * (1.05 - d))
    stoneGap: tuple = (0.05, 0.1)    # m between stones at difficulty 0 and 1
    pitDepth: float = 1.0            # m below 0 between the stones
    maxHeightfieldSamples: int = 4_000_000

    def sample_counts(self) -> tuple[int, int, int, int]:
        """(samples per cell along x, along y, border samples, total samples)."""
        px = int(round(self.mapLength / self.horizontalScale))
        py = int(round(self.mapWidth / self.horizontalScale))
        b = int(round(self.borderSize / self.horizontalScale))
        return px, py, b, (self.numLevels * px + 2 * b) * (self.numTerrains * py + 2 * b)


DEFAULT_PROPORTIONS = {"smooth_slope": 0.1, "rough_slope": 0.1, "stairs_up": 0.35, "stairs_down": 0.25,
                       "discrete_obstacles": 0.2, "stepping_stones": 0.0}  # legged_gym's rough-terrain mix


def parse_terrain_config(raw: Mapping | None) -> TerrainConfig:
    """Validate ``env.terrain``; every error names the key and what would be valid."""
    raw = dict(raw or {})
    known = set(TerrainConfig.__dataclass_fields__)
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ConfigError(f"env.terrain: unknown key(s) {unknown}; valid keys: {sorted(known)}")
    cfg = TerrainConfig(**raw)
    if cfg.type not in GROUND_TYPES:
        raise ConfigError(f"env.terrain.type: '{cfg.type}' is not one of {list(GROUND_TYPES)}")
    props = dict(DEFAULT_PROPORTIONS if cfg.proportions is None else cfg.proportions)
    bad = sorted(k for k in props if k not in TERRAIN_TYPES)
    if bad:
        raise ConfigError(f"env.terrain.proportions: unknown terrain type(s) {bad}; valid types: {list(TERRAIN_TYPES)}")
    if any(float(v) < 0 for v in props.values()) or not np.isclose(sum(float(v) for v in props.values()), 1.0):
        raise ConfigError(f"env.terrain.proportions={props} must be >= 0 and sum to 1 (they sum to "
                         f"{sum(float(v) for v in props.values()):.4g}); types: {list(TERRAIN_TYPES)}")
    cfg.proportions = {t: float(props.get(t, 0.0)) for t in TERRAIN_TYPES}
    for key in ("mapLength", "mapWidth", "horizontalScale", "platformSize", "stepWidth"):
        if float(getattr(cfg, key)) <= 0:
            raise ConfigError(f"env.terrain.{key}={getattr(cfg, key)} must be > 0")
    for key in ("numLevels", "numTerrains"):
        if int(getattr(cfg, key)) < 1:
            raise ConfigError(f"env.terrain.{key}={getattr(cfg, key)} must be >= 1")
    for key in ("stepHeight", "obstacleHeight", "obstacleSize", "stoneSize", "stoneGap"):
        value = getattr(cfg, key)
        ordered = key not in ("stoneSize",)  # stones shrink with difficulty
        if len(value) != 2 or (ordered and float(value[0]) > float(value[1])) or min(map(float, value)) < 0:
            rule = "low <= high" if ordered else "both >= 0"
            raise ConfigError(f"env.terrain.{key}={list(value)} is invalid: give [at difficulty 0, at 1] ({rule})")
        setattr(cfg, key, (float(value[0]), float(value[1])))
    if cfg.platformSize > min(cfg.mapLength, cfg.mapWidth):
        raise ConfigError(f"env.terrain.platformSize={cfg.platformSize} is larger than the cell "
                         f"(mapLength={cfg.mapLength}, mapWidth={cfg.mapWidth})")
    if cfg.borderSize < 0:
        raise ConfigError(f"env.terrain.borderSize={cfg.borderSize} must be >= 0")
    px, py, b, total = cfg.sample_counts()
    if cfg.type == "heightfield" and total > cfg.maxHeightfieldSamples:
        raise ConfigError(
            f"env.terrain: the heightfield would have {total:,} samples ({cfg.numLevels * px + 2 * b} x "
            f"{cfg.numTerrains * py + 2 * b}), more than "
            f"env.terrain.maxHeightfieldSamples={cfg.maxHeightfieldSamples:,}"
            "; lower numLevels, numTerrains, mapLength, mapWidth or borderSize, or raise horizontalScale")
    return cfg


@dataclass
class Terrain:
    """A generated terrain: heights[a, b] at x = a * spacing + x0, y = b * spacing + y0 (metres)."""

    heights: np.ndarray              # (nx, ny) float64
    spacing: float
    x0: float
    y0: float
    origins: np.ndarray              # (numLevels, numTerrains, 3): spawn point (platform centre) of each cell
    column_types: list[str]          # terrain type of each column
    config: TerrainConfig


def column_types(cfg: TerrainConfig) -> list[str]:
    """Type of each column: column j has choice = j / numTerrains + 0.001 and takes the first type whose
    cumulative proportion exceeds it (legged_gym's rule)."""
    cum = np.cumsum([cfg.proportions[t] for t in TERRAIN_TYPES])
    last = max(k for k, t in enumerate(TERRAIN_TYPES) if cfg.proportions[t] > 0)  # rounding never picks a 0 share
    out = []
    for j in range(cfg.numTerrains):
        choice = j / cfg.numTerrains + 0.001
        k = int(np.searchsorted(cum, choice, side="right"))
        out.append(TERRAIN_TYPES[min(k, last)])
    return out


def column_sign(cfg: TerrainConfig, j: int) -> float:
    """-1 for the first half of the smooth/rough slope columns (pits), +1 otherwise; -1 for stairs_down."""
    kind = column_types(cfg)[j]
    if kind == "stairs_down":
        return -1.0
    if kind in ("smooth_slope", "rough_slope"):
        cum = np.concatenate(([0.0], np.cumsum([cfg.proportions[t] for t in TERRAIN_TYPES])))
        k = TERRAIN_TYPES.index(kind)
        choice = j / cfg.numTerrains + 0.001
        return -1.0 if choice < cum[k] + 0.5 * cfg.proportions[kind] else 1.0
    return 1.0


def difficulty(cfg: TerrainConfig, level: int) -> float:
    return level / cfg.numLevels


def edge_distance(cfg: TerrainConfig, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Distance (m) from local cell coordinates (x, y) to the nearest cell edge, capped at the platform's edge."""
    cx, cy = 0.5 * cfg.mapLength, 0.5 * cfg.mapWidth
    e = np.minimum(cx - np.abs(x - cx), cy - np.abs(y - cy))
    return np.minimum(e, min(cx, cy) - 0.5 * cfg.platformSize)


def generate_terrain(cfg: TerrainConfig) -> Terrain:
    """The whole height map for ``cfg`` (validated by parse_terrain_config); deterministic in ``cfg.seed``."""
    rng = np.random.default_rng(int(cfg.seed))
    px, py, b, _ = cfg.sample_counts()
    hs = cfg.horizontalScale
    heights = np.zeros((cfg.numLevels * px + 2 * b, cfg.numTerrains * py + 2 * b))
    types = column_types(cfg)
    origins = np.zeros((cfg.numLevels, cfg.numTerrains, 3))
    lx, ly = np.meshgrid(np.arange(px) * hs, np.arange(py) * hs, indexing="ij")
    centre = _on_platform(cfg, lx, ly)
    for i in range(cfg.numLevels):
        for j in range(cfg.numTerrains):
            cell = cell_heights(cfg, types[j], column_sign(cfg, j), difficulty(cfg, i), lx, ly, rng)
            heights[b + i * px:b + (i + 1) * px, b + j * py:b + (j + 1) * py] = cell
            origins[i, j] = ((i + 0.5) * cfg.mapLength, (j + 0.5) * cfg.mapWidth, cell[centre].max())
    return Terrain(heights=heights, spacing=hs, x0=-b * hs, y0=-b * hs, origins=origins, column_types=types,
                   config=cfg)


def cell_heights(cfg: TerrainConfig, kind: str, sign: float, d: float, x: np.ndarray, y: np.ndarray,
                 rng: np.random.Generator) -> np.ndarray:
    """Heights of one cell at local coordinates (x, y) (the formulas of the module docstring)."""
    e = edge_distance(cfg, x, y)
    if kind in ("smooth_slope", "rough_slope"):
        h = sign * d * cfg.maxSlope * e
        if kind == "rough_slope":
            levels = np.arange(-cfg.roughHeight, cfg.roughHeight + 1e-9, cfg.roughStep)
            h = h + rng.choice(levels, size=h.shape)
        return h
    if kind in ("stairs_up", "stairs_down"):
        step = cfg.stepHeight[0] + d * (cfg.stepHeight[1] - cfg.stepHeight[0])
        return sign * step * np.floor(e / cfg.stepWidth + 1e-9)
    if kind == "stepping_stones":
        side = cfg.stoneSize[0] + d * (cfg.stoneSize[1] - cfg.stoneSize[0])
        pitch = side + cfg.stoneGap[0] + d * (cfg.stoneGap[1] - cfg.stoneGap[0])
        on_stone = (np.mod(x + 1e-9, pitch) < side) & (np.mod(y + 1e-9, pitch) < side)
        return np.where(on_stone | _on_platform(cfg, x, y), 0.0, -cfg.pitDepth)
    # discrete_obstacles
    height = cfg.obstacleHeight[0] + d * (cfg.obstacleHeight[1] - cfg.obstacleHeight[0])
    h = np.zeros_like(x)
    for _ in range(cfg.numObstacles):
        w, l = rng.uniform(*cfg.obstacleSize, size=2)
        x0, y0 = rng.uniform(0.0, cfg.mapLength - w), rng.uniform(0.0, cfg.mapWidth - l)
        h[(x >= x0) & (x < x0 + w) & (y >= y0) & (y < y0 + l)] = height * rng.choice([-1.0, -0.5, 0.5, 1.0])
    h[_on_platform(cfg, x, y)] = 0.0
    return h


def _on_platform(cfg: TerrainConfig, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return (np.abs(x - 0.5 * cfg.mapLength) <= 0.5 * cfg.platformSize) & \
           (np.abs(y - 0.5 * cfg.mapWidth) <= 0.5 * cfg.platformSize)


GROUND_PART_PREFIX = "ground/"  # the builder's names for the terrain's parts: ground/cell_<i>_<j>, ground/border_<k>


def ground_geoms(model) -> list[int]:
    """Ids of the geoms that make up the ground: the plane "ground", or a terrain's "ground/..." parts (one
    heightfield per cell and the border boxes, see sim/ground.py)."""
    import mujoco

    names = (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "" for g in range(model.ngeom))
    return [g for g, name in enumerate(names) if name == "ground" or name.startswith(GROUND_PART_PREFIX)]


def heightfield_grid(model) -> dict:
    """The compiled terrain as world heights: {'heights': (nx, ny) array, 'x0', 'y0', 'spacing'} with
    heights[a, b] at (x0 + a * spacing, y0 + b * spacing); read back from ``model``'s ground heightfields (and the
    tops of its border boxes) so a lookup sees exactly the surface MuJoCo collides with (between samples MuJoCo's
    surface is two triangles per square, split along the (a, b)-(a+1, b+1) diagonal)."""
    import mujoco

    parts = ground_geoms(model)
    fields = [g for g in parts if int(model.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_HFIELD)]
    if not fields:
        raise ConfigError("the model has no ground heightfield (env.terrain.type is not heightfield?)")
    half = {g: (model.hfield_size[model.geom_dataid[g]] if g in fields else model.geom_size[g])[:2] for g in parts}
    spacing = float(2.0 * half[fields[0]][0] / (model.hfield_ncol[model.geom_dataid[fields[0]]] - 1))
    # The grid's samples are the heightfields'; the border boxes (a hair wider than their samples) extend it by
    # whole samples.
    origin = np.min([model.geom_pos[g][:2] - half[g] for g in fields], axis=0)
    outer = np.min([model.geom_pos[g][:2] - half[g] for g in parts], axis=0)
    lo = origin - spacing * np.round((origin - outer) / spacing)
    hi = np.max([model.geom_pos[g][:2] + half[g] for g in parts], axis=0)
    heights = np.zeros(tuple(int(round(n)) + 1 for n in (hi - lo) / spacing))

    def index(x: float, axis: int) -> int:
        return int(round((x - lo[axis]) / spacing))

    for g in (g for g in parts if g not in fields):  # boxes first: the heightfields own the grid's edge samples
        (cx, cy, cz), (sx, sy) = model.geom_pos[g], half[g]
        top = cz + model.geom_size[g][2]
        heights[index(cx - sx, 0):index(cx + sx, 0) + 1, index(cy - sy, 1):index(cy + sy, 1) + 1] = top
    for g in fields:
        h = int(model.geom_dataid[g])
        nrow, ncol, adr = int(model.hfield_nrow[h]), int(model.hfield_ncol[h]), int(model.hfield_adr[h])
        rx, ry, rz, _ = model.hfield_size[h]
        data = model.hfield_data[adr:adr + nrow * ncol].reshape(nrow, ncol).astype(np.float64)
        pos = model.geom_pos[g]
        a0, b0 = index(pos[0] - rx, 0), index(pos[1] - ry, 1)
        heights[a0:a0 + ncol, b0:b0 + nrow] = (pos[2] + rz * data).T
    return {"heights": heights, "x0": float(lo[0]), "y0": float(lo[1]), "spacing": spacing}
