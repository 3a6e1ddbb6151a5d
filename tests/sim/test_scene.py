"""Scenes of several assets (issue 31): env.asset plus the named assets of env.assets composed into one MuJoCo model
by the sim layer, with per-asset views by name.

References: MuJoCo C (mujoco.mj_step) on a combined MJCF written by hand below (the cart-pole URDF as MuJoCo reads
it, a free box and the framework's actuator and contact settings), and MuJoCo's own address tables
(jnt_qposadr, actuator ids by name) for the views.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from conftest import TESTS_DIR
from isaacgymenvs_mw.sim import Simulator, build_model, request_from_config
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError, MissingFileError

REPO = TESTS_DIR.parent
ASSETS = TESTS_DIR / "assets"
BOX_START = (-0.05, 0.0, 0.5)  # over the cart (its top is at z = 0.1), clear of the pole (x from 0.10 to 0.14)
DT = 0.0166

# Cartpole.yaml runs without contacts; the box needs them.
CONTACTS = ["task.sim.enableContacts=True", "task.sim.nconmax=16", "task.sim.njmax=64"]
BOX = [f"+task.env.assets.box={{assetRoot: '{ASSETS}', assetFileName: box.xml, "
       f"pos: [{', '.join(map(str, BOX_START))}]}}"]

# The same scene written by hand. Cart-pole: assets/urdf/cartpole.urdf as MuJoCo compiles a URDF (static rail fused
# into the world, visuals dropped, inertials as given, the continuous joint unlimited, effort -> actuatorfrcrange),
# with the framework's collision filter (robot geoms: contype 0, conaffinity 1) and an effort drive (an unlimited
# motor). Box: tests/assets/box.xml under the prefix 'box/', moved to BOX_START, its own contact bits kept.
HAND_MJCF = f"""
<mujoco model="cartpole_and_box">
  <option timestep="{DT}" integrator="implicitfast" solver="Newton" iterations="4" ls_iterations="8"
          gravity="0 0 -9.81"/>
  <worldbody>
    <geom type="box" size="0.015 4 0.015" contype="0" conaffinity="1"/>
    <body name="cart">
      <inertial pos="0 0 0" mass="1" fullinertia="0.008541667 0.006666667 0.008541667 0 0 0"/>
      <joint name="slider_to_cart" type="slide" axis="0 1 0" range="-4 4" limited="true"
             actuatorfrcrange="-1000 1000" actuatorfrclimited="true"/>
      <geom type="box" size="0.1 0.125 0.1" contype="0" conaffinity="1"/>
      <body name="pole" pos="0.12 0 0">
        <inertial pos="0 0 0.47" mass="1" fullinertia="0.083633333 0.083466667 0.000433333 0 0 0"/>
        <joint name="cart_to_pole" type="hinge" axis="1 0 0" limited="false"
               actuatorfrcrange="-1000 1000" actuatorfrclimited="true"/>
        <geom type="box" size="0.02 0.03 0.5" pos="0 0 0.47" contype="0" conaffinity="1"/>
      </body>
    </body>
    <body name="box/box" pos="{' '.join(map(str, BOX_START))}">
      <freejoint name="box/root"/>
      <geom name="box/box_geom" type="box" size="0.1 0.1 0.1" mass="0.5"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="slider_to_cart" joint="slider_to_cart" ctrllimited="false"/>
  </actuator>
