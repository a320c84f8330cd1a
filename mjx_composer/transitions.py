"""`Transitions`: one world's reset and control step, as pure functions.

`Environment` checks arguments, compiles and owns the public API; this
module is what runs on the device for one world: the reset with its bounded
initialization attempts, and the control step with its sub-step scan. Both
are written so that each expensive piece (the `initialize_episode` hooks,
`mjx.step`) is traced once and appears once in the lowered program.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from mujoco import mjx

from mjx_composer import episode as episode_lib
from mjx_composer import physics as physics_lib
from mjx_composer import state as state_lib


def initial_physics(task, model, data, index) -> physics_lib.Physics:
  """One world before any hook: `model`, `data`, the declared initial state."""
  entity_states = {}
  for entity in task.root_entity.iter_entities():
    initial = entity.initial_state()
    if initial is not None:
      entity_states[entity.full_identifier] = initial
  return physics_lib.Physics(
      model=model,
      data=data,
      task_state=task.initial_task_state(),
      index=index,
      persistent={},
      initialization_failed=jnp.zeros((), bool),
      entity_states=entity_states,
  )


def forward_without_actuation(physics):
  """`mj_forward` with actuation disabled, as composer's reset context does."""
  opt = physics.model.opt
  model = physics.model.replace(
      opt=opt.replace(disableflags=opt.disableflags | mjx.DisableBit.ACTUATION)
  )
  return physics.replace(data=mjx.forward(model, physics.data))


@dataclasses.dataclass(frozen=True)
class Transitions:
  """Reset and step of one world (see `Environment` for their contract).

  Attributes:
    initial: the `Physics` every world starts from (`initial_physics`).
    hooks: the `hooks.EnvironmentHooks`.
    updater: the observation `Updater`.
    episode: the `episode.EpisodeRules`.
    n_sub_steps: physics steps per control step.
    max_reset_attempts: initialization attempts per reset.
    declared_model_fields: model fields that step hooks may write.
  """

  initial: physics_lib.Physics
  hooks: object
  updater: object
  episode: episode_lib.EpisodeRules
  n_sub_steps: int
  max_reset_attempts: int
  declared_model_fields: tuple

  def physics(self, state: state_lib.State) -> physics_lib.Physics:
    """The `Physics` of a `State`."""
    return self._restore(
        physics_lib.PhysicsCarry(
            data=state.data,
            task_state=state.task_state,
            entity_states=state.entity_states,
            model_fields=state.model_fields,
            persistent=state.persistent,
            initialization_failed=None,
            scheduled_hooks=state.scheduled_hooks,
        )
    )

  def per_world_model_fields(self) -> dict[str, tuple[str, ...]]:
    fields = dict(self.hooks.model_field_writers)
    for name in self.declared_model_fields:
      fields[name] = fields.get(name, ()) + (
          'Environment(per_world_model_fields=...)',
      )
    return dict(sorted(fields.items()))

  def _restore(self, carry) -> physics_lib.Physics:
    return carry.restore(self.initial.model, self.initial.index)

  # -- reset ---------------------------------------------------------------

  def reset(self, key, previous: state_lib.State | None = None):
    """A new episode; `previous` is the world's last state on auto-reset."""
    init_key, obs_key, next_key = jax.random.split(key, 3)
    start = self.initial.carry(())
    if previous is not None:
      # An auto-reset keeps the world's model and persistent entries.
      start = start.replace(
          model_fields=previous.model_fields,
          persistent=previous.persistent,
          scheduled_hooks=previous.scheduled_hooks,
      )
    carry, failures = self._initialize(init_key, start)
    physics = forward_without_actuation(self._restore(carry))
    return _state(
        physics,
        tuple(carry.model_fields),
        self.updater.reset(physics, obs_key),
        self.updater,
        next_key,
        self.episode.start(physics, failures),
    )

  def restart(self, stepped: state_lib.State) -> state_lib.State:
    """Same-step auto-reset: the next episode, reporting the ended one."""
    restarted = self.reset(stepped.key, previous=stepped)
    return restarted.replace(
        step_type=stepped.step_type,
        reward=stepped.reward,
        discount=stepped.discount,
        terminated=stepped.terminated,
        truncated=stepped.truncated,
        final_observation=stepped.final_observation,
        metrics=stepped.metrics,
    )

  def _attempt(self, key, start):
    """One run of the `initialize_episode` hooks from `start`."""
    physics = self._restore(start)
    if self.hooks.has('initialize_episode'):
      # Composer runs a whole forward pass here; the hooks read poses, so
      # kinematics suffices, and keeps a second copy of the collision and
      # constraint code out of every program that contains a reset (the
      # step program does, through auto-reset).
      physics = physics.kinematics()
      physics = self.hooks.initialize_episode(physics, key)
    base = self.initial.model
    changed = {
        f.name
        for f in dataclasses.fields(mjx.Model)
        if getattr(physics.model, f.name) is not getattr(base, f.name)
    }
    fields = sorted(changed | set(self.declared_model_fields))
    return physics.carry(fields)

  def _initialize(self, init_key, start):
    """The initialized carry and the number of failed attempts.

    With `max_reset_attempts > 1`, failed attempts are resampled with fresh
    keys; every attempt starts from the same model and persistent entries,
    so a failed attempt leaves no trace but its key. The hooks are traced
    once: the loop's body evaluates that trace.
    """
    if self.max_reset_attempts == 1 or not self.hooks.has('initialize_episode'):
      carry = self._attempt(init_key, start)
      return carry, carry.initialization_failed.astype(jnp.int32)
    attempt, shapes = episode_lib.trace_once(
        self._attempt, init_key, start, return_shapes=True
    )

    def body(loop):
      attempts, failures, _ = loop
      key = _select_key(
          attempts == 0, init_key, jax.random.fold_in(init_key, attempts)
      )
      carry = attempt(key, start)
      failed = carry.initialization_failed.astype(jnp.int32)
      return attempts + 1, failures + failed, carry

    def again(loop):
      attempts, _, carry = loop
      return jnp.logical_or(
          attempts == 0,
          jnp.logical_and(
              carry.initialization_failed, attempts < self.max_reset_attempts
          ),
      )

    placeholder = jax.tree.map(_zeros_like_shape, shapes)
    _, failures, carry = jax.lax.while_loop(
        again,
        body,
        (jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32), placeholder),
    )
    return carry, failures

  # -- step ----------------------------------------------------------------

  def step(self, state: state_lib.State, action) -> state_lib.State:
    """One control step; episode ends are decided, not acted on."""
    before_key, substep_key, after_key, obs_key, next_key = jax.random.split(
        state.key, 5
    )
    physics = self.physics(state)
    fields = tuple(state.model_fields)
    start = physics
    physics = self.hooks.scheduled(physics, before_key)
    physics = self.hooks.before_step(physics, action, before_key)
    _check_step_writes(start, physics, fields, 'before_step')
    n = self.n_sub_steps

    def substep(loop, i):
      carry, obs_state = loop
      physics = self._restore(carry)
      sub_key = jax.random.fold_in(substep_key, i)
      physics = self.hooks.before_substep(
          physics, action, jax.random.fold_in(sub_key, 0)
      )
      physics = physics.step()
      physics = self.hooks.after_substep(
          physics, jax.random.fold_in(sub_key, 1)
      )
      _check_step_writes(start, physics, fields, 'before_substep/after_substep')
      if n > 1:
        # Sub-steps 1..n-1 update the observations here; the updater skips,
        # at trace time, every observable that cannot be sampled there. The
        # last sub-step's update comes after the after_step hooks.
        obs_state = jax.lax.cond(
            i < n - 1,
            lambda: self.updater.update(
                obs_state,
                physics,
                jax.random.fold_in(sub_key, 2),
                i + 1,
                substep_bounds=(1, n - 1),
            ),
            lambda: obs_state,
        )
      return (physics.carry(fields), obs_state), None

    (carry, obs_state), _ = jax.lax.scan(
        substep,
        (physics.carry(fields), state.obs_state),
        jnp.arange(n, dtype=jnp.int32),
    )
    physics = self.hooks.after_step(self._restore(carry), after_key)
    _check_step_writes(start, physics, fields, 'after_step')
    return _state(
        physics,
        fields,
        self.updater.update(obs_state, physics, obs_key, n),
        self.updater,
        next_key,
        self.episode.end_of_step(state, physics),
    )


