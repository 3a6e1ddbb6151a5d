"""IsaacGymEnvs' public VecTask surface, as a mixin VecTask inherits.

IsaacGymEnvs' tasks and the clients written for them (rl_games' env wrapper, its train.py, an asymmetric critic
reading ``env.state_space``) read names that IsaacGymEnvs' ``Env`` and ``VecTask`` classes define
(isaac-sim/IsaacGymEnvs, isaacgymenvs/tasks/base/vec_task.py). Here each fact has one home elsewhere (the observation
groups, the episode, the randomisation layer, the step execution); this mixin shows them under IsaacGymEnvs' names
with IsaacGymEnvs' meaning. Names of IsaacGym's own machinery (the gym handle, sim_params, the viewer's key events,
its randomisation bookkeeping) have no meaning on MuJoCo Warp: docs/porting.md lists them.
"""

from __future__ import annotations

import gymnasium as gym
import torch

from isaacgymenvs_mw.tasks.base.public_names import ObservationBuffer, TaskOverridable

_RENDER_MODES, _RENDER_FPS = ["human", "rgb_array"], 24


class IGESurface:
    """IsaacGymEnvs' public ``Env`` / ``VecTask`` names over a VecTask, read from VecTask's ``observations``
    (``_built_observations()``), ``randomizer``, ``execution`` and env-step count. Each read-only name is a
    ``TaskOverridable`` (tasks/base/public_names.py): a ported task that sets it, as IsaacGymEnvs' Env did, keeps its
    own value."""

    # gymnasium's keys, and the gym keys IsaacGymEnvs' metadata uses (video recorders of either read theirs)
    metadata = {"render_modes": _RENDER_MODES, "render_fps": _RENDER_FPS,
                "render.modes": _RENDER_MODES, "video.frames_per_second": _RENDER_FPS}
    # IsaacGymEnvs reads env.numAgents (default 1) for multi-agent tasks; every task here has one agent per env.
    num_agents: int = 1

    # ------------------------------------------------------------- sizes
    @TaskOverridable
    def num_environments(self) -> int:
        """IsaacGymEnvs' second name for ``num_envs`` (VecTask's one name for it), kept for ported code."""
        return self.num_envs

    @TaskOverridable
    def num_obs(self) -> int:
        """The policy observation's size (with ``env.history.policy``, the stacked size the learner sees)."""
        return self._built_observations().num_obs

    @TaskOverridable
    def num_observations(self) -> int:
        """IsaacGymEnvs' ``env.numObservations``: here derived from the task's terms when the YAML leaves it out."""
        return self.num_obs

    @TaskOverridable
    def num_states(self) -> int:
        """The critic state's size per frame, 0 without one (``env.numStates``, or the task's state terms)."""
        return self._built_observations().num_states

    @TaskOverridable
    def num_acts(self) -> int:
        return self.num_actions

    def get_number_of_agents(self) -> int:
        """What rl_games' IsaacGymEnvs wrapper asks the env (RLGPUEnv.get_number_of_agents)."""
        return self.num_agents

    # ------------------------------------------------------------- spaces
    @TaskOverridable
    def obs_space(self) -> gym.spaces.Box:
        """Box(-inf, inf) of the policy observation, the shape of ``obs_dict["obs"]``."""
        return self._built_observations().obs_space

    @TaskOverridable
    def state_space(self) -> gym.spaces.Box:
        """Box(-inf, inf) of the critic state, the shape of ``obs_dict["states"]`` (frames stacked with
        ``env.history.critic``); shape (0,) without a critic state, as IsaacGymEnvs' for numStates 0."""
        return self._built_observations().state_space

    @TaskOverridable
    def act_space(self) -> gym.spaces.Box:
        """Box(-1, 1) of the actions (clamped to ``clip_actions`` in the step)."""
        return self._act_space

    @TaskOverridable
    def observation_space(self) -> gym.spaces.Box:
        """gym's name for ``obs_space``, as IsaacGymEnvs' Env gives it."""
        return self._built_observations().obs_space

    @TaskOverridable
    def action_space(self) -> gym.spaces.Box:
        """gym's name for ``act_space``, as IsaacGymEnvs' Env gives it."""
        return self._act_space

    # ------------------------------------------------------------- buffers
    obs_buf = ObservationBuffer("(num_envs, numObservations): the policy observation the task's terms (or the task) "
                                "write each step; an assignment copies into it")
    states_buf = ObservationBuffer("(num_envs, numStates): the critic's privileged state; an assignment copies into it")

    @property
    def randomize_buf(self) -> torch.Tensor:
        """(num_envs,) long: env steps since each env's reset-time randomisation last drew (``frequency`` gates the
        next draw). VecTask counts it; a ported task's ``self.randomize_buf += 1`` would count twice."""
        return self.randomizer.since_draw

    @randomize_buf.setter
    def randomize_buf(self, value: torch.Tensor) -> None:
        raise AttributeError("randomize_buf is counted by VecTask every env step (the randomisation layer); remove "
                             "the task's `self.randomize_buf += 1` (it would count twice)")

    # ------------------------------------------------------------- clocks and devices
    @TaskOverridable
    def control_steps(self) -> int:
        """Env steps taken (the step execution's count, the run's one clock)."""
        return self.execution.steps

    @TaskOverridable
    def total_train_env_frames(self) -> int:
        """Env frames of the run so far (``env_steps`` as an int: a host read; hooks read ``env_steps``)."""
        return int(self._env_steps())

    @TaskOverridable
    def device_type(self) -> str:
        """"cuda" or "cpu": where the simulation runs."""
        return torch.device(self.device).type

    @TaskOverridable
    def device_id(self) -> int:
        """The simulation's CUDA device index (0 on the CPU, as IsaacGymEnvs)."""
        return torch.device(self.device).index or 0

    @TaskOverridable
    def sim_initialized(self) -> bool:
        """True once ``create_sim`` has built the simulator."""
        return getattr(self, "sim", None) is not None
