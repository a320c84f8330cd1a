"""`Arena`: the root entity of a scene, with composer's global defaults."""

import mujoco

from mjx_composer import entity
from mjx_composer.model import layouts
from mjx_composer.model import pymjcf


class Arena(entity.Entity):
  """The root of a scene, carrying composer's `arena.xml` defaults.

  The defaults are those of composer's arena where MJX honours them:
  `compiler boundmass=1e-5 boundinertia=1e-11` (so empty attachment frames
  with freejoints compile), radian angles, `option timestep=0.002` and
  elliptic friction cones, and the same headlight and visual scale. Composer's
  `noslip_iterations=5` is left out: MJX has no noslip solver, and asking for
  it would make MuJoCo on the host (our reference) disagree with MJX.

  An arena written against PyMJCF, as dm_control's arenas are, reads and
  edits `self._mjcf_root` after `super()._build(name=name)`: on first use it
  becomes the arena's model, an `mjcf.RootElement` with the same defaults
  (or `xml_path` loaded with `mjcf.from_path`), in place of the MjSpec. A
  subclass may also assign its own `mjcf.RootElement` to `self._mjcf_root`.

  Args:
    name: the arena's name (its spec's `modelname`).
    xml_path: optional MJCF file to start from instead of an empty scene.
  """

  _pymjcf_root = None
  _episode_layouts = None

  def _build(self, name=None, xml_path=None):
    self._build_args = (name, xml_path)
    if xml_path is not None:
      spec = mujoco.MjSpec.from_file(str(xml_path))
    else:
      spec = mujoco.MjSpec()
      spec.compiler.degree = False
      spec.option.timestep = 0.002
      spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.compiler.boundmass = 1e-5
    spec.compiler.boundinertia = 1e-11
    spec.visual.map.znear = 0.01
    spec.visual.headlight.diffuse = [0.6, 0.6, 0.6]
    spec.visual.headlight.ambient = [0.3, 0.3, 0.3]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    spec.modelname = name or spec.modelname or 'arena'
    if spec.modelname == 'MuJoCo Model':
      spec.modelname = 'arena'
    self._spec = spec

  @property
  def mjcf_model(self):
    if self._pymjcf_root is not None:
      return self._pymjcf_root
    return self._spec

  @property
  def _mjcf_root(self):
    """The arena's PyMJCF model (dm_control's attribute); see the class."""
    if self._pymjcf_root is None:
      spec = self._spec
      if len(spec.bodies) > 1 or spec.geoms or spec.sites or spec.lights:
        raise RuntimeError(
            f'Arena {self.name!r} already has MjSpec elements: an arena is '
            'built either on its MjSpec (self.mjcf_model) or on PyMJCF '
            '(self._mjcf_root), not both.'
        )
      self._pymjcf_root = _pymjcf_arena(*self._build_args)
      self._spec = None
    return self._pymjcf_root

  @_mjcf_root.setter
  def _mjcf_root(self, root):
    if root is not None and not pymjcf.is_root(root):
      raise TypeError(
          f'_mjcf_root must be a dm_control mjcf.RootElement, got '
          f'{type(root).__name__}.'
      )
    self._pymjcf_root = root

  def add_free_entity(self, entity_to_add):
    """Attaches an entity with a freejoint on its frame; returns the frame."""
    frame = self.attach(entity_to_add)
    if pymjcf.is_element(frame):
      frame.add('freejoint')
    else:
      frame.add_freejoint()
    return frame

  @property
  def ground_geoms(self):
    """Geoms that form the ground (none for a bare arena)."""
    return ()

  def regenerate(self, random_state):
    """Regenerates the arena's layout at build time (no-op by default).

    Composer's hook: it edits the spec on the host, before the one compile.
    Call it from the task's `initialize_episode_mjcf`, as composer's tasks
    do; `regenerate_per_episode` draws a new layout at every episode.
    """
    del random_state

  def regenerate_per_episode(self, layouts_count: int):
    """Gives each episode one of `layouts_count` regenerated layouts.

    When the environment is built (`after_compile`), `regenerate` runs
    `layouts_count` times on the host and the whole tree is compiled after
    each; every episode (`initialize_episode`) then writes a uniformly drawn
    layout's model fields into its world's model: the values MuJoCo's
    compiler gave that layout. Only regenerations that keep the structure
    (move, resize or recolour existing elements, as a corridor's `regenerate`
    does) can be carried; others raise at build, naming the field.
    """
    self._episode_layouts = layouts.EpisodeLayouts(layouts_count)

  def after_compile(self, physics, random_state):
    if self._episode_layouts is not None:
      root = self
      while root.parent is not None:
        root = root.parent
      self._episode_layouts.sample(root, self.regenerate, random_state)

  def initialize_episode(self, physics, key):
    if self._episode_layouts is not None:
      physics = self._episode_layouts.apply(physics, key)
    return physics

  def regenerate_world(self, physics, key):
    """Samples one world's layout on the device (identity by default).

    The per-world counterpart of `regenerate`: write the model fields a
    regenerated spec would have compiled to, and return the physics. Call it
    from `initialize_episode`.
    """
    del key
    return physics


def _pymjcf_arena(name, xml_path):
  """A PyMJCF arena model with `Arena`'s defaults, or `xml_path` loaded."""
  from dm_control import mjcf  # pylint: disable=g-import-not-at-top

  if xml_path is not None:
    root = mjcf.from_path(str(xml_path))
  else:
    root = mjcf.RootElement()
    root.compiler.angle = 'radian'
    root.option.timestep = 0.002
    root.option.cone = 'elliptic'
  root.compiler.boundmass = 1e-5
  root.compiler.boundinertia = 1e-11
  root.visual.map.znear = 0.01
  root.visual.headlight.diffuse = [0.6, 0.6, 0.6]
  root.visual.headlight.ambient = [0.3, 0.3, 0.3]
  root.visual.headlight.specular = [0.0, 0.0, 0.0]
  root.model = name or root.model or 'arena'
  return root