</mujoco>
"""


def scene_cfg(overrides: list[str] = ()) -> dict:
    cfg = compose_config(["task=Cartpole", "num_envs=2", *CONTACTS, *BOX, *overrides])
    return OmegaConf.to_container(cfg.task, resolve=True)


def build(cfg: dict, num_worlds: int = 2) -> Simulator:
    request = request_from_config(cfg["env"], cfg["sim"], cfg.get("yaml_dir"), REPO / "assets")
    return Simulator(build_model(request), num_worlds, "cpu", nconmax=16, njmax=64)


@pytest.fixture(scope="module")
def sim() -> Simulator:
    return build(scene_cfg())


def push(step: int, world: int) -> float:
    """Cart force (N): world 0 pushes gently one way, world 1 the other. Gently: the box rests flat on the cart (four
    contacts); at twice these forces it rocks onto an edge (one contact), and that event comes a step earlier or
    later in float32 than in float64, after which the trajectories part by millimetres."""
    return (1.5 if world == 0 else -2.0) * math.sin(0.05 * step)


def test_cartpole_with_a_free_box_follows_mujoco_c_on_a_hand_written_scene(sim):
    """100 steps: the box falls 0.3 m onto the cart, lands, and rides it while the cart is pushed and the pole swings.
    Every qpos column (cart, pole, box position and quaternion) against MuJoCo C on the hand-written scene."""
    ref_model = mujoco.MjModel.from_xml_string(HAND_MJCF)
    assert ref_model.nq == sim.mj_model.nq == 9 and ref_model.nu == sim.mj_model.nu == 1
    refs = [mujoco.MjData(ref_model) for _ in range(2)]
    start = sim.qpos.clone()
    # The pole hangs below the cart, swinging (upright, its fall shakes the box off the cart within 100 steps).
    start[:, 1] = torch.tensor([math.pi - 0.3, math.pi + 0.5])
    sim.reset_worlds(torch.ones(2, dtype=torch.bool))
    sim.qpos.copy_(start)
    for d, q in zip(refs, start.double().numpy()):
        d.qpos[:] = q
    same_model = [mujoco.MjData(sim.mj_model) for _ in range(2)]  # MuJoCo C on the model the sim layer composed
    for d, q in zip(same_model, start.double().numpy()):
        d.qpos[:] = q
    worst = composed_vs_hand = 0.0
    theirs = []
    for step in range(100):
        for w, (d, e) in enumerate(zip(refs, same_model)):
            d.ctrl[0] = e.ctrl[0] = push(step, w)
            mujoco.mj_step(ref_model, d)
            mujoco.mj_step(sim.mj_model, e)
        sim.ctrl[:, 0] = torch.tensor([push(step, 0), push(step, 1)])
        sim.simulate()
        ref_q = np.stack([d.qpos for d in refs])
        worst = max(worst, float(np.abs(sim.qpos.double().numpy() - ref_q).max()))
        composed_vs_hand = max(composed_vs_hand, float(np.abs(np.stack([e.qpos for e in same_model]) - ref_q).max()))
        theirs.append(ref_q)
    assert composed_vs_hand < 1e-12, composed_vs_hand  # the composition is the hand-written scene
    theirs = np.array(theirs)
    # The scene did what it is meant to: the box came down onto the cart top (centre 0.1 above it) and moved with
    # the cart; the pole swung.
    box_z, offset = theirs[50:, :, 4], theirs[50:, :, 3] - theirs[50:, :, 0]
    np.testing.assert_allclose(box_z, 0.2, atol=5e-3)
    assert np.all(np.abs(theirs[-1, :, 0]) > 0.25) and np.ptp(offset, axis=0).max() < 3e-3  # carried, not sliding
    assert np.ptp(theirs[:, :, 1]) > 0.5
    # float32 Warp against float64 C, contacts included: measured 1.6e-6 (MuJoCo C on the composed model and on the
    # hand-written one agree exactly).
    assert worst < 1e-5, worst


def test_box_views_are_qpos_and_qvel_columns(sim):
    """root_pos / root_quat / root_lin_vel / root_ang_vel are zero-copy slices at the box's free joint's addresses."""
    m = sim.mj_model
    box = sim.asset("box")
    j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "box/root")
    q, v = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
    assert box.floating_base and box.dof_names == [] and box.body_names == ["box/box"]
    for view, full, cols in ((box.root_pos, sim.qpos, slice(q, q + 3)), (box.root_quat, sim.qpos, slice(q + 3, q + 7)),
                             (box.root_lin_vel, sim.qvel, slice(v, v + 3)),
                             (box.root_ang_vel, sim.qvel, slice(v + 3, v + 6))):
        assert view.data_ptr() == full[:, cols].data_ptr()  # a view, not a copy
        torch.testing.assert_close(view, full[:, cols])
    # The main asset keeps its views: the cart-pole's two joints, no root.
    assert sim.dof_names == ["slider_to_cart", "cart_to_pole"] and not sim.floating_base
    assert sim.dof_pos.shape == (2, 2) and sim.dof_pos.data_ptr() == sim.qpos.data_ptr()


def test_write_state_of_one_asset_writes_the_masked_worlds_and_refreshes_its_pose(sim):
    sim.reset_worlds(torch.ones(2, dtype=torch.bool))
    before = sim.qpos.clone()
    pos = torch.tensor([[9.0, 9.0, 9.0], [0.3, -0.2, 1.5]])
    half = math.sqrt(0.5)
    quat = torch.tensor([[1.0, 0.0, 0.0, 0.0], [half, 0.0, 0.0, half]])
    sim.write_state(torch.tensor([False, True]), root_pos=pos, root_quat=quat, asset="box")
    torch.testing.assert_close(sim.qpos[0], before[0])  # world 0 untouched
    torch.testing.assert_close(sim.asset("box").root_pos[1], pos[1])
    torch.testing.assert_close(sim.qpos[1, :2], before[1, :2])  # the cart-pole's columns untouched
    # Reference: MuJoCo C's kinematics of the same qpos.
    d = mujoco.MjData(sim.mj_model)
    d.qpos[:] = sim.qpos[1].double().numpy()
    mujoco.mj_kinematics(sim.mj_model, d)
    b = sim.body_id("box/box")
    np.testing.assert_allclose(sim.xpos[1, b].numpy(), d.xpos[b], atol=1e-6)
    np.testing.assert_allclose(sim.xquat[1, b].numpy(), d.xquat[b], atol=1e-6)
    with pytest.raises(ValueError, match="fixed-base asset"):
        sim.write_state(torch.tensor([True, True]), root_pos=pos)  # the cart-pole is fixed


# --------------------------------------------------------------------------------------- articulated assets
DRAWER = """
<!-- A fixed cabinet with a prismatic drawer (the shape of the Franka cabinet task's fixture). -->
<mujoco model="cabinet">
  <worldbody>
    <body name="cabinet" pos="0 0 0.4">
      <geom name="carcass" type="box" size="0.2 0.3 0.4" mass="20"/>
      <body name="drawer" pos="0.25 0 0.2">
        <joint name="drawer_slide" type="slide" axis="1 0 0" range="0 0.3" damping="5"/>
        <geom name="front" type="box" size="0.02 0.25 0.08" mass="1"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def composite(tmp_path_factory) -> Simulator:
    folder = tmp_path_factory.mktemp("scene")
    (folder / "cabinet.xml").write_text(DRAWER)
    walker = f"{{assetRoot: '{ASSETS}', assetFileName: walker.xml"
    cabinet = f"{{assetRoot: '{folder}', assetFileName: cabinet.xml, fixBaseLink: True, pos: [1, 0, 0.4]}}"
    cfg = scene_cfg([f"+task.env.assets.cabinet={cabinet}", f"+task.env.assets.w1={walker}, pos: [0, 2, 1.5]}}",
                     f"+task.env.assets.w2={walker}, pos: [0, -2, 1.5], prefix: 'other_'}}"])
    return build(cfg)


def test_articulated_assets_get_their_dof_and_actuator_columns_by_name(composite):
    m = composite.mj_model
    cabinet, w1, w2 = composite.asset("cabinet"), composite.asset("w1"), composite.asset("w2")
    assert list(composite.assets) == ["box", "cabinet", "w1", "w2"]  # env.assets order
    assert cabinet.dof_names == ["cabinet/drawer_slide"] and not cabinet.floating_base
    walker = mujoco.MjModel.from_xml_path(str(ASSETS / "walker.xml"))
    walker_joints = [walker.joint(j).name for j in range(1, walker.njnt)]  # after its free root joint
    assert w1.dof_names == [f"w1/{n}" for n in walker_joints]
    assert w2.dof_names == [f"other_{n}" for n in walker_joints]
    for view in (cabinet, w1, w2):
        for name, col in zip(view.dof_names, range(view.dof_pos.shape[1])):
            j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
            assert view.dof_pos[:, col].data_ptr() == composite.qpos[:, int(m.jnt_qposadr[j])].data_ptr()
            assert view.dof_vel[:, col].data_ptr() == composite.qvel[:, int(m.jnt_dofadr[j])].data_ptr()
    # Actuators: the cart-pole's drive first (ctrl[:, 0]), then each asset's own, under its prefix.
    assert composite.actuator_names[0] == "slider_to_cart"
    assert cabinet.actuator_names == [] and cabinet.ctrl.shape == (2, 0)
    walker_acts = [walker.actuator(a).name for a in range(walker.nu)]
    assert w1.actuator_names == [f"w1/{a}" for a in walker_acts]
    for name, col in zip(w2.actuator_names, range(w2.ctrl.shape[1])):
        a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        assert w2.ctrl[:, col].data_ptr() == composite.ctrl[:, a].data_ptr()
    # Placed where the YAML says: the cabinet's root is welded at pos (fused into the world body, as a URDF's
    # static links are), so its drawer sits 0.25 m in front and 0.2 m up; the walkers start at theirs.
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    np.testing.assert_allclose(d.xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "cabinet/drawer")],
                               [1.25, 0, 0.6], atol=1e-12)
    torch.testing.assert_close(w1.root_pos, torch.tensor([[0.0, 2.0, 1.5]] * 2))
    torch.testing.assert_close(w2.root_pos, torch.tensor([[0.0, -2.0, 1.5]] * 2))


