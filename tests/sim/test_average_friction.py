"""``env.averageFriction`` (issue 59): the geom pairs a task names touch with the average of their two frictions, as
PhysX (IsaacGymEnvs) combines materials, instead of MuJoCo's larger one; everything else about the contact stays as
MuJoCo would mix it. Checked in MuJoCo C's mjData of the built model."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from isaacgymenvs_mw.sim import build_model, request_from_config
from isaacgymenvs_mw.utils.errors import ConfigError

# A cube (sliding friction 1.0, its own solref and solmix) resting on a table (0.1), and a second box of the same
# body on the table that no pair names. The table is a geom of the world, the body free; the asset's contacts count.
SCENE = """<mujoco>
  <worldbody>
    <geom name="table" type="box" pos="0 0 0.5" size="1 1 0.05" friction="0.1 0.004 0.0002"/>
    <body name="cube" pos="0 0 0.598"><freejoint/>
      <geom name="cube" type="box" size="0.05 0.05 0.05" friction="1.0 0.02 0.0004" solref="0.01 0.8" solmix="3"
            condim="4"/>
      <geom name="other" type="box" pos="0.5 0 0" size="0.05 0.05 0.05" friction="0.8 0.01 0.0001"/></body>
  </worldbody>
</mujoco>"""


def build(tmp_path, **env):
    (tmp_path / "scene.xml").write_text(SCENE)
    cfg = {"asset": {"assetRoot": str(tmp_path), "assetFileName": "scene.xml", "fixBaseLink": False}, **env}
    return build_model(request_from_config(cfg, {}, None, tmp_path))


def contacts(m: mujoco.MjModel) -> dict[tuple[str, str], list]:
    """{(geom, geom): [contacts]} of the model's initial state, MuJoCo C."""
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    out: dict[tuple[str, str], list] = {}
    for c in d.contact[:d.ncon]:
        key = tuple(sorted((m.geom(c.geom1).name, m.geom(c.geom2).name)))
        out.setdefault(key, []).append(c)
    return out


def test_named_pair_touches_with_the_average_friction_and_otherwise_as_mujoco_mixes(tmp_path):
    plain = contacts(build(tmp_path))
    averaged = contacts(build(tmp_path, averageFriction=[["cube", "table"]]))
    pair = ("cube", "table")
    assert len(plain[pair]) == len(averaged[pair]) == 4  # a box face on a box: four corners, made once each
    for before, after in zip(plain[pair], averaged[pair]):
        # MuJoCo's own rule: the larger of each coefficient (1.0, 0.02, 0.0004)
        np.testing.assert_allclose(before.friction, [1.0, 1.0, 0.02, 0.0004, 0.0004])
        # PhysX's: the average, (1.0 + 0.1) / 2 = 0.55, and likewise the torsional and rolling coefficients
        np.testing.assert_allclose(after.friction, [0.55, 0.55, 0.012, 0.0003, 0.0003], rtol=1e-12)
        assert after.dim == before.dim == 4
        np.testing.assert_allclose(after.solref, before.solref, rtol=1e-12)  # solmix 3 : 1 of (0.01, 0.8), (0.02, 1)
        np.testing.assert_allclose(after.solref, [0.75 * 0.01 + 0.25 * 0.02, 0.75 * 0.8 + 0.25 * 1.0])
        np.testing.assert_allclose(after.solimp, before.solimp, rtol=1e-12)
        np.testing.assert_allclose(after.pos, before.pos, atol=1e-12)
    # the pair that was not named keeps MuJoCo's rule
    for c in averaged[("other", "table")]:
        np.testing.assert_allclose(c.friction, [0.8, 0.8, 0.01, 0.0002, 0.0002])


def test_patterns_select_every_pair_once_and_env_contact_counts_first(tmp_path):
    m = build(tmp_path, contact={"table": {"friction": [0.3]}}, averageFriction=[["cube|other", "table"],
                                                                               ["table", "cube"]])
    assert m.npair == 2  # cube-table named twice, once
    got = contacts(m)
    for c in got[("cube", "table")]:
        assert c.friction[0] == pytest.approx((1.0 + 0.3) / 2)
    for c in got[("other", "table")]:
        assert c.friction[0] == pytest.approx((0.8 + 0.3) / 2)


@pytest.mark.parametrize("value, message", [
    (["cube"], r"^env\.averageFriction=\['cube'\] is invalid: give a list of \[geom regex, geom regex\] pairs"),
    ("cube", r"^env\.averageFriction='cube' is invalid: give a list of"),
    ([["cube", "table", "other"]], r"^env\.averageFriction=\[\['cube', 'table', 'other'\]\] is invalid"),
    ([["cube", "floor"]], r"^env\.averageFriction\[0\]: 'floor' matches no geom .*geoms: \['table', 'cube', 'other'\]"),
])
def test_bad_pairs_are_refused_in_one_line_naming_the_key(tmp_path, value, message):
    with pytest.raises(ConfigError, match=message):
        build(tmp_path, averageFriction=value)
