"""`Entity`: a reusable piece of a scene that owns its own `mujoco.MjSpec`.

Entities are composed into a tree with `attach`. Composition is *lazy*: each
entity keeps its own, untouched spec (what `_build` made), and the tree is only
merged into one spec, on a copy, when the environment compiles. That keeps
three composer guarantees that MjSpec's attach-by-reference cannot:

* the same entity class can be instantiated and attached many times;
* `detach()` restores the tree exactly (a child spec attached by reference
  can never be compiled or attached again);
* element handles taken from an entity's own spec (`self._hand_site`) stay the
  handles users bind to; the compiler resolves them to compiled indices.

Names of attached elements are prefixed with `"<entity name>/"`, so a site
`hand` of an arm attached as `arm` compiles to `arm/hand`, and the attachment
frame body (which may carry a freejoint) is named `arm/`, as in dm_control.

PyMJCF. An entity's model may instead be a `dm_control.mjcf.RootElement`
(`mjcf.from_path(...)`, `mjcf.RootElement()`), as dm_control's entities
build it: it is converted to an MjSpec each time the tree is composed
(`model/pymjcf.py`), and the PyMJCF elements it hands out (bodies, joints,
sites, geoms, actuators, sensors, cameras) bind, observe, vary and host
attachments like MjSpec handles. PyMJCF and MjSpec entities attach to each
other in either direction. A dm_control `composer.Entity` itself (its
walkers, arenas and props) attaches wrapped in
`entities.dm_control_entity.DmControlEntity`.

Hooks. The build-time hooks `initialize_episode_mjcf(random_state)` and
`after_compile(physics, random_state)` run once on the host when the
environment is built (with a `numpy.random.RandomState`); an `MJCFVariator`
that `initialize_episode_mjcf` applies composer's way runs every episode. The per-episode and
per-step hooks are pure functions on the device: they take a `Physics` and a
JAX PRNG key and must return the new `Physics`. Unlike composer, they cannot
mutate anything in place, and must not keep per-world state on `self` (declare
it in `Task.initial_task_state` instead).
"""

from __future__ import annotations

import abc
import warnings
import weakref
from typing import Iterator

import jax.numpy as jnp
import mujoco

from mjx_composer.model import composition_checks
from mjx_composer.model import element_index
from mjx_composer.model import pymjcf
from mjx_composer.utils import transformations as tr

_DEFAULT_SPEC_NAME = 'MuJoCo Model'
# The bindable kind of each MjSpec element list.
_BINDABLE_LISTS = {
    attr: kind for kind, attr in element_index.SPEC_LISTS.items()
}