def _state(physics, fields, obs_state, updater, key, episode_fields):
  """The `State` of `physics` with its observation and episode fields."""
  observation = updater.get_observation(obs_state)
  return state_lib.State(
      data=physics.data,
      task_state=physics.task_state,
      entity_states=physics.entity_states,
      model_fields={f: getattr(physics.model, f) for f in fields},
      persistent=physics.persistent,
      obs_state=obs_state,
      observation=observation,
      final_observation=observation,
      key=key,
      scheduled_hooks=physics.scheduled_hooks,
      **episode_fields,
  )


def _check_step_writes(before, after, fields, hook_names):
  """Step hooks may update, not add, per-world fields and persistent entries."""
  changed = [
      f.name
      for f in dataclasses.fields(mjx.Model)
      if getattr(after.model, f.name) is not getattr(before.model, f.name)
  ]
  undeclared = sorted(set(changed) - set(fields))
  if undeclared:
    raise ValueError(
        f'The {hook_names} hooks wrote model fields {undeclared} that are not '
        'per-world. Declare them with Environment(..., '
        f'per_world_model_fields={tuple(undeclared)!r}), or write them in '
        'initialize_episode.'
    )
  if after.scheduled_hooks != before.scheduled_hooks:
    raise ValueError(
        f'The {hook_names} hooks scheduled a hook: call '
        'physics.schedule_before_step from initialize_episode.'
    )
  shapes = lambda tree: jax.tree.map(
      lambda x: (jnp.shape(x), jnp.result_type(x)), tree
  )
  for name, old, new in (
      ('persistent', before.persistent, after.persistent),
      ('entity state', before.entity_states, after.entity_states),
  ):
    if jax.tree.structure(old) != jax.tree.structure(new) or shapes(
        old
    ) != shapes(new):
      raise ValueError(
          f'The {hook_names} hooks added, removed or reshaped {name} '
          f'entries (before: {shapes(old)}, after: {shapes(new)}). Create '
          f'every {name} entry with its final shape and dtype (persistent '
          'entries in initialize_episode, entity state in '
          'Entity.initial_state); step hooks may only update it.'
      )


def _select_key(pred, on_true, on_false):
  data = jnp.where(
      pred, jax.random.key_data(on_true), jax.random.key_data(on_false)
  )
  return jax.random.wrap_key_data(data, impl=jax.random.key_impl(on_true))


def _zeros_like_shape(shape):
  if jnp.issubdtype(shape.dtype, jax.dtypes.prng_key):
    return jax.random.wrap_key_data(
        jnp.zeros(
            shape.shape + jax.random.key_data(jax.random.key(0)).shape,
            jnp.uint32,
        ),
        impl=jax.random.key_impl(jax.random.key(0)),
    )
  return jnp.zeros(shape.shape, shape.dtype)
