"""VecTask: IsaacGymEnvs' vectorised-task contract over a batch of MuJoCo Warp worlds.

The episode belongs to VecTask: ``env.episodeLength_s`` (seconds) becomes ``max_episode_length`` (policy steps), and
one after-physics sequence (``post_physics_step``) runs every task:

    progress_buf += 1 -> refresh_state() -> terminations: check_termination() | blown-up worlds; successes:
    check_success(); and time-outs -> compute_reward() -> resets: the randomisation layer's on_reset, then reset_idx() -> after_reset()
    -> sense: self.sim.sense() (computed sensors, sim/sensors.py) -> compute_observations()

A task writes the terms of that sequence, not the sequence (``tasks/base/contract.py`` lists them).

Resets are boolean masks (an index tensor, as IsaacGymEnvs passes, is turned into one): ``nonzero()`` would make
the step wait on the GPU. On CUDA the step's torch work is compiled and captured (``step_execution.py``), so the
hooks stay device-only tensor code. The episode's buffers, its clock and blown-up worlds: ``episode.py`` (a blown-up
world, marked in ``nonfinite_buf``, is a termination: the task's ``reset_idx`` places it, its reward is zeroed).
A ported IsaacGymEnvs task may still override ``post_physics_step``; it then calls ``reset_envs(mask)`` itself, and
``self.sim.sense()`` before observing when it reads a computed sensor (IsaacGym's ``refresh_*_tensor``).
"""

from __future__ import annotations

import functools
import math
from typing import Any, Callable

import gymnasium as gym
import numpy as np
import torch

from isaacgymenvs_mw.sim import ModelRequest, Simulator, sim_dt
from isaacgymenvs_mw.sim.blowup import BlowupLog
from isaacgymenvs_mw.tasks.base.contract import check_actuator_count, check_required_hooks, hook_message
from isaacgymenvs_mw.tasks.base.display import Display
from isaacgymenvs_mw.tasks.base.env_keys import episode_length, joint_velocity_clamp, task_settings
from isaacgymenvs_mw.tasks.base.episode import Episode, EpisodeBuffer
from isaacgymenvs_mw.tasks.base.ige_surface import IGESurface
from isaacgymenvs_mw.tasks.base.metrics import SUCCESS, SUCCESS_RATE, Metric, TaskMetrics
from isaacgymenvs_mw.tasks.base.observation_composer import Observations
from isaacgymenvs_mw.tasks.base.observation_terms import ImageTerm, ObsTerm, sensor_terms
from isaacgymenvs_mw.tasks.base.public_names import TaskOverridable, check_framework_objects
from isaacgymenvs_mw.tasks.base.randomization import Randomizer
from isaacgymenvs_mw.tasks.base.rewards import RewardTerms
from isaacgymenvs_mw.tasks.base.sim_factory import build_simulator, yaml_model_request
from isaacgymenvs_mw.tasks.base.step_execution import StepExecution, StepPhases, fresh_dict
from isaacgymenvs_mw.utils.device import resolve_device


