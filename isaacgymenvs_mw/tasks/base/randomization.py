"""Domain randomisation for every VecTask, driven by the task YAML (``task.randomize``, ``task.randomization_params``).

The vocabulary is IsaacGymEnvs' where it maps: ``observations`` and ``actions`` noise, ``sim_params`` (gravity),
``actor_params`` grouped as ``rigid_body_properties`` / ``rigid_shape_properties`` / ``dof_properties`` (plus our
``actuator_properties``), each quantity with ``range``, ``distribution`` (uniform | gaussian | loguniform),
``operation`` (additive | scaling) and an optional ``schedule`` (linear | constant) over ``schedule_steps`` env
steps; also IsaacGymEnvs' per-actor level (``actor_params.<actor>.<group>``), ``frequency``, ``range_correlated``,
``setup_only`` and ``num_buckets``, and a one-line refusal of its keys with no MuJoCo counterpart (``REFUSED``). Ours on
top: what a quantity applies to (``bodies`` / ``geoms`` / ``joints`` / ``actuators``: names or regular
expressions), when it is drawn (``apply``: startup | reset | interval), per-term observation noise, an action delay
and pushes. docs/config.md lists every key.

Each draw is relative to the compiled model's (nominal) value, so scaling never compounds; only the worlds that
reset (or whose interval is due) draw; the values live in per-world Model fields on the device, and every draw is
masked torch work (no host sync), so the step stays capturable as a CUDA graph and compilable by torch.compile.
"""

from __future__ import annotations

import torch

from isaacgymenvs_mw.sim import Simulator
from isaacgymenvs_mw.tasks.base.observation_terms import ObsLayout
from isaacgymenvs_mw.tasks.base.randomization_config import parse_randomization
from isaacgymenvs_mw.tasks.base.randomization_delay import ActionDelay
from isaacgymenvs_mw.tasks.base.randomization_model import ModelRandomizer
from isaacgymenvs_mw.tasks.base.randomization_noise import Noise
from isaacgymenvs_mw.tasks.base.randomization_push import Pushes
from isaacgymenvs_mw.tasks.base.randomization_sampling import Sampler


class Randomizer:
    """The randomisation layer of one VecTask: the YAML parsed (randomization_config.py), then one part per concern:
    model quantities (randomization_model.py), noise (randomization_noise.py), the action delay
    (randomization_delay.py) and pushes (randomization_push.py), all drawing through one ``Sampler``.

    ``VecTask`` calls, in this order each step: ``before_physics`` (interval draws, pushes), ``actions`` (delay,
    noise), the physics, the task's post-physics step (whose resets call ``on_reset`` before the task's ``reset_idx``),
    ``observations`` (noise). All of it is masked torch work on the sim device.
    """

    def __init__(self, task_cfg: dict | None, control_dt: float, num_envs: int, device: torch.device) -> None:
        self.config = parse_randomization(task_cfg, control_dt)
        self.enabled = self.config.enabled
        self.num_envs, self.device = num_envs, device
        # The schedules read the run's env steps per env: the episode's clock, handed over by follow_clock.
        self.sampler = Sampler(device)
        cfg = self.config
        self.model = ModelRandomizer(cfg.entries, cfg.frequency, num_envs, self.sampler)
        self.noise = Noise(cfg.observations, cfg.obs_terms, cfg.actions, cfg.frequency, num_envs, self.sampler)
        self.delay = ActionDelay(cfg.delay, num_envs, device)
        self.push = Pushes(cfg.push, num_envs, self.sampler) if cfg.push is not None else None
        self.sim: Simulator | None = None

    @property
    def step_count(self) -> torch.Tensor:
        """The run's env steps per env that the schedules read: the episode's ``run_steps`` once followed."""
        return self.sampler.clock

    @property
    def since_draw(self) -> torch.Tensor:
        """Env steps since each env's reset-time draws last drew (IsaacGymEnvs' ``randomize_buf``)."""
        return self.model.since_draw

    def follow_clock(self, run_steps: torch.Tensor) -> None:
        """Read the schedules' step count from ``run_steps`` (the episode's clock, at 0 before the first step, as
        the layer's own clock is until now)."""
        self.sampler.clock = run_steps

    def parts(self) -> dict[str, object]:
        """The objects holding the layer's device state, by name (diagnostics copy and compare their tensors)."""
        return {"sampler": self.sampler, "model": self.model, "noise": self.noise, "delay": self.delay,
                "push": self.push}

    # ------------------------------------------------------------------ building
    def per_world_fields(self) -> tuple[str, ...]:
        """Model fields the simulator must batch per world for the configured quantities."""
        return self.model.per_world_fields()

    def bind(self, sim: Simulator) -> None:
        """Resolve names against the compiled model, check the ranges against the nominal values, draw startup."""
        self.sim = sim
        self.model.bind(sim)

    def with_term_noise(self, layout: ObsLayout) -> ObsLayout:
        """The task's policy layout with ``observations.terms`` noise added to its terms' own (per-column noise)."""
        return self.noise.with_term_noise(layout)

    def setup_delay(self, nominal: int, num_actions: int) -> None:
        """Allocate the action ring buffer: ``nominal`` (env.control.actionDelay) plus the randomised range."""
        self.delay.check_nominal(nominal)
        self.noise.start_action_offsets(num_actions)
        self.delay.setup(nominal, num_actions)

    # ------------------------------------------------------------------ per step
    def on_reset(self, mask: torch.Tensor) -> None:
        """Draw the reset-time quantities of the resetting worlds (those whose last draw is ``frequency`` env steps
        old) and clear their action history."""
        self.model.on_reset(mask)
        self.delay.on_reset(mask)

    def before_physics(self, progress: torch.Tensor) -> None:
        """Interval draws and pushes for the worlds whose interval is due (by their episode's step count)."""
        self.model.before_physics(progress)
        self.delay.before_physics(progress)
        if self.push is not None:
            self.push.before_physics(progress, self.sim)

    def actions(self, actions: torch.Tensor) -> torch.Tensor:
        """The actions that reach the task this step: delayed by each env's delay, then noised."""
        return self.noise.actions(self.delay.apply(actions))

    def observations(self, obs: torch.Tensor) -> None:
        """Add the per-term and the section-wide observation noise to the policy observation, in place."""
        self.noise.observations(obs)

    def count_step(self) -> None:
        self.model.count_step()
