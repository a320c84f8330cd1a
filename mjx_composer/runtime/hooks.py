"""`EnvironmentHooks`: the task's, the entities' and extra hooks, in order.

Composer's `_EnvironmentHooks` gathers, once, every participant that
overrides a hook and calls them in order: the task first, then the entities
in depth-first attachment order, then hooks added with
`Environment.add_extra_hook`. This is the same, with one named method per
hook and pure device hooks:

* build time (host, once): `initialize_episode_mjcf(random_state)` and
  `after_compile(physics, random_state)`; an MJCF variator that an
  `initialize_episode_mjcf` hook applies the composer way
  (`apply_variations(random_state)`) is applied per episode on the device,
  before the `initialize_episode` hooks (`episode_variations`);
* device (pure, traced): `initialize_episode(physics, key)`,
  `before_step(physics, action, key)`, `before_substep(physics, action,
  key)`, `after_substep(physics, key)`, `after_step(physics, key)`. The task
  and extra hooks receive the action in `before_step`/`before_substep`;
  entities never do.

Keys: each participant's key is `fold_in(key, id)` where `id` is derived
from a stable identity of the participant (the task; an entity's full
identifier; an extra hook's registration slot), so overriding one more hook,
or attaching another entity, never changes the draws of the others.

Model fields: a device hook that writes a model field (a variator writing
`geom_size`, a step hook recolouring a geom) makes that field per-world.
`model_field_writers` and `step_model_field_writers` say which participant
writes which field (abstract traces of the hooks), so that the environment
carries those fields per world from the reset on, and can report why. Step
hooks may update, never add, per-world entries (`check_step_writes`).

Porting checks, at trace time: a device hook whose parameter is named
`random_state` is refused (it receives a JAX key); so is a hook that wrote
to the `Physics` it received and then returned that very object
(`Physics.wrote_to_result`): every write returns a new `Physics`, and
dropping it (`walker.shift_pose(physics, ...)` without keeping the result)
would lose the write silently; so is a device hook that draws from NumPy's
random module (`numpy.random.uniform`, ..., the legacy global `RandomState`,
a generator made in the hook: `HostRandomnessError`), whose draw would be
one constant for every world and episode. At build, an
`initialize_episode_mjcf` hook
that draws from the `random_state` it receives (composer's way to place a
target per episode) is warned about (`BuildTimeDrawWarning`): it runs once,
so the draw is one value for every world and episode.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from typing import Any, Callable
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer import entity as entity_lib
from mjx_composer import physics as physics_lib
from mjx_composer import task as task_lib
from mjx_composer.platform import internals_numpy
from mjx_composer.runtime import keys as keys_lib
from mjx_composer.variation import mjcf_variator


class BuildTimeDrawWarning(UserWarning):
  """An `initialize_episode_mjcf` hook drew from its `random_state`.

  composer runs the hook before every episode, so such a draw (an MJCF
  attribute set from it, a value kept on the task) is new every episode;
  here the hook runs once, when the `Environment` is built, and the draw is
  the same in every world and every episode.
  """


class HostRandomnessError(RuntimeError):
  """A device hook drew from NumPy's random module while it was traced.

  Device hooks (`initialize_episode`, the step hooks, scheduled hooks) run
  once, when the reset or step is traced; a NumPy draw there is a constant
  of the compiled program, the same in every world and every episode.
  Raised at trace time, naming the hook; the fix is a draw from the hook's
  `key` with `jax.random`.
  """


HOOK_NAMES = (
    'initialize_episode_mjcf',
    'after_compile',
    'initialize_episode',
    'before_step',
    'before_substep',
    'after_substep',
    'after_step',
)
# Hooks through which the task (and extra hooks) receive the action.
_ACTION_HOOKS = ('before_step', 'before_substep')


@dataclasses.dataclass(frozen=True)
class Participant:
  """One overridden hook of one owner.

  Attributes:
    identity: a stable identity of the owner ('task', 'entity:<full
      identifier>', 'extra:<hook name>:<slot>'); the hook's key derives from
      it.
    describe: the owner as error messages and reports name it.
    hook: the callable.
    takes_action: whether the hook receives the action.
  """

  identity: str
  describe: str
  hook: Callable[..., Any]
  takes_action: bool


def _keyed(participants, key):
  """`(participant, its key)` pairs (`keys.hook_keys`: one hash for all)."""
  return zip(participants, keys_lib.hook_keys(key, participants))


def _overrides(obj, name: str, base_cls) -> bool:
  method = getattr(type(obj), name, None)
  return method is not None and method is not getattr(base_cls, name, None)


class EnvironmentHooks:
  """Calls every participant's hook in composer's order.

  Args:
    task: the `Task`; its root entity's tree gives the entities.
  """

  def __init__(self, task):
    self._task = task
    self._extra: dict[str, list[Callable]] = {name: [] for name in HOOK_NAMES}
    # The MJCF variators that `initialize_episode_mjcf` hooks applied the
    # composer way, as participants (`episode_variations`).
    self._episode_variators: list[Participant] = []

  def add_extra_hook(self, hook_name: str, hook: Callable):
    """See `Environment.add_extra_hook`."""
    if hook_name not in HOOK_NAMES:
      raise ValueError(
          f'{hook_name!r} is not a valid hook name. Valid hook '
          f'names: {HOOK_NAMES}'
      )
    if not callable(hook):
      raise ValueError(f'{hook!r} is not a callable.')
    self._extra[hook_name].append(hook)

  def participants(self, name: str) -> list[Participant]:
    """The participants of hook `name`, in calling order."""
    takes_action = name in _ACTION_HOOKS
    out = []
    # The task's before_step writes the action into ctrl even if not
    # overridden; its other hooks run only where overridden.
    if name == 'before_step' or _overrides(self._task, name, task_lib.Task):
      out.append(
          Participant(
              'task',
              type(self._task).__name__,
              getattr(self._task, name),
              takes_action,
          )
      )
    for entity in self._task.root_entity.iter_entities():
      if _overrides(entity, name, entity_lib.Entity):
        out.append(
            Participant(
                f'entity:{entity.full_identifier}',
                f'{type(entity).__name__}({entity.name!r})',
                getattr(entity, name),
                False,
            )
        )
    for slot, hook in enumerate(self._extra[name]):
      out.append(
          Participant(
              f'extra:{name}:{slot}',
              getattr(hook, '__qualname__', repr(hook)),
              hook,
              takes_action,
          )
      )
    return out

  def has(self, name: str) -> bool:
    return bool(self.participants(name))

  def initializes(self) -> bool:
    """Whether a reset runs anything per episode: `initialize_episode`
    hooks or `episode_variations`."""
    return self.has('initialize_episode') or bool(self._episode_variators)

  def model_field_writers(
      self, name: str, physics, key, action=None
  ) -> dict[str, tuple[str, ...]]:
    """`{model field: the hooks that write it}` of hook `name` on `physics`.

    From an abstract trace of the hooks (`jax.eval_shape`): nothing is
    computed. `key` and `action` may be shapes.
    """
    writers = {}
    jax.eval_shape(
        lambda key, action: self._run(name, physics, key, action, writers),
        key,
        action,
    )
    return dict(sorted(writers.items()))

  def step_model_field_writers(
      self, physics, key, action
  ) -> dict[str, tuple[str, ...]]:
    """`{model field: the hooks that write it}` of a control step's hooks.

    From an abstract trace (`jax.eval_shape`; `physics`, `key` and `action`
    may be shapes) of the scheduled, `before_step`, `before_substep`,
    `after_substep` and `after_step` hooks in a step's order, each seeing
    its physics as the step passes it on: rebuilt from the sub-step
    loop's carry before `before_substep`, after the physics step, and after
    the last one's forward pass (a new `Physics`, with no record of
    unsynced writes: `replace`).
    """
    writers = {}

    def run(physics, key, action):
      physics = self.scheduled(physics, key, writers)
      physics = self._run('before_step', physics, key, action, writers)
      physics = physics.replace()
      physics = self._run('before_substep', physics, key, action, writers)
      physics = physics.replace()
      physics = self._run('after_substep', physics, key, None, writers)
      return self._run('after_step', physics.replace(), key, None, writers)

    jax.eval_shape(run, physics, key, action)
    return dict(sorted(writers.items()))

  # -- build time (host) ----------------------------------------------------

  def initialize_episode_mjcf(self, random_state):
    """Runs `initialize_episode_mjcf`, and records the MJCF variators that
    each hook applies composer's way (`apply_variations(random_state)`)."""
    self._episode_variators = []
    owners = [('task', type(self._task).__name__, self._task)] + [
        (
            f'entity:{entity.full_identifier}',
            f'{type(entity).__name__}({entity.name!r})',
            entity,
        )
        for entity in self._task.root_entity.iter_entities()
    ]
    hooks = [
        (identity, describe, owner.initialize_episode_mjcf)
        for identity, describe, owner in owners
    ] + [
        (
            f'extra:initialize_episode_mjcf:{slot}',
            getattr(hook, '__qualname__', repr(hook)),
            hook,
        )
        for slot, hook in enumerate(self._extra['initialize_episode_mjcf'])
    ]
    for identity, describe, hook in hooks:
      before = random_state.get_state()
      with mjcf_variator.collecting_episode_calls() as calls:
        hook(random_state)
      if _drew(before, random_state.get_state()):
        warnings.warn(
            BuildTimeDrawWarning(
                f'{describe}.initialize_episode_mjcf drew from random_state. '
                'composer runs it before every episode; here it runs once, '
                'when the Environment is built, so what it drew (an MJCF '
                "attribute such as a target's position, a value kept on "
                'self) is the same in every world and every episode. Draw '
                'per episode instead: bind the attribute to a '
                'variation.MJCFVariator (its apply_variations(random_state) '
                'in this hook applies it at every reset, per world), set '
                'the value in initialize_episode from its key, or, for an '
                "arena's regenerate(random_state), call "
                'Arena.regenerate_per_episode(count).'
            ),
            stacklevel=2,
        )
      for i, variator in enumerate(calls):
        self._episode_variators.append(
            Participant(
                f'{identity}:mjcf_variator:{i}',
                describe,
                variator.apply_variations,
                False,
            )
        )

  def after_compile(self, physics, random_state):
    """Runs `after_compile`; returns the physics the last hook returned."""
    for participant in self._host_participants('after_compile'):
      result = participant(physics, random_state)
      if isinstance(result, physics_lib.Physics):
        physics = result
    return physics

  def _host_participants(self, name):
    # Composer calls build-time hooks on every participant (they are cheap
    # no-ops by default).
    owners = [self._task] + list(self._task.root_entity.iter_entities())
    return [getattr(owner, name) for owner in owners] + self._extra[name]

  # -- device (pure) ----------------------------------------------------------

  def episode_variations(self, physics, key, writers=None):
    """Applies the MJCF variators that `initialize_episode_mjcf` hooks
    applied composer's way, in their order, each with the key of its own
    identity (its owner's, and its place among that owner's calls);
    `writers` as in `initialize_episode`."""
    name = 'initialize_episode_mjcf'
    for participant, hook_key in _keyed(self._episode_variators, key):
      result = self._call(participant, name, physics, hook_key, None)
      _record_writers(
          writers, f'{participant.describe}.{name}', physics, result
      )
      physics = result
    return physics

  def initialize_episode(self, physics, key, writers=None):
    """Runs `initialize_episode`; `writers`, where given, a dict that
    receives `{model field: the hooks that wrote it}`."""
    return self._run('initialize_episode', physics, key, writers=writers)

  def before_step(self, physics, action, key):
    return self._run('before_step', physics, key, action)

  def before_substep(self, physics, action, key):
    return self._run('before_substep', physics, key, action)

  def after_substep(self, physics, key):
    return self._run('after_substep', physics, key)

  def after_step(self, physics, key):
    return self._run('after_step', physics, key)

  def scheduled(self, physics, key, writers=None):
    """Runs the hooks registered with `Physics.schedule_before_step`;
    `writers` as in `initialize_episode`."""
    participants = [
        Participant(f'scheduled:{name}', name, hook, False)
        for name, hook in physics.scheduled_hooks
    ]
    for participant, hook_key in _keyed(participants, key):
      result = self._call(participant, 'scheduled', physics, hook_key, None)
      _record_writers(
          writers, f'{participant.describe} (scheduled)', physics, result
      )
      physics = result
    return physics

  def _run(self, name, physics, key, action=None, writers=None):
    for participant, hook_key in _keyed(self.participants(name), key):
      result = self._call(participant, name, physics, hook_key, action)
      label = f'{participant.describe}.{name}'
      _record_writers(writers, label, physics, result)
      physics = result
    return physics

  def _call(self, participant, name, physics, hook_key, action):
    """`participant`'s hook `name` with its own key (`keys.hook_keys`)."""
    _check_takes_key(participant, name)
    physics.forget_writes()
    refusal = functools.partial(_host_randomness_error, participant, name)
    with internals_numpy.refusing_host_randomness(refusal):
      if participant.takes_action:
        result = participant.hook(physics, action, hook_key)
      else:
        result = participant.hook(physics, hook_key)
    if not isinstance(result, physics_lib.Physics):
      raise TypeError(
          f'{participant.describe}.{name} returned {type(result).__name__}: '
          'device hooks are pure and must return the (new) Physics.'
      )
    if result is physics and physics.wrote_to_result():
      raise ValueError(
          f'{participant.describe}.{name} wrote to the physics it received '
          "(a binding's set, set_control, update_task_state, a method such "
          'as walker.shift_pose(physics, ...) that returns the new Physics) '
          'and then returned the physics it received, so the write is lost. '
          'Every write returns a new Physics: keep it, `physics = '
          'walker.shift_pose(physics, ...)`, and return the last one.'
      )
    return result