class VecTask(IGESurface):
    """IsaacGymEnvs' VecTask; IGESurface (tasks/base/ige_surface.py) gives its public names that read facts kept here."""

    # True: the episodes that end by ``check_success`` are counted as successes, the metrics SUCCESS_RATE (logged as
    # Episode/success, the rate over ended episodes) and SUCCESS (test mode's eval "success", each env's first episode).
    reports_success: bool = False
    # The history key of the task's success when it is a statistic of the run, not a declared metric: "timeout_fraction"
    # for a task whose goal is to last to the time limit. None: the first Metric(success=True), else the episode reward.
    primary_metric: str | None = None
    # IsaacGymEnvs' names for the buffers of ``self.episode`` (tasks/base/episode.py), read and written by tasks.
    rew_buf, reset_buf, timeout_buf, progress_buf = EpisodeBuffer(), EpisodeBuffer(), EpisodeBuffer(), EpisodeBuffer()
    terminate_buf, success_buf, nonfinite_buf = EpisodeBuffer(), EpisodeBuffer(), EpisodeBuffer()
    nonfinite_inputs_buf, nonfinite_inputs_count = EpisodeBuffer(), EpisodeBuffer()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Wrap a task class's own ``__init__`` so that, once the outermost one returns, VecTask checks that the task
        left the objects its step runs on in place (tasks/base/public_names.py)."""
        super().__init_subclass__(**kwargs)
        init = cls.__dict__.get("__init__")
        if init is None:
            return

        @functools.wraps(init)
        def checked_init(self: VecTask, *args: Any, **kw: Any) -> None:
            init(self, *args, **kw)
            if type(self).__init__ is checked_init:  # the outermost constructor: the task is built
                check_framework_objects(self, {"episode": Episode, "observations": Observations,
                                               "randomizer": Randomizer, "execution": StepExecution,
                                               "metrics": TaskMetrics, "display": Display, "extras": dict})

        cls.__init__ = checked_init

    def __init__(self, config: dict, rl_device: str, sim_device: str, graphics_device_id: int, headless: bool,
                 virtual_screen_capture: bool = False, force_render: bool = False) -> None:
        # IsaacGymEnvs' signature, kept as given: rendering runs on the sim device, videos come from capture_video
        self.cfg, self.graphics_device_id = config, graphics_device_id
        self.virtual_screen_capture, self.force_render = virtual_screen_capture, force_render
        check_required_hooks(type(self), VecTask)
        self.sim_device = resolve_device(sim_device, "sim_device")
        self.rl_device = resolve_device(rl_device, "rl_device")
        self.device = self.sim_device
        declares_layout = type(self).observation_terms is not VecTask.observation_terms
        settings = task_settings(config, declares_layout)
        self.num_envs, self.num_actions = settings.num_envs, settings.num_actions
        self.control_freq_inv, self.render_interval = settings.control_freq_inv, settings.render_interval
        self.clip_obs, self.clip_actions = settings.clip_obs, settings.clip_actions
        self.overflow_check_interval = settings.overflow_check_interval
        self._act_space = gym.spaces.Box(-1.0, 1.0, shape=(self.num_actions,), dtype=np.float32)

        # Parsed before the model is built: it decides which Model fields get one value per world.
        self.randomizer = Randomizer(config.get("task"), sim_dt(config.get("sim", {})) * self.control_freq_inv,
                                     self.num_envs, self.sim_device)
        self.sim: Simulator | None = None
        self.create_sim()
        if self.sim is None:
            raise RuntimeError(f"{type(self).__name__}.create_sim() must set self.sim")
        self.dt = self.sim.dt
        self.control_dt = self.dt * self.control_freq_inv
        self.max_episode_length, self.max_episode_length_s = episode_length(
            config["env"], self.control_dt, getattr(self, "max_episode_length", None))
        self.check_action_size()
        # (joints,) speed limits of the robot's dof_vel columns (env.control.velocityClamp), or None
        self.dof_velocity_clamp = joint_velocity_clamp(config["env"], self.sim.dof_names, self.device)
        self.randomizer.bind(self.sim)  # the randomisation layer, on the built model
        self.randomizer.setup_delay(settings.action_delay, self.num_actions)
        self.display = Display(self.sim, headless)
        self.headless = self.display.headless
        self.observations = Observations(
            type(self).__name__, self.num_envs, self.device, self.rl_device, settings.num_obs, settings.num_states,
            self.clip_obs, settings.history, self.randomizer.with_term_noise, self.image_terms(), self.sim.sensors,
            sensor_terms(self.sim.sensor, settings.observe_sensors))
        self.allocate_buffers()
        # Warp's kernels have been compiling in the background since create_sim: wait for them now, or, with a compiled
        # step, at the first step, while the step compiles (StepExecution.run).
        if not self.execution.compiled:
            self.sim.load_kernels()
        self.obs_dict: dict[str, torch.Tensor] = {}
        self.rewards: RewardTerms | None = None  # a task that sums named terms sets it (tasks/base/rewards.py)
        if not declares_layout:  # sizes from the YAML: known now (a layout waits for the task's own __init__)
            self.build_observation_layouts()

    # --------------------------------------------------------------- building
    def create_sim(self) -> None:
        """Build ``self.sim`` from the YAML: ``env.asset``, ``env.control`` drive settings and the ``sim`` section."""
        self.sim = self.make_simulator(self.model_request())

    def model_request(self) -> ModelRequest:
        """What ``create_sim`` asks the sim layer to build: ``env.asset``, ``env.assets``, ``env.control``,
        ``env.plane``, ``env.baseInitState`` and ``sim`` (``sim.request.request_from_config``); tasks may extend it
        (more contact bodies, per-world fields, ...)."""
        return yaml_model_request(self.cfg)

    def make_simulator(self, request: ModelRequest, per_world_fields: tuple[str, ...] = ()) -> Simulator:
        """The Simulator of ``request``, with ``per_world_fields`` and the randomised quantities' fields per world."""
        return build_simulator(self.cfg, request, self.num_envs, self.sim_device, self.control_freq_inv,
                               tuple(per_world_fields) + self.randomizer.per_world_fields())

    def allocate_buffers(self) -> None:
        n, dev = self.num_envs, self.device
        self.episode = Episode(n, dev, self.max_episode_length, BlowupLog(self.sim),
                               shared_sequence=type(self).post_physics_step is VecTask.post_physics_step)
        self.randomizer.follow_clock(self.episode.run_steps)  # the episode counts the clock the schedules read
        self.extras: dict[str, Any] = {}
        self.metrics = TaskMetrics(self.declared_metrics, n, dev)  # recorded by the task's step, read by learning/
        self._all_envs = torch.ones(n, device=dev, dtype=torch.bool)
        images = None if self.observations.images is None else self._observe_images
        self.execution = StepExecution(
            type(self).__name__, StepPhases(self._before_physics, self.sim.simulate, self._after_physics,
                                            self._render_cameras, images), self.cfg.get("sim", {}),
            graphs_possible=self.sim.use_graphs and torch.device(dev).type == "cuda" and self.rl_device == dev,
            action_shape=(n, self.num_actions), device=dev, load_kernels=self.sim.load_kernels, task=self,
        )

    # ------------------------------------------------------------ observations
    def _built_observations(self) -> Observations:
        if not self.observations.built:  # a declared layout gives the sizes once the task's __init__ has run
            self.build_observation_layouts()
        return self.observations

    def observation_terms(self) -> list[ObsTerm] | None:
        """The policy observation as named terms (``ObsTerm(name, size, scale, noise, compute=...)``), in column
        order; ``compute_observations`` builds ``obs_buf`` from them and ``numObservations`` is their total. None:
        the task declares no layout, fills ``obs_buf`` itself and gives ``numObservations``."""
        return None

    def state_terms(self) -> list[ObsTerm] | None:
        """The privileged critic state as named terms; ``numStates`` is their total (``numStates: 0`` in the YAML
        turns the critic state off). None or []: no critic state, or one the task fills itself (``numStates`` > 0)."""
        return None

    def image_terms(self) -> list[ImageTerm] | None:
        """The image observation (the "camera" group, (num_envs, C, H, W) uint8), read once the simulator is built:
        ``camera_terms(self.sim.cameras)`` observes every ``env.cameras`` output, or ``ImageTerm``s pick some.
        The cameras render after each step's resets (every ``env.renderInterval`` steps). None: no images."""
        return None

    def build_observation_layouts(self) -> None:
        """Derive the layouts, sizes, buffers, spaces and history from the declared terms (a YAML size must agree).
        A task whose terms depend on its own ``__init__`` calls it at the end of that, so that a wrong size fails at
        construction; otherwise the first ``reset()`` (or ``num_obs``) does."""
        obs = self.observations
        obs.build(self.observation_terms(), self.state_terms() if obs.wants_state_terms else None)

    def compute_observations(self) -> None:
        """Fill ``obs_buf`` (and ``states_buf``) from the declared terms; a task without terms overrides this."""
        if self.observations.obs_layout is None:
            raise NotImplementedError(hook_message(type(self), "compute_observations"))
        self.observations.compute()

    def deployment_info(self) -> dict[str, Any]:
        """What a runtime needs to feed an exported policy and apply its actions (``learning/export.py`` adds the
        versions). Tasks with joints add their joint names, default pose, action scale and PD gains."""
        return {"task": type(self).__name__, "control_dt": self.control_dt, "physics_dt": self.dt,
                "decimation": self.control_freq_inv, "num_actions": self.num_actions,
                "clip_actions": self.clip_actions if math.isfinite(self.clip_actions) else None,
                **self._built_observations().describe()}

    def action_actuators(self) -> list[str] | None:
        """The model actuator each action commands, by name: VecTask's contract (check_action_size) makes action i
        ``ctrl[:, i]`` whenever the counts agree. None for a task whose actions are not its actuators."""
        return list(self.sim.actuator_names) if self.num_actions == self.sim.num_actuators else None

    def get_state(self) -> torch.Tensor:
        """The critic's input as the last step returned it (stacked when ``env.history.critic`` is set)."""
        return self.observations.get_state()

    # ------------------------------------------------------------------ hooks
    def pre_physics_step(self, actions: torch.Tensor) -> None:
        raise NotImplementedError(hook_message(type(self), "pre_physics_step"))

    def post_physics_step(self) -> None:
        """The after-physics sequence every task shares; tasks fill its terms (module docstring), not the order."""
        self.progress_buf += 1
        self.refresh_state()
        self.episode.close_step(self.check_termination, self.check_success)  # which episodes end, and how
        self.compute_reward()
        new_episode = self.reset_buf != 0
        self.reset_envs(new_episode)
        self.after_reset(new_episode)
        self.sim.sense()
        self.compute_observations()

    def refresh_state(self) -> None:
        """Derive, after the physics, the quantities the terms read (base velocities, contact forces, ...)."""

    def check_termination(self) -> torch.Tensor:
        """(num_envs,) bool: the envs that failed this step; time-outs and blown-up worlds are VecTask's."""
        return torch.zeros_like(self.nonfinite_buf)

    def check_success(self) -> torch.Tensor:
        """(num_envs,) bool: the envs that reached the task's goal this step (their episodes end, bootstrapped as
        at a time-out); default: none. With ``reports_success`` the rate is logged (``reset_envs``)."""
        return torch.zeros_like(self.nonfinite_buf)

    def compute_reward(self) -> None:
        raise NotImplementedError(hook_message(type(self), "compute_reward"))

    def declared_metrics(self) -> list[Metric]:
        """What the task reports beyond its reward (tasks/base/metrics.py), recorded in its step with
        ``self.metrics.record(metric, value)``; read once, before the first step. Tasks add theirs to these."""
        return [SUCCESS_RATE, SUCCESS] if self.reports_success else []

    def reset_envs(self, env_ids: torch.Tensor) -> None:
        """Reset the selected envs: the randomisation layer draws their new model values first (so the task's
        reset sees the world it will run in), then the task's ``reset_idx``; the reward helper, when the task has
        one, reports their episode sums (``extras["episode_terms"]``), and, with ``reports_success``, which of them
        succeeded (the metrics SUCCESS_RATE and SUCCESS)."""
        mask = self.env_mask(env_ids)
        self.randomizer.on_reset(mask)
        self.reset_idx(mask)
        self.episode.restart(mask)
        if self.reports_success:
            self.metrics.record_successes(self.success_buf & mask)
        if self.rewards is not None:
            self.extras["episode_terms"] = self.rewards.finish_episodes(mask)

    def reset_idx(self, mask: torch.Tensor) -> None:
        """Place the envs of ``mask`` ((num_envs,) bool) for a new episode: robot, objects, goals, task buffers. The
        default does nothing (tasks override). Called through ``reset_envs``, which accepts IGE's index tensors too
        and restarts the episode clock (``progress_buf``) afterwards."""

    def after_reset(self, new_episode: torch.Tensor) -> None:
        """Per-step work that must see this step's new episodes, before the observation (e.g. timed commands). Runs
        after every reset, ``reset()`` and ``reset_done()`` included (there every env of ``new_episode`` is new and
        the step's own quantities, from ``refresh_state``, may not exist yet)."""

    def check_action_size(self) -> None:
        """``env.numActions`` must equal the model's actuator count, checked at construction. A task whose actions
        do not map one to one onto actuators overrides this with its own check."""
        check_actuator_count(type(self).__name__, self.num_actions, self.sim)

    def longest_episode(self) -> int:
        """The most policy steps an episode can last: test mode steps this long (plus 2) before it stops waiting.
        The time limit by default; a task whose successes restart the clock says more."""
        return int(self.max_episode_length)

    def evaluation_groups(self) -> dict[str, torch.Tensor]:
        """Per-env labels by which test mode also reports its results (``per_<name>`` in eval.json), read when the
        evaluation starts. None by default; the terrain tasks group by curriculum level."""
        return {}

    # ---------------------------------------------------------------- contract
    def env_mask(self, env_ids: torch.Tensor) -> torch.Tensor:
        """A boolean (num_envs,) mask from a mask or an index tensor (IsaacGymEnvs passes indices)."""
        return self.episode.mask(env_ids)

    def step(self, actions: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor, dict]:
        """Apply actions, run controlFrequencyInv physics steps, and return (obs_dict, rew, reset, extras)."""
        self.metrics.begin_step(replay := self.execution.replays)
        with fresh_dict(self, "extras"):
            self.execution.run(actions)  # the step's phases: eager, compiled or captured
        if not replay and self.execution.replays:  # this step was captured: the replays rewrite what it recorded
            self.metrics.hold_for_replays()

        self.extras.update(self.episode.step_extras(self.rl_device))
        self.observations.step_outputs(self.obs_dict, self.execution.steps)

        if self.execution.steps % self.overflow_check_interval == 0:
            self.sim.poll_overflow()
            self.episode.blowups.poll(self.overflow_check_interval)
        self.display.show(self.control_dt, self.execution.steps)
        return self.obs_dict, self.rew_buf.to(self.rl_device), self.reset_buf.to(self.rl_device), self.extras

    def _before_physics(self, actions: torch.Tensor) -> None:
        action_tensor = torch.clamp(actions.to(self.device), -self.clip_actions, self.clip_actions)
        self.randomizer.before_physics(self.progress_buf)
        self.pre_physics_step(self.randomizer.actions(action_tensor))

    def _after_physics(self) -> None:
        """Everything after the physics: device work only, no host sync (a CUDA graph when captured)."""
        if self.dof_velocity_clamp is not None:  # before anything reads the speeds: the task sees clamped ones
            # In place on the view of qvel: the next physics step starts from the clamped speeds.
            self.sim.dof_vel.clamp_(min=-self.dof_velocity_clamp, max=self.dof_velocity_clamp)
        self.episode.after_physics(self.post_physics_step)
        self.randomizer.observations(self.obs_buf)
        self.episode.count_step()
        self.randomizer.count_step()
        self.episode.guard_inputs(self.observations.finish_step)  # an env reset in this step starts its history

    def _render_cameras(self, step: int) -> None:
        """The render phase, after the step's resets (and after a reset): the images show the state the observation
        describes. The cameras render (Warp, one graph on CUDA) every ``env.renderInterval`` steps (a host counter:
        no sync); between renders their images stay those of the last one."""
        if step % self.render_interval == 0:
            self.sim.render_cameras()

    def _observe_images(self, step: int) -> None:
        self.observations.observe_images(self.reset_buf != 0, step)

    @TaskOverridable
    def step_execution(self) -> str:
        """How the step's torch work runs: "eager", "compiled", "captured" or "compiled+captured"."""
        return self.execution.mode

    def zero_actions(self) -> torch.Tensor:
        return torch.zeros((self.num_envs, self.num_actions), dtype=torch.float32, device=self.rl_device)

    def reset(self) -> dict[str, torch.Tensor]:
        """Reset every env and return the first observations (call once before stepping)."""
        self._built_observations()
        return self._reset(self._all_envs, lambda: self.observations.compute_checked(self.compute_observations))

    def reset_done(self) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """Reset the envs whose reset_buf is set; returns (obs_dict, their indices)."""
        done = self.reset_buf != 0
        return self._reset(done, self.compute_observations), done.nonzero(as_tuple=False).flatten()

    def _reset(self, new_episode: torch.Tensor, observe: Callable[[], None]) -> dict[str, torch.Tensor]:
        """Reset the envs of ``new_episode`` and observe them (``observe``) after the sense phase; the images come
        through the step's own render phase, and ``new_episode`` envs forget their past frames."""
        self.metrics.begin_step()
        self.reset_envs(new_episode)
        self.after_reset(new_episode)  # the same reset path as a step's: what a task draws there is set from step 0
        self.sim.sense()
        observe()
        self.randomizer.observations(self.obs_buf)
        self._render_cameras(self.execution.steps)
        return self.observations.reset_outputs(self.obs_dict, new_episode, self.execution.steps)

    def set_train_info(self, env_frames: int, *args, **kwargs) -> None:
        # Randomisation schedules count env steps (IsaacGymEnvs' last_step): resume them where training is.
        self.episode.run_steps.fill_(env_frames // self.num_envs)

    @TaskOverridable
    def env_steps(self) -> torch.Tensor:
        """The run's env steps so far over this process's envs, a () int64 tensor on the sim device: num_envs per
        step, as IsaacGymEnvs' frame count (``set_train_info(env_frames)``) counts. Reward schedules and periodic events
        read it in the step (device work, so it keeps counting in a captured step, where a Python counter would
        freeze). A run from a checkpoint starts at the checkpoint's (resumed or in test mode). Read it each step: it
        is computed from the one counter the randomisation schedules and the penalty curriculum also read (steps
        per env, ``env_steps // num_envs``)."""
        return self._env_steps()

    def _env_steps(self) -> torch.Tensor:
        # the framework's reads of the count: a task may keep its own ``env_steps`` (tasks/base/public_names.py)
        return self.episode.run_steps.long() * self.num_envs

    def get_env_state(self) -> None:  # IsaacGymEnvs' checkpoint hooks: nothing beyond the policy to save
        return None

    def set_env_state(self, env_state: Any) -> None:
        pass

    # --------------------------------------------------------------- rendering
    def render(self, mode: str = "rgb_array") -> None:
        """IsaacGymEnvs' render: the viewer (``self.display``, tasks/base/display.py) shows env 0."""
        self.display.sync_viewer(self.control_dt)

    def close(self) -> None:
        self.display.close()

    # ------------------------------------------------------ forces on bodies (IsaacGym's force tensors)
    def apply_body_forces(self, forces: torch.Tensor | None = None, torques: torch.Tensor | None = None,
                          bodies: list[str] | list[int] | torch.Tensor | None = None,
                          positions: torch.Tensor | None = None, frame: str = "world", persist: bool = False) -> None:
        """Forces/torques (num_envs, len(bodies), 3) on bodies for the coming env step (``persist``: until
        ``clear_body_forces``), in the "world" or "body" frame, at the centre of mass or at ``positions``.

        IsaacGym's ``apply_rigid_body_force_tensors`` / ``apply_rigid_body_force_at_pos_tensors``; call it from
        ``pre_physics_step``. ``bodies``: names or MuJoCo body indices (None: all, world body 0 included).
        Semantics in ``Simulator.apply_body_forces`` and docs/porting.md.
        """
        self.sim.apply_body_forces(forces, torques, bodies, positions, frame, persist)

    def clear_body_forces(self) -> None:
        """Drop every force of ``apply_body_forces``, one-step and persistent."""
        self.sim.clear_body_forces()

