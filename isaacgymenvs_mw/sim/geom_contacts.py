"""Contact properties a task YAML gives geoms of the composed scene: ``env.contact`` (condim, friction per geom) and
``env.averageFriction`` (geom pairs whose contacts take the average of the two frictions, as PhysX does).

How two surfaces combine differs between the engines. PhysX, and so IsaacGymEnvs, averages the two materials'
coefficients by default (a cube of 1.0 on a table of 0.1 slides with 0.55); MuJoCo, for two geoms of equal priority,
takes the larger of each coefficient (1.0). MuJoCo's way to give a pair of geoms its own friction is an explicit
contact pair (MJCF ``<pair>``): a pair replaces the contacts the two geoms would have made anyway and is made even
where the collision filter (contype / conaffinity) would skip them. ``add_average_friction_pairs`` adds one per
selected geom pair with the average friction and, for everything else, what MuJoCo's own mixing of the two geoms
would have given (the larger condim, margin and gap, solref and solimp mixed by solmix; the higher priority's when
the priorities differ), so only the friction differs from the contact MuJoCo would have made. Randomising a geom's
friction (``geom_friction``) does not reach a pair's contacts: they read the pair's own friction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import mujoco
import numpy as np

from isaacgymenvs_mw.sim.names import name_matches


@dataclass
class GeomContact:
    """How a geom touches others: MuJoCo's condim (1 frictionless, 3 sliding friction, 4 + torsional, 6 + rolling)
    and friction (sliding, torsional, rolling); None keeps the file's."""

    condim: int | None = None
    friction: Sequence[float] | None = None


def set_geom_contacts(spec: mujoco.MjSpec, contacts: Mapping[str, GeomContact]) -> None:
    """``env.contact``: each pattern's condim / friction on every geom of the scene whose whole name it matches
    (scene assets' prefixed names included)."""
    geoms = [g for g in spec.geoms if g.name]
    names = [g.name for g in geoms]
    for pattern, contact in contacts.items():
        for i in name_matches(pattern, names, f"env.contact.{pattern}", "geoms"):
            if contact.condim is not None:
                geoms[i].condim = int(contact.condim)
            if contact.friction is not None:
                geoms[i].friction = list(contact.friction)


def _mix_weight(a: mujoco.MjsGeom, b: mujoco.MjsGeom) -> float:
    """MuJoCo's weight of ``a`` in the mix of two geoms' solver parameters (``mj_contactParam``): all or nothing when
    the priorities differ, else by solmix (an even split when both are negligible)."""
    small = mujoco.mjMINVAL
    if a.priority != b.priority:
        return 1.0 if a.priority > b.priority else 0.0
    if a.solmix < small and b.solmix < small:
        return 0.5
    if a.solmix < small:
        return 0.0
    if b.solmix < small:
        return 1.0
    return float(a.solmix / (a.solmix + b.solmix))


def _averaged_pair(spec: mujoco.MjSpec, a: mujoco.MjsGeom, b: mujoco.MjsGeom) -> None:
    sliding, torsional, rolling = (0.5 * (np.asarray(a.friction) + np.asarray(b.friction))).tolist()
    mix = _mix_weight(a, b)
    ref_a, ref_b = np.asarray(a.solref), np.asarray(b.solref)
    if a.priority != b.priority:  # the higher priority's settings, as MuJoCo would use them
        condim, solref = (a.condim, ref_a) if mix == 1.0 else (b.condim, ref_b)
    else:
        condim = max(int(a.condim), int(b.condim))
        # Standard references (time constant, damping ratio) mix; direct ones (negative) take the smaller of each.
        solref = mix * ref_a + (1 - mix) * ref_b if ref_a[0] > 0 and ref_b[0] > 0 else np.minimum(ref_a, ref_b)
    solimp = mix * np.asarray(a.solimp) + (1 - mix) * np.asarray(b.solimp)
    spec.add_pair(geomname1=a.name, geomname2=b.name, condim=int(condim),
                  friction=[sliding, sliding, torsional, rolling, rolling], solref=list(solref),
                  solimp=solimp.tolist(), margin=max(a.margin, b.margin), gap=max(a.gap, b.gap))


def add_average_friction_pairs(spec: mujoco.MjSpec, pairs: Sequence[tuple[str, str]]) -> int:
    """``env.averageFriction``: for each (pattern, pattern), a contact pair of every geom the first selects with
    every geom the second selects (not with itself, not within one body), whose friction is the average of the two
    geoms' (after ``env.contact``). Returns the number of pairs added."""
    geoms = [g for g in spec.geoms if g.name]
    names = [g.name for g in geoms]
    done: set[frozenset[str]] = set()
    for i, (first, second) in enumerate(pairs):
        key = f"env.averageFriction[{i}]"
        for a in name_matches(first, names, key, "geoms"):
            for b in name_matches(second, names, key, "geoms"):
                both = frozenset((names[a], names[b]))
                if a == b or both in done or geoms[a].parent.name == geoms[b].parent.name:
                    continue
                done.add(both)
                _averaged_pair(spec, geoms[a], geoms[b])
    return len(done)