def _host_randomness_error(participant, name, what):
  """The `HostRandomnessError` for `participant`'s hook `name` drawing
  `what` (e.g. 'numpy.random.uniform')."""
  return HostRandomnessError(
      f'{participant.describe}.{name} drew host randomness ({what}). Device '
      'hooks are traced once and compiled: a NumPy draw runs once, while the '
      'hook is traced, and its value is a constant of the program, the same '
      "in every world and every episode. Draw from the hook's `key` "
      'argument with jax.random instead (e.g. jax.random.uniform(key, shape, '
      'minval=..., maxval=...); jax.random.split(key) for several draws, or '
      'pass key=... to a variation or initializer). A value meant to be '
      'drawn once, when the environment is built, belongs in a build-time '
      'hook (initialize_episode_mjcf or after_compile, which receive a '
      'random_state).'
  )


def _record_writers(writers, label, before, after):
  """Adds `label` to `writers[field]` for each model field that a hook
  wrote from `before` to `after` (nothing where `writers` is None)."""
  if writers is None:
    return
  for field in physics_lib.changed_model_fields(before.model, after.model):
    labels = writers.get(field, ())
    if label not in labels:
      writers[field] = labels + (label,)


def _check_takes_key(participant, name):
  """Refuses a device hook whose parameter is composer's `random_state`."""
  try:
    parameters = inspect.signature(participant.hook).parameters
  except (TypeError, ValueError):
    return
  if 'random_state' in parameters:
    raise TypeError(
        f'{participant.describe}.{name} takes random_state: device hooks '
        'receive a JAX PRNG key, not a numpy RandomState. Rename the '
        'parameter to key, draw with jax.random (or pass key=... to '
        'variations and initializers), and return the new Physics.'
    )


def check_step_writes(before, after, fields, hook_names):
  """Step hooks may update, not add, per-world fields and persistent entries.

  Raises a `ValueError` (while the step is traced) where the `hook_names`
  hooks, run from the `Physics` `before` to `after`, wrote a model field
  that is not among the per-world `fields` (the reset makes per-world every
  field that `step_model_field_writers` finds written, so this means a hook
  wrote differently when the step was traced), scheduled a hook, or added,
  removed or reshaped a persistent entry or entity state.
  """
  changed = physics_lib.changed_model_fields(before.model, after.model)
  undeclared = sorted(set(changed) - set(fields))
  if undeclared:
    raise ValueError(
        f'The {hook_names} hooks wrote model fields {undeclared} that are not '
        'per-world. Declare them with Environment(..., options='
        f'ExecutionOptions(per_world_model_fields={tuple(undeclared)!r})), or '
        'write them in '
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


def _drew(before, after) -> bool:
  """Whether a numpy `RandomState` drew between its states `before` and
  `after` (`get_state()`: the generator's name, key, position and cached
  Gaussian)."""
  return any(
      not np.array_equal(a, b) for a, b in zip(before, after, strict=True)
  )
