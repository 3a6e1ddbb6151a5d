"""Sim-to-sim: run an exported legged policy (policy.onnx + policy.json + model.mjb) with onnxruntime on plain MuJoCo
(C, CPU), the way a robot runtime would: the observation is rebuilt from the metadata (term names, sizes, scales,
history), actions become joint targets for the model's position actuators (PD), and the velocity tracking error it
reaches for a fixed command is reported. See docs/deploy.md.

MuJoCo C solves the contacts to convergence here (MuJoCo's default iteration limits), not with the few solver
iterations the task trains with: MuJoCo Warp's Newton solver lands near the converged solution within them, MuJoCo
C's does not (docs/deploy.md, "Solver iterations"); ``--trained-solver`` keeps the exported limits.

    python examples/deploy_mujoco.py runs/Go1/<stamp>/exported --command 1.0 0.0 0.0 --seconds 20

Prints one JSON object. Needs mujoco and onnxruntime only (not warp, not torch).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Callable, NoReturn

import mujoco
import numpy as np


def quat_rotate_inverse(quat: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """``vec`` (world frame) in the frame of the body whose orientation is ``quat`` (w, x, y, z)."""
    inverse, out = np.zeros(4), np.zeros(3)
    mujoco.mju_negQuat(inverse, quat)
    mujoco.mju_rotVecQuat(out, vec, inverse)
    return out


def converge_solver(model: mujoco.MjModel) -> None:
    """Raise the constraint solver's iteration limits (in place) to MuJoCo's defaults, where they are lower.

    The task trains with a few Newton iterations (sim.iterations, sim.ls_iterations: 4 and 8 for the legged
    robots). MuJoCo Warp's solver ends those near the converged solution; MuJoCo C's, from the same state, often
    does not while the contact set changes (a foot landing): joint speeds then end tens of rad/s off. The converged
    solution is the physics the policy learnt on; with it both engines agree (docs/deploy.md, "Solver iterations").
    """
    default = mujoco.MjOption()
    model.opt.iterations = max(model.opt.iterations, default.iterations)
    model.opt.ls_iterations = max(model.opt.ls_iterations, default.ls_iterations)


class Deployment:
    """One robot in MuJoCo C driven by an exported policy, following ``policy.json``.

    ``trained_solver``: keep the exported model's solver iteration limits instead of solving to convergence.
    """

    def __init__(self, export_dir: Path, model: mujoco.MjModel | None = None, trained_solver: bool = False) -> None:
        export_dir = Path(export_dir)
        self.meta = json.loads((export_dir / "policy.json").read_text())
        meta = self.meta
        for key in ("joint_names", "default_joint_pos", "action_scale", "commands_scale"):
            if key not in meta:
                raise ValueError(f"export_dir='{export_dir}' holds {meta.get('task', 'an unnamed task')}'s policy, "
                                 f"whose policy.json has no '{key}': this example deploys the legged robots' "
                                 "policies (Anymal, Go1, G1 and their terrain tasks)")
        self.model = model or mujoco.MjModel.from_binary_path(str(export_dir / meta["files"]["mujoco_model"]))
        if not trained_solver:
            converge_solver(self.model)
        self.data = mujoco.MjData(self.model)
        m = self.model
        names = meta["joint_names"]
        ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
        missing = [n for n, i in zip(names, ids) if i < 0]
        if missing:
            raise ValueError(f"the model has no joints {missing}")
        self.qpos_adr = np.array([m.jnt_qposadr[i] for i in ids])
        self.qvel_adr = np.array([m.jnt_dofadr[i] for i in ids])
        self.ctrl_adr = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in names])
        self.default = np.asarray(meta["default_joint_pos"], dtype=np.float64)
        self.action_scale = float(meta["action_scale"])
        self.clip_actions = meta["clip_actions"] or np.inf
        self.clip_obs = meta["clip_observations"] or np.inf
        self.decimation = int(round(meta["control_dt"] / m.opt.timestep))
        self.command = np.zeros(3)
        self.last_action = np.zeros(len(names))
        obs = meta["observation"]
        if obs["terms"] is None:
            raise ValueError("policy.json lists no observation terms: the observation cannot be rebuilt")
        self.terms = obs["terms"]
        unknown = [t["name"] for t in self.terms if t["name"] not in self.term_functions()]
        if unknown:
            raise ValueError(f"observation terms {unknown} are not computed by this example; it knows "
                             f"{sorted(self.term_functions())}")
        self.history = obs["history"]
        self.columns = np.asarray(self.history.get("columns", []), dtype=np.int64)
        self.past: list[np.ndarray] = []  # selected columns of past frames, newest first

    # ------------------------------------------------------------------ observation (as the task computes it)
    def term_functions(self) -> dict[str, Callable[[], np.ndarray]]:
        """Each term's raw value; ``frame()`` multiplies by the term's scale (commands: by ``commands_scale``)."""
        d = self.data
        quat = d.qpos[3:7]
        return {
            "base_lin_vel": lambda: quat_rotate_inverse(quat, d.qvel[0:3]),  # free joint: world-frame velocity
            "base_ang_vel": lambda: d.qvel[3:6].copy(),                       # free joint: body-frame rate
            "projected_gravity": lambda: quat_rotate_inverse(quat, np.array([0.0, 0.0, -1.0])),
            "commands": lambda: self.command * np.asarray(self.meta["commands_scale"]),
            "dof_pos": lambda: d.qpos[self.qpos_adr] - self.default,
            "dof_vel": lambda: d.qvel[self.qvel_adr].copy(),
            "actions": lambda: self.last_action.copy(),
        }

    def frame(self) -> np.ndarray:
        """One observation frame, clipped (the task's obs_buf, noiseless)."""
        fns = self.term_functions()
        parts = [fns[t["name"]]() * float(t["scale"]) for t in self.terms]
        return np.clip(np.concatenate(parts), -self.clip_obs, self.clip_obs)

    def observe(self, new_episode: bool = False) -> np.ndarray:
        """The policy input: this frame, then the selected columns of the past ``length - 1`` frames, newest first;
        a new episode fills the past with its first frame (as the task's history buffer does)."""
        current = self.frame()
        length = int(self.history.get("length", 1))
        if length == 1:
            return current
        selected = current[self.columns]
        if new_episode or not self.past:
            self.past = [selected] * (length - 1)
        stacked = np.concatenate([current, *self.past])
        self.past = [selected, *self.past[:-1]]
        return stacked

    # ------------------------------------------------------------------ control
    def reset(self) -> None:
        """The task's nominal start: base at its initial pose, joints at the default angles, at rest."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[0:3] = self.meta["base_init_pos"]
        self.data.qpos[3:7] = self.meta["base_init_quat"]
        self.data.qpos[self.qpos_adr] = self.default
        self.data.ctrl[self.ctrl_adr] = self.default
        self.last_action[:] = 0.0
        self.past = []
        mujoco.mj_forward(self.model, self.data)

    def apply(self, action: np.ndarray) -> None:
        """Joint targets for the position actuators, then ``decimation`` physics steps (one control period)."""
        action = np.clip(np.asarray(action, dtype=np.float64), -self.clip_actions, self.clip_actions)
        self.last_action[:] = action
        self.data.ctrl[self.ctrl_adr] = self.default + self.action_scale * action
        for _ in range(self.decimation):
            mujoco.mj_step(self.model, self.data)


def load_session(export_dir: Path):
    import onnxruntime as ort

    return ort.InferenceSession(str(Path(export_dir) / "policy.onnx"), providers=["CPUExecutionProvider"])


def run(export_dir: Path, command: tuple[float, float, float], seconds: float, settle: float,
        trained_solver: bool = False) -> dict:
    """Follow ``command`` for ``seconds``; errors are means over the steps after the first ``settle`` seconds."""
    robot, session = Deployment(export_dir, trained_solver=trained_solver), load_session(export_dir)
    robot.reset()
    robot.command[:] = command
    steps = int(round(seconds / robot.meta["control_dt"]))
    skip = int(round(settle / robot.meta["control_dt"]))
    lin_err, yaw_err, heights, fell = [], [], [], False
    start = robot.data.qpos[0:3].copy()
    obs = robot.observe(new_episode=True)
    for step in range(steps):
        action = session.run(["actions"], {"obs": obs[None].astype(np.float32)})[0][0]
        robot.apply(action)
        obs = robot.observe()
        d = robot.data
        vel = quat_rotate_inverse(d.qpos[3:7], d.qvel[0:3])
        up = quat_rotate_inverse(d.qpos[3:7], np.array([0.0, 0.0, -1.0]))[2]
        fell |= bool(up > -0.5)  # tilted past 60 degrees
        heights.append(float(d.qpos[2]))
        if step >= skip:
            lin_err.append(float(np.linalg.norm(robot.command[:2] - vel[:2])))  # the task's eval metric
            yaw_err.append(abs(float(robot.command[2] - d.qvel[5])))
    return {
        "task": robot.meta["task"],
        "command": list(command),
        "seconds": seconds,
        "settle_s": settle,
        "lin_vel_tracking_error": float(np.mean(lin_err)) if lin_err else None,
        "yaw_rate_tracking_error": float(np.mean(yaw_err)) if yaw_err else None,
        "fell": fell,
        "min_base_height": min(heights) if heights else None,
        "distance_xy": float(np.linalg.norm(robot.data.qpos[0:2] - start[0:2])),
        "solver_iterations": [int(robot.model.opt.iterations), int(robot.model.opt.ls_iterations)],
        "mujoco": mujoco.__version__,
        "trained_with": robot.meta["versions"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("export_dir", type=Path, help="folder with policy.onnx, policy.json and model.mjb")
    parser.add_argument("--command", type=float, nargs=3, default=(1.0, 0.0, 0.0), metavar=("VX", "VY", "YAW"))
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--settle", type=float, default=1.0, help="seconds left out of the error (start-up)")
    parser.add_argument("--trained-solver", action="store_true",
                        help="keep the exported solver iteration limits (MuJoCo C then stops short of convergence)")
    args = parser.parse_args()
    if not (args.export_dir / "policy.json").is_file():
        fail(f"export_dir='{args.export_dir}' has no policy.json: give the exported/ folder that test mode "
             "(train.py test=True) writes next to the checkpoint")
    try:
        result = run(args.export_dir, tuple(args.command), args.seconds, args.settle, args.trained_solver)
    except ValueError as err:  # an export this example cannot run: what and why, as one line
        fail(str(err))
    print(json.dumps(result), flush=True)


def fail(message: str) -> NoReturn:
    """End with one line on stderr and exit status 2, as train.py does for bad input."""
    print(f"[deploy] error: {message}", file=sys.stderr, flush=True)
    sys.exit(2)


if __name__ == "__main__":
    main()
