"""The ground of a scene: a plane or a generated height map's heightfields (sim/terrain.py), and the collision bits
that decide what touches it (sim/builder.py composes the model)."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from isaacgymenvs_mw.sim.terrain import GROUND_PART_PREFIX, Terrain

# Collision bits: robot geoms touch only the ground unless self-collisions are asked for.
GROUND_BIT = 1
ROBOT_BIT = 2


@dataclass
class GroundPlane:
    friction: float = 1.0


def add_ground(spec: mujoco.MjSpec, plane: GroundPlane, terrain: Terrain | None, collide_bits: tuple[int, int],
               keep_asset_contacts: bool) -> list[mujoco.MjsGeom]:
    """The ground's geoms: an infinite plane, or the parts of ``terrain``, colliding by ``collide_bits``."""
    parts = terrain_parts(spec, terrain) if terrain is not None else [("ground", {
        "type": mujoco.mjtGeom.mjGEOM_PLANE, "size": [0.0, 0.0, 0.05]})]  # zero half-sizes: an infinite plane
    ground = []
    for name, shape in parts:
        ground.append(spec.worldbody.add_geom(
            name=name,
            **shape,
            friction=[plane.friction, 0.005, 0.0001],
            contype=collide_bits[0],
            conaffinity=collide_bits[1],
            # Framework filter: the ground's friction and condim decide the contact. Asset contacts kept:
            # equal priority, so MuJoCo's mixing (the larger friction, the larger condim) lets the asset's
            # settings count.
            condim=1 if keep_asset_contacts else 3,
            priority=0 if keep_asset_contacts else 1,
        ))
    return ground


def terrain_parts(spec: mujoco.MjSpec, terrain: Terrain) -> list[tuple[str, dict]]:
    """The ground of a generated height map as (geom name, shape arguments): one heightfield per cell, each holding
    its cell's samples plus the first row and column after it (and on the grid's low edges the border's last sample
    before it), so the surface between samples is the one a single heightfield would have; and four flat boxes with
    their tops at z = 0 for the border.

    One heightfield per cell, not one for the map: MuJoCo Warp 4.0's heightfield collision loses precision with
    the distance from the heightfield's centre. On a 130 m x 210 m map, 5-10 % of foot spheres more than 20 m from
    it got a contact metres deep at a wrong place, which blew the world up.
    Within a cell, no point is more than ~6 m from its heightfield's centre. MuJoCo stores heights normalised to
    [0, 1] times the elevation range, above the geom's z; rows run along y, columns along x.
    """
    cfg, h, hs = terrain.config, terrain.heights, terrain.spacing
    px, py, b, _ = cfg.sample_counts()
    edge = 1 if b > 0 else 0  # cells on the grid's low edges also take the border's last sample before them
    parts = []
    for i in range(cfg.numLevels):
        for j in range(cfg.numTerrains):
            a0, b0 = b + i * px - (edge if i == 0 else 0), b + j * py - (edge if j == 0 else 0)
            tile = h[a0:b + (i + 1) * px + 1, b0:b + (j + 1) * py + 1]
            low, span = float(tile.min()), max(float(np.ptp(tile)), 1e-3)  # flat tiles need a positive range
            nx, ny = tile.shape
            rx, ry = 0.5 * (nx - 1) * hs, 0.5 * (ny - 1) * hs
            name = f"{GROUND_PART_PREFIX}cell_{i}_{j}"
            field = spec.add_hfield(name=name, nrow=ny, ncol=nx, size=[rx, ry, span, 1.0])  # 1 m thick base
            field.userdata = ((tile - low) / span).T.astype(np.float32).ravel().tolist()
            parts.append((name, {"type": mujoco.mjtGeom.mjGEOM_HFIELD, "hfieldname": name,
                                     "pos": [terrain.x0 + a0 * hs + rx, terrain.y0 + b0 * hs + ry, low]}))
    if b > 0:
        # Border strips, flat at 0 where the heightfields end: x below and above the grid over the full width,
        # then y below and above along the grid.
        x_lo, y_lo = terrain.x0, terrain.y0
        x_hi, y_hi = terrain.x0 + (h.shape[0] - 1) * hs, terrain.y0 + (h.shape[1] - 1) * hs
        gx, gy = cfg.numLevels * px * hs, cfg.numTerrains * py * hs  # the grid spans [0, gx] x [0, gy]
        for k, (x0, x1, y0, y1) in enumerate([(x_lo, -hs, y_lo, y_hi), (gx, x_hi, y_lo, y_hi),
                                              (-hs, gx, y_lo, -hs), (-hs, gx, gy, y_hi)]):
            if x1 - x0 > 1e-9 and y1 - y0 > 1e-9:
                # 0.1 mm wider on every side: no seam for a ray or a contact where a box meets a heightfield or
                # where the map ends (both are at height 0 there).
                parts.append((f"{GROUND_PART_PREFIX}border_{k}", {
                    "type": mujoco.mjtGeom.mjGEOM_BOX, "size": [0.5 * (x1 - x0) + 1e-4, 0.5 * (y1 - y0) + 1e-4, 0.5],
                    "pos": [0.5 * (x0 + x1), 0.5 * (y0 + y1), -0.5]}))
    return parts


def set_collision_filter(spec: mujoco.MjSpec, self_collisions: bool, keep: bool) -> tuple[int, int]:
    """Set the robot's collision bits; returns the ground's (contype, conaffinity)."""
    if keep:
        # Collide with every geom that collides with anything: MuJoCo pairs geoms when
        # (contype1 & conaffinity2) | (contype2 & conaffinity1) is non-zero.
        contype = conaffinity = 0
        for geom in spec.geoms:
            contype |= int(geom.conaffinity)
            conaffinity |= int(geom.contype)
        return contype or GROUND_BIT, conaffinity or GROUND_BIT
    for geom in spec.geoms:
        geom.contype = ROBOT_BIT if self_collisions else 0
        geom.conaffinity = GROUND_BIT | (ROBOT_BIT if self_collisions else 0)
    return GROUND_BIT, ROBOT_BIT | GROUND_BIT
