"""`DmControlEntity`: a dm_control `composer.Entity` in a composition.

dm_control's walkers, arenas and props (`locomotion.walkers.ant.Ant`,
`locomotion.arenas.floors.Floor`, `entities.props.Primitive`, ...) are
entities of dm_control's composer: their models are PyMJCF, which this
package composes (`mjx_composer.model.pymjcf`), but their hooks are NumPy
code on a stateful physics. Wrapping one carries its model, its element
handles and its `MJCFFeature` observables into a composition; see the class
for what is not carried.
"""

from __future__ import annotations

from mjx_composer import entity as entity_lib
from mjx_composer.model import layouts
from mjx_composer.model import pymjcf
from mjx_composer.observation import observable


class DmControlEntity(entity_lib.Entity):
  """A dm_control `composer.Entity` (walker, arena, prop) in a composition.

  Wrap a dm_control entity to attach it, or to make it a task's root entity
  (an arena): `arena.add_free_entity(DmControlEntity(ant.Ant()))`.

  Carried: the entity's PyMJCF model, as it stands when the environment is
  built (its PyMJCF elements bind, observe and vary like MjSpec handles),
  and its attributes: any name this class does not define is read from the
  dm_control entity (`walker.actuators`, `walker.end_effectors`,
  `walker.observable_joints`, `arena.ground_geoms`, ...). Its observables of
  type `MJCFFeature` become this entity's observables (enabled as they
  were, with their index, update interval, buffer size, delay and
  aggregator).

  Not carried: the entity's hooks (`initialize_episode`, `before_step`, ...:
  NumPy code that writes a stateful physics in place, which cannot run on
  a traced, pure physics), its `Generic` and camera observables, and the
  corruptors of its observables. Composer's frame and pose methods
  (`root_body`, `get_pose`, `set_pose`, `shift_pose`, `set_velocity`,
  `configure_joints`, `attach`) are this class's, acting on the wrapped
  model. Port a hook into a subclass when you need it.

  Args:
    entity: a dm_control `composer.Entity` that is not attached (use
      `Entity.attach`, not dm_control's).
  """

  def _build(self, entity):  # pylint: disable=arguments-differ
    if not pymjcf.is_dm_control_entity(entity):
      raise TypeError(
          'DmControlEntity wraps a dm_control composer.Entity, got '
          f'{type(entity).__name__}.'
      )
    if entity.parent is not None:
      raise ValueError(
          f'dm_control entity {entity.mjcf_model.model!r} is attached to '
          f"{entity.parent.mjcf_model.model!r} with dm_control's attach: "
          "attach it with this package's Entity.attach instead."
      )
    self._entity = entity

  @property
  def mjcf_model(self):
    return self._entity.mjcf_model

  @property
  def entity(self):
    """The wrapped dm_control entity."""
    return self._entity

  _episode_layouts = None

  def regenerate_per_episode(self, layouts_count: int):
    """A wrapped arena's `regenerate`, per episode: see `Arena`'s method."""
    if not callable(getattr(self._entity, 'regenerate', None)):
      raise TypeError(
          f'{type(self._entity).__name__} has no regenerate(random_state): '
          'only arenas regenerate.'
      )
    self._episode_layouts = layouts.EpisodeLayouts(layouts_count)

  def after_compile(self, physics, random_state):
    if self._episode_layouts is not None:
      root = self
      while root.parent is not None:
        root = root.parent
      self._episode_layouts.sample(root, self._entity.regenerate, random_state)

  def initialize_episode(self, physics, key):
    if self._episode_layouts is not None:
      physics = self._episode_layouts.apply(physics, key)
    return physics

  def add_free_entity(self, entity_to_add):
    """Attaches an entity with a freejoint on its frame; returns the frame.

    Composer's `Arena.add_free_entity`, through this package's `attach`
    (dm_control's would merge the entity into the arena's PyMJCF model).
    """
    frame = self.attach(entity_to_add)
    frame.add('freejoint')
    return frame

  def __getattr__(self, name):
    # Only names this class lacks get here (dm_control's own attributes).
    if name.startswith('__') or '_entity' not in self.__dict__:
      raise AttributeError(name)
    return getattr(self.__dict__['_entity'], name)

  def _build_observables(self):
    observables = observable.Observables(self)
    for name, obs in self._entity.observables.as_dict(
        fully_qualified=False
    ).items():
      if type(obs).__name__ != 'MJCFFeature':
        continue
      # pylint: disable=protected-access
      ours = observable.MJCFFeature(
          obs._kind,
          obs._mjcf_element,
          update_interval=obs.update_interval,
          buffer_size=obs.buffer_size,
          delay=obs.delay,
          aggregator=obs.aggregator,
          index=obs._index,
      )
      ours.enabled = obs.enabled
      observables.add_observable(name, ours, enabled=obs.enabled)
    return observables