class Entity(abc.ABC):
  """The base class for robots, props and arenas.

  Subclasses implement `_build` (create the spec and remember element handles)
  and the `mjcf_model` property, and may override `_build_observables` and the
  hooks. The constructor is not meant to be overridden.
  """

  def __init__(self, *args, **kwargs):
    self._parent = None  # weakref to the parent entity
    self._attached: list[Entity] = []
    self._attachment_frame = None  # MjsBody in the parent's own spec
    observable_options = kwargs.pop('observable_options', None)
    try:
      self._build(*args, **kwargs)
    except AttributeError as e:
      hinted = pymjcf.spec_attribute_error(e, f'{type(self).__name__}._build')
      if hinted is not None:
        raise hinted from e
      raise
    spec = self.mjcf_model
    if pymjcf.is_root(spec):
      if not spec.model:
        spec.model = type(self).__name__.lower()
    elif not isinstance(spec, mujoco.MjSpec):
      raise TypeError(
          f'{type(self).__name__}.mjcf_model must return a '
          'mujoco.MjSpec or a dm_control mjcf.RootElement, got '
          f'{type(spec).__name__}.'
      )
    elif not spec.modelname or spec.modelname == _DEFAULT_SPEC_NAME:
      spec.modelname = type(self).__name__.lower()
    if '/' in self.name:
      raise ValueError(f'Entity name {self.name!r} must not contain "/".')
    self._observables = self._build_observables()
    self._observables.set_options(observable_options)

  @abc.abstractmethod
  def _build(self, *args, **kwargs):
    """Creates the entity's `MjSpec` and any element handles it keeps."""

  def _build_observables(self):
    """Returns this entity's `Observables`; override to declare your own."""
    from mjx_composer.observation import observable  # pylint: disable=g-import-not-at-top

    return observable.Observables(self)

  @property
  @abc.abstractmethod
  def mjcf_model(self) -> mujoco.MjSpec:
    """The entity's own model (never the composed one).

    A `mujoco.MjSpec`, or a dm_control `mjcf.RootElement`.
    """

  @property
  def name(self) -> str:
    """The entity name, used as the prefix `"<name>/"` when attached."""
    model = self.mjcf_model
    if pymjcf.is_root(model):
      return pymjcf.model_name(model)
    return model.modelname

  @property
  def full_identifier(self) -> str:
    """Prefix of this entity's compiled names: '' at the root, 'a/b/' below."""
    parent = self.parent
    if parent is None:
      return ''
    return parent.full_identifier + self.name + '/'

  @property
  def observables(self):
    return self._observables

  # -- per-world state -----------------------------------------------------

  def initial_state(self):
    """This entity's per-episode state at the start of an episode, or None.

    Like `Task.initial_task_state`: a pytree (usually a dict of arrays) whose
    structure, shapes and dtypes are fixed for the environment's life, one
    copy per world, reset at every episode. Read it with
    `physics.entity_state(self)` and write it with
    `physics.update_entity_state(self, **values)`. State that must outlive
    an episode goes in persistent entries (`physics.set_persistent`).
    """
    return None

  # -- hooks ---------------------------------------------------------------
  # Build time (host). `random_state` is a numpy RandomState.

  def initialize_episode_mjcf(self, random_state):
    """Edits the spec before compilation. Runs once, at environment build.

    An `MJCFVariator` applied here composer's way,
    `apply_variations(random_state)`, is applied at every reset, per world.
    """

  def after_compile(self, physics, random_state):
    """Runs once after compilation; may return a Physics whose model is kept."""

  # Device (pure). Each returns the new Physics.

  def initialize_episode(self, physics, key):
    """Sets up the episode (e.g. randomizes poses); returns the Physics."""
    return physics

  def before_step(self, physics, key):
    """Runs before the control step's sub-steps; returns the Physics."""
    return physics

  def before_substep(self, physics, key):
    """Runs before each physics sub-step; returns the Physics."""
    return physics

  def after_substep(self, physics, key):
    """Runs after each physics sub-step; returns the Physics."""
    return physics

  def after_step(self, physics, key):
    """Runs after the control step's sub-steps; returns the Physics."""
    return physics

  # -- tree ----------------------------------------------------------------

  @property
  def parent(self) -> Entity | None:
    return self._parent() if self._parent is not None else None

  @property
  def attachment_site(self):
    """Where children attach by default: this entity's worldbody."""
    return self.mjcf_model.worldbody

  def iter_entities(self, exclude_self=False) -> Iterator[Entity]:
    """Depth-first pre-order over the tree, children in attachment order."""
    if not exclude_self:
      yield self
    for child in self._attached:
      yield from child.iter_entities()

  def attach(self, entity: Entity, attach_site=None) -> mujoco.MjsBody:
    """Attaches `entity` below this one and returns its attachment frame.

    Args:
      entity: an entity with no parent (a dm_control `composer.Entity`
        attaches wrapped: `entities.dm_control_entity.DmControlEntity`).
      attach_site: an `MjsSite` or `MjsBody` of this entity's own spec (a
        PyMJCF `site` or `body` of its own PyMJCF model); the frame takes the
        site's pose. Defaults to `self.attachment_site`.

    Returns:
      The attachment frame: an `MjsBody` named `"<entity name>/"` in this
      entity's spec that holds the child. Add a freejoint to it
      (`frame.add_freejoint()`) to make the child free, or edit its
      `pos`/`quat` to move it. In a PyMJCF model it is a PyMJCF `body`
      (`frame.add('freejoint')`), named `"<entity name>/"` once composed.
    """
    if not isinstance(entity, Entity):
      if pymjcf.is_dm_control_entity(entity):
        raise TypeError(
            f'{type(entity).__name__} is a dm_control composer.Entity: wrap '
            'it to attach it, attach(DmControlEntity(entity)) with '
            '`from mjx_composer.suite.entities.dm_control_entity import '
            'DmControlEntity`.'
        )
      raise TypeError(
          f'Can only attach an Entity, got {type(entity).__name__}.'
      )
    if entity is self or any(e is self for e in entity.iter_entities()):
      raise ValueError('Cannot attach an entity to itself or its descendant.')
    if entity.parent is not None:
      raise ValueError(
          f'Entity {entity.name!r} is already attached to '
          f'{entity.parent.name!r}; detach() it first, or build another '
          'instance to attach it twice.'
      )
    taken = {sibling.name for sibling in self._attached}
    if pymjcf.is_root(entity.mjcf_model) and entity.name in taken:
      # As PyMJCF's attach: a clashing model name gets the first free `_N`.
      base, number = entity.name, 1
      while f'{base}_{number}' in taken:
        number += 1
      entity.mjcf_model.model = f'{base}_{number}'
    for sibling in self._attached:
      if sibling.name == entity.name:
        raise ValueError(
            f'{self.name!r} already has an attached entity named '
            f'{entity.name!r}: compiled names would clash. Give each instance '
            'a distinct name (its mjcf_model.modelname).'
        )
    spec = self.mjcf_model
    site = self.attachment_site if attach_site is None else attach_site
    if pymjcf.is_root(spec) or pymjcf.is_element(site):
      frame = pymjcf.attachment_frame(spec, site, self.name)
    elif isinstance(site, mujoco.MjsSite):
      if not any(s is site for s in spec.sites):
        raise ValueError(
            f'attach_site {site.name!r} is not a site of '
            f"{self.name!r}'s own spec."
        )
      frame = site.parent.add_body(name=entity.name + '/')
      frame.pos = site.pos
      frame.quat = site.quat
      frame.alt = site.alt
    elif isinstance(site, mujoco.MjsBody):
      if not any(b is site for b in spec.bodies):
        raise ValueError(
            f'attach_site {site.name!r} is not a body of '
            f"{self.name!r}'s own spec."
        )
      frame = site.add_body(name=entity.name + '/')
    else:
      raise TypeError(
          'attach_site must be an MjsSite or MjsBody, got '
          f'{type(site).__name__}.'
      )
    entity._parent = weakref.ref(self)  # pylint: disable=protected-access
    entity._attachment_frame = frame  # pylint: disable=protected-access
    self._attached.append(entity)
    return frame

  def detach(self):
    """Detaches this entity from its parent, restoring the parent's spec."""
    parent = self.parent
    if parent is None:
      raise RuntimeError('Cannot detach an entity that is not attached.')
    if pymjcf.is_element(self._attachment_frame):
      self._attachment_frame.remove()
    else:
      parent.mjcf_model.delete(self._attachment_frame)
    parent._attached.remove(self)  # pylint: disable=protected-access
    self._parent = None
    self._attachment_frame = None

  @property
  def attachment_frame(self) -> mujoco.MjsBody | None:
    """The body in the parent's spec that holds this entity, if attached."""
    return self._attachment_frame

  @property
  def root_body(self) -> mujoco.MjsBody:
    """The attachment frame if attached, else this entity's worldbody."""
    if self._attachment_frame is not None:
      return self._attachment_frame
    return self.mjcf_model.worldbody

  # -- composition (host, at compile time) ----------------------------------

  def compose(self) -> tuple[mujoco.MjSpec, dict[int, tuple]]:
    """Merges this entity's tree into a fresh spec.

    An element of an entity's own spec may refer by full name to an element
    of an entity attached below it (`'arm/hand'`): it is added to the
    composed spec after the attached entities, so it compiles after them
    (an actuator declared that way comes after the attached entities'
    actuators). Any other reference that does not resolve is an error
    (`composition_checks`).

    Returns:
      The composed spec (a copy: no entity's own spec is modified), and a map
      `id(handle) -> (handle, kind name, composed handle)` for every element
      of every entity in the tree, where `composed handle` is the element in
      the composed spec (its `.name` is the fully qualified name).
    """
    own = self.mjcf_model
    aliases = {}
    if pymjcf.is_root(own):
      own, aliases = pymjcf.to_spec(
          own,
          {id(c.attachment_frame): c.name + '/' for c in self._attached},
      )
      # Keyed by the spec handle (kept alive in the value, so ids stay unique).
      aliases = {id(h): (e, h) for e, _, h in aliases.values()}
      # The handles live in the converted spec's memory: it must outlive
      # the element index that keeps them (until the next compose).
      self._converted_spec = own
    # copy() and attach() silently drop elements with dangling references;
    # elements that refer to attached entities are added back at the end.
    deferred = composition_checks.cross_entity_elements(self, own)
    spec = own.copy()
    composition_checks.check_copy(self, own, spec, deferred)
    deferred_ids = {id(element) for _, element in deferred}
    handles = {}
    kept = [
        (kind, original)
        for kind, original in element_index.iter_elements(own)
        if id(original) not in deferred_ids
    ]
    for (kind, original), (_, copied) in zip(
        kept, element_index.iter_elements(spec)
    ):
      if kind == 'body' and copied is spec.worldbody:
        pass
      elif not copied.name:
        # Unnamed elements get a stable name so they can be resolved.
        copied.name = f'unnamed_{kind}_{len(handles)}'
      handles[id(original)] = (original, kind, copied)
      alias = aliases.get(id(original))
      if alias is not None:  # The PyMJCF element the handle was made from.
        handles[id(alias[0])] = (alias[0], kind, copied)
    for child in self._attached:
      child_spec, child_handles = child.compose()
      if pymjcf.is_root(child.mjcf_model):
        # PyMJCF merges an attached model into its parent's, under one
        # compiler: the mass and inertia bounds set above (the arena's)
        # apply to the child's bodies too.
        for bound in ('boundmass', 'boundinertia'):
          if not getattr(child_spec.compiler, bound):
            setattr(child_spec.compiler, bound, getattr(spec.compiler, bound))
      frame = handles[id(child.attachment_frame)][2]
      counts = composition_checks.count_elements(spec)
      with warnings.catch_warnings():
        # A spec converted from PyMJCF carries its assets (meshes, textures)
        # in an asset dict; attaching is what compiling needs, once.
        warnings.filterwarnings(
            'ignore', message='Attaching a child without asset dict'
        )
        spec.attach(
            child_spec, prefix=child.name + '/', frame=frame.add_frame()
        )
      composition_checks.check_attach(child, child_spec, counts, spec)
      # The child's own worldbody stands for its attachment frame.
      child_world = child.mjcf_model.worldbody
      child_handles[id(child_world)] = (child_world, 'body', frame)
      handles.update(child_handles)
    for attr, original in deferred:
      copied = composition_checks.readd(spec, attr, original)
      kind = _BINDABLE_LISTS.get(attr)
      if kind is not None:
        if not copied.name:
          copied.name = f'unnamed_{kind}_{len(handles)}'
        handles[id(original)] = (original, kind, copied)
    return spec, handles

  # -- frames and poses (device, pure) --------------------------------------

  def global_vector_to_local_frame(self, physics, vec):
    """Rotates a global vector (last axis 3 or 2) into this entity's frame."""
    vec = jnp.asarray(vec)
    xmat = physics.bind(self.root_body).xmat.reshape(3, 3)
    if vec.shape[-1] == 3:
      return vec @ xmat
    if vec.shape[-1] == 2:
      return vec @ xmat[:2, :2]
    raise ValueError(
        '`vec` should have its last dimension of size 2 or 3, '
        f'got shape {vec.shape}.'
    )

  def global_xmat_to_local_frame(self, physics, xmat):
    """Expresses a global rotation matrix ((3,3) or (9,)) in this frame."""
    xmat = jnp.asarray(xmat)
    if xmat.shape not in ((3, 3), (9,)):
      raise ValueError(
          f'`xmat` must have shape (3, 3) or (9,), got {xmat.shape}.'
      )
    self_xmat = physics.bind(self.root_body).xmat.reshape(3, 3)
    return (self_xmat.T @ xmat.reshape(3, 3)).reshape(xmat.shape)

  @property
  def freejoint(self) -> mujoco.MjsJoint | None:
    """The freejoint of this entity's attachment frame, if it has one."""
    frame = self._attachment_frame
    if frame is None:
      return None
    if pymjcf.is_element(frame):
      return pymjcf.freejoint(frame)
    for joint in frame.joints:
      if joint.type == mujoco.mjtJoint.mjJNT_FREE:
        return joint
    return None

  def _require_frame(self):
    if self._attachment_frame is None:
      raise RuntimeError('No attachment frame found.')
    return self._attachment_frame

  def get_pose(self, physics):
    """Returns `(position (3,), quaternion (4,))`.

    Global coordinates (the freejoint's qpos) for a free entity; otherwise the
    attachment frame's model pose relative to its parent body.
    """
    frame = self._require_frame()
    joint = self.freejoint
    if joint is not None:
      qpos = physics.bind(joint).qpos
      return qpos[:3], qpos[3:]
    binding = physics.bind(frame)
    return binding.pos, binding.quat

  def set_pose(self, physics, position=None, quaternion=None):
    """Returns a Physics with the entity moved (quaternion normalised).

    A free entity gets its freejoint's qpos written. A fixed entity gets its
    attachment frame's *model* `body_pos`/`body_quat` written, which makes
    those model fields per-world. In a step hook, call `physics.forward()`
    before reading derived quantities (`initialize_episode` reads run it).
    """
    frame = self._require_frame()
    joint = self.freejoint
    if joint is not None:
      qpos = physics.bind(joint).qpos
      if position is not None:
        qpos = qpos.at[:3].set(jnp.asarray(position, qpos.dtype))
      if quaternion is not None:
        qpos = qpos.at[3:].set(
            tr.normalize(jnp.asarray(quaternion, qpos.dtype))
        )
      return physics.bind(joint).set(qpos=qpos)
    values = {}
    if position is not None:
      values['pos'] = position
    if quaternion is not None:
      values['quat'] = tr.normalize(jnp.asarray(quaternion, jnp.float32))
    return physics.bind(frame).set(**values) if values else physics

  def shift_pose(
      self, physics, position=None, quaternion=None, rotate_velocity=False
  ):
    """Translates by `position` and pre-multiplies the orientation.

    New position = current + `position`; new quaternion = `quaternion ⊗
    current`. With `rotate_velocity`, a free entity's linear velocity is
    rotated by `quaternion` too (angular velocity is local and unchanged).
    """
    current_pos, current_quat = self.get_pose(physics)
    new_pos = None if position is None else current_pos + jnp.asarray(position)
    new_quat = None
    if quaternion is not None:
      quaternion = jnp.asarray(quaternion, current_quat.dtype)
      new_quat = tr.quat_mul(quaternion, current_quat)
      if rotate_velocity and self.freejoint is not None:
        linear, _ = self.get_velocity(physics)
        physics = self.set_velocity(
            physics, velocity=tr.rotate_vec(tr.normalize(quaternion), linear)
        )
    return self.set_pose(physics, new_pos, new_quat)

  def get_velocity(self, physics):
    """Returns `(linear (3,), angular (3,))` of a free entity's freejoint."""
    joint = self.freejoint
    if joint is None:
      raise ValueError(
          'get_velocity needs a free entity (a freejoint on its '
          'attachment frame).'
      )
    qvel = physics.bind(joint).qvel
    return qvel[:3], qvel[3:]

  def set_velocity(self, physics, velocity=None, angular_velocity=None):
    """Writes a free entity's freejoint qvel; a no-op (with a warning) else."""
    joint = self.freejoint
    if joint is None:
      import logging  # pylint: disable=g-import-not-at-top

      logging.warning(
          'set_velocity on a non-free entity %r does nothing.', self.name
      )
      return physics
    qvel = physics.bind(joint).qvel
    if velocity is not None:
      qvel = qvel.at[:3].set(jnp.asarray(velocity, qvel.dtype))
    if angular_velocity is not None:
      qvel = qvel.at[3:].set(jnp.asarray(angular_velocity, qvel.dtype))
    return physics.bind(joint).set(qvel=qvel)

  def configure_joints(self, physics, position):
    """Writes qpos of this entity's own joints (not its children's)."""
    model = self.mjcf_model
    if pymjcf.is_root(model):
      joints = pymjcf.own_joints(model)
    else:
      joints = list(model.joints)
    return physics.bind(joints).set(qpos=position)


class ModelWrapperEntity(Entity):
  """An entity around an existing model: an MjSpec, an XML file or string.

  Args:
    mjcf_model: a `mujoco.MjSpec`, a path to an MJCF file (meshes and other
      files are resolved relative to it), or an MJCF XML string.
    assets: optional `{filename: bytes}` for an XML string's assets.
    name: optional entity name (overrides the model's name).
  """

  def _build(self, mjcf_model, assets=None, name=None):
    if isinstance(mjcf_model, mujoco.MjSpec):
      spec = mjcf_model
    elif isinstance(mjcf_model, str) and mjcf_model.lstrip().startswith('<'):
      spec = mujoco.MjSpec.from_string(mjcf_model, assets=assets or {})
    elif isinstance(mjcf_model, str) or hasattr(mjcf_model, '__fspath__'):
      spec = mujoco.MjSpec.from_file(str(mjcf_model), assets=assets or {})
    else:
      raise TypeError(
          'mjcf_model must be an MjSpec, an MJCF path or an XML '
          f'string, got {type(mjcf_model).__name__}.'
      )
    if name is not None:
      spec.modelname = name
    self._spec = spec

  @property
  def mjcf_model(self):
    return self._spec