def test_prefixes_keep_names_apart(composite):
    """The same file twice and the main asset: every body, joint and actuator name is unique, and each asset's
    names are exactly its file's names under its prefix."""
    m = composite.mj_model
    for kind, count in ((mujoco.mjtObj.mjOBJ_BODY, m.nbody), (mujoco.mjtObj.mjOBJ_JOINT, m.njnt),
                        (mujoco.mjtObj.mjOBJ_ACTUATOR, m.nu)):
        names = [mujoco.mj_id2name(m, kind, i) for i in range(count)]
        named = [n for n in names if n]
        assert len(set(named)) == len(named), names
    spec = mujoco.MjSpec.from_file(str(ASSETS / "walker.xml"))
    spec.compiler.fusestatic = True  # as env.asset's collapseFixedJoints (default True) compiles every asset
    walker = spec.compile()
    bodies = [walker.body(b).name for b in range(1, walker.nbody)]
    assert composite.asset("w1").body_names == [f"w1/{b}" for b in bodies]
    assert composite.asset("w2").body_names == [f"other_{b}" for b in bodies]
    assert "cart" in composite.body_names and "pole" in composite.body_names  # the main asset stays unprefixed


def test_the_composite_steps_as_mujoco_c_steps_it(composite):
    """The bigger scene (drawer, two walkers with their motors, box, cart-pole) on Warp against MuJoCo C's mj_step
    on the same compiled model: 30 steps with the walkers' motors driven."""
    m = composite.mj_model
    composite.reset_worlds(torch.ones(2, dtype=torch.bool))
    composite.dof_pos[:, 1] = math.pi  # the pole hangs (upright, float32 and float64 topple it differently)
    refs = [mujoco.MjData(m) for _ in range(2)]
    for d in refs:
        d.qpos[:] = composite.qpos[0].double().numpy()
    # The cart stays still (the box lands flat on it); each walker's two motors are driven.
    ctrl = torch.tensor([[0.0, 0.5, -0.5, 0.3, -0.3], [0.0, -0.5, 0.5, -0.3, 0.3]])
    worst = 0.0
    for _ in range(30):
        composite.ctrl.copy_(ctrl)
        composite.simulate()
        for w, d in enumerate(refs):
            d.ctrl[:] = ctrl[w].double().numpy()
            mujoco.mj_step(m, d)
        worst = max(worst, float(np.abs(composite.qpos.double().numpy() - np.stack([d.qpos for d in refs])).max()))
    assert m.nu == 1 + 2 * 2  # the cart drive, then each walker's two motors
    assert worst < 1e-4, worst  # float32 against float64: measured 2.0e-5, in the walkers' free-falling legs


# ------------------------------------------------------------------------------------------------- bad input
def test_two_assets_with_the_same_prefix_are_refused():
    walker = f"{{assetRoot: '{ASSETS}', assetFileName: walker.xml, prefix: 'box/'}}"
    with pytest.raises(ConfigError) as err:
        build(scene_cfg([f"+task.env.assets.other={walker}"]))
    message = str(err.value)
    assert message == "env.assets.other.prefix='box/' is also the prefix of env.assets.box: give each asset its own prefix"


def test_an_asset_whose_file_is_missing_is_refused():
    with pytest.raises(MissingFileError) as err:
        build(scene_cfg(["task.env.assets.box.assetFileName=nope.xml"]))
    message = str(err.value)
    assert "\n" not in message and isinstance(err.value, ConfigError)
    assert message.startswith(f"env.assets.box: asset file '{ASSETS / 'nope.xml'}' does not exist (assetRoot=")


def test_an_unknown_asset_key_is_refused():
    with pytest.raises(ConfigError, match=r"^env\.assets\.box: unknown key\(s\) \['mass'\]; valid keys: "):
        build(scene_cfg(["+task.env.assets.box.mass=3"]))


def test_an_unknown_asset_name_is_a_key_error(sim):
    with pytest.raises(KeyError, match="no scene asset named 'cube'.*\\['box'\\]"):
        sim.asset("cube")
