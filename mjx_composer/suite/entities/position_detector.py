"""`PositionDetector`: which registered entities are inside a box region.

dm_control's `entities.props.PositionDetector`, with its state per world.
An entity is detected when the world position (`xpos`) of any one of its
geoms lies strictly inside the axis-aligned region `(lower, upper)` (or
outside it, when `inverted`). With 2-number `pos` and `size` the region is
2D: infinitely tall along z. This is not contact-based: a geom is detected
once its centre is in, i.e. when it is about half inside.

    detector = PositionDetector(pos=(0.4, 0.4), size=(0.1, 0.1), visible=True)
    arena.attach(detector)
    detector.register_entities(box_0, box_1)
    ...
    inside = detector.detected_entities(physics)   # bool (2,), in order

Differences from composer:

* `detected_entities(physics)` returns a bool array over the registered
  entities (in registration order), not a list of entities, and
  `activated(physics)` is a function of the physics.
* Without `retain_substep_detections` detection is computed from the current
  geom positions whenever it is read, which is what composer's state holds
  after the last sub-step. With it, the per-step "seen at any sub-step" flags
  are the detector's per-episode entity state (`initial_state`: cleared in
  `before_step`, OR-ed in `after_substep`, set at `initialize_episode`).
* The zone site does not change colour on detection: that would be a
  per-step model write for rendering only. Detection (`detected` observable)
  is what policies and rewards use.
* The region's bounds are the model positions of the `lower` and `upper`
  sites, so `set_position` in `initialize_episode` moves the region per world.
  As in composer they are world coordinates: attach the detector at the
  arena's origin (the default).
"""

import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_composer import constants
from mjx_composer import define
from mjx_composer import entity
from mjx_composer.observation import observable

_RENDERED_HEIGHT_IN_2D_MODE = 0.01


def _ensure_3d(pos):
  pos = np.asarray(pos, float)
  return np.concatenate([pos, [0.0]]) if pos.size == 2 else pos


class PositionDetectorObservables(observable.Observables):
  """The region's corners and centre (sensors) and the detection flags."""

  @define.observable
  def lower(self):
    return observable.MJCFFeature('sensordata', self._entity.lower_sensor)

  @define.observable
  def mid(self):
    return observable.MJCFFeature('sensordata', self._entity.mid_sensor)

  @define.observable
  def upper(self):
    return observable.MJCFFeature('sensordata', self._entity.upper_sensor)

  @define.observable
  def detected(self):
    """1. for each registered entity that is detected, else 0. (float32)."""
    return observable.Generic(
        lambda physics: self._entity.detected_entities(physics).astype(
            jnp.float32
        )
    )


class PositionDetector(entity.Entity):
  """Detects registered entities within (or outside) an axis-aligned box.

  Args:
    pos: centre of the region, 3 numbers (3D) or 2 (2D mode).
    size: half-lengths of the region, as many numbers as `pos`.
    inverted: detect entities that are *not* in the region.
    visible: if False, the sites go to `SENSOR_SITES_GROUP` (not rendered by
      default).
    rgba: the zone site's colour.
    material: optional material name for the zone site.
    detected_rgba: kept for composer compatibility (see module docstring).
    retain_substep_detections: report an entity detected at the end of a
      control step if it was detected at any of its sub-steps.
    name: the entity name.

  Raises:
    ValueError: if `pos` and `size` differ in length or are not 2 or 3 long.
  """

  def _build(
      self,
      pos,
      size,
      inverted=False,
      visible=False,
      rgba=(1, 1, 1, 1),
      material=None,
      detected_rgba=(0, 1, 0, 0.25),
      retain_substep_detections=False,
      name='position_detector',
  ):
    pos, size = np.asarray(pos, float), np.asarray(size, float)
    if pos.shape != size.shape or pos.size not in (2, 3):
      raise ValueError(
          '`pos` and `size` should have the same length (2 or '
          f'3): got {pos.tolist()!r} and {size.tolist()!r}'
      )
    self._dims = pos.size
    self._inverted = bool(inverted)
    self._retain_substep_detections = bool(retain_substep_detections)
    self._rgba = np.asarray(rgba, float)
    self._detected_rgba = np.asarray(detected_rgba, float)
    self._entities = []
    spec = mujoco.MjSpec()
    spec.modelname = name
    self._spec = spec
    self._site = spec.worldbody.add_site(
        name='detection_zone', type=mujoco.mjtGeom.mjGEOM_BOX, rgba=self._rgba
    )
    if material is not None:
      self._site.material = material
    self._lower_site = spec.worldbody.add_site(
        name='lower', size=[0.05, 0, 0], rgba=self._rgba
    )
    self._mid_site = spec.worldbody.add_site(
        name='mid', size=[0.05, 0, 0], rgba=self._rgba
    )
    self._upper_site = spec.worldbody.add_site(
        name='upper', size=[0.05, 0, 0], rgba=self._rgba
    )
    site_obj = mujoco.mjtObj.mjOBJ_SITE
    self._lower_sensor, self._mid_sensor, self._upper_sensor = (
        spec.add_sensor(
            name=f'{name}_{which}',
            type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
            objtype=site_obj,
            objname=which,
        )
        for which in ('lower', 'mid', 'upper')
    )
    if not visible:
      for site in (
          self._site,
          self._lower_site,
          self._mid_site,
          self._upper_site,
      ):
        site.group = constants.SENSOR_SITES_GROUP
    self._set_spec_region(pos, size)

  def _build_observables(self):
    return PositionDetectorObservables(self)

  def _set_spec_region(self, pos, size):
    self._lower = pos - size
    self._upper = pos + size
    render_pos = np.zeros(3)
    render_pos[: pos.size] = pos
    render_size = np.full(3, _RENDERED_HEIGHT_IN_2D_MODE)
    render_size[: size.size] = size
    self._site.pos = render_pos
    self._site.size = render_size
    self._lower_site.pos = _ensure_3d(self._lower)
    self._mid_site.pos = (_ensure_3d(self._lower) + _ensure_3d(self._upper)) / 2
    self._upper_site.pos = _ensure_3d(self._upper)

  def resize(self, pos, size):
    """Changes the region before the environment is built (host)."""
    pos, size = np.asarray(pos, float), np.asarray(size, float)
    if pos.shape != size.shape or pos.size != self._dims:
      raise ValueError(
          '`pos` and `size` should have the same length as the '
          f"detector's ({self._dims}): got {pos.tolist()!r} and "
          f'{size.tolist()!r}'
      )
    self._set_spec_region(pos, size)

  def set_position(self, physics, pos):
    """Moves the region's centre in one world; returns the Physics.

    Writes the sites' model positions (per-world when done in
    `initialize_episode`); the region keeps its size.
    """
    pos = jnp.asarray(pos, jnp.float32)
    if pos.shape != (self._dims,):
      raise ValueError(f'pos must have shape ({self._dims},), got {pos.shape}.')
    half = (
        jnp.asarray(self._upper, jnp.float32)
        - jnp.asarray(self._lower, jnp.float32)
    ) / 2
    zone = physics.bind(self._site).pos
    physics = physics.bind(self._site).set(pos=zone.at[: self._dims].set(pos))
    lower, upper = pos - half, pos + half
    pad = (
        lambda x: jnp.concatenate([x, jnp.zeros(1, x.dtype)])
        if self._dims == 2
        else x
    )
    physics = physics.bind(self._lower_site).set(pos=pad(lower))
    physics = physics.bind(self._mid_site).set(pos=pad(pos))
    return physics.bind(self._upper_site).set(pos=pad(upper))

  @property
  def mjcf_model(self):
    return self._spec

  # -- registration (host) --------------------------------------------------

  def register_entities(self, *entities):
    """Adds entities whose presence is detected (before the env is built)."""
    self._entities.extend(entities)

  def deregister_entities(self):
    self._entities = []

  @property
  def registered_entities(self):
    return tuple(self._entities)

  # -- detection (device) ---------------------------------------------------

  def _region(self, physics):
    lower = physics.bind(self._lower_site).pos[: self._dims]
    upper = physics.bind(self._upper_site).pos[: self._dims]
    return lower, upper

  def _instantaneous(self, physics):
    """Detection from the current geom positions, one flag per entity."""
    if not self._entities:
      return jnp.zeros((0,), bool)
    lower, upper = self._region(physics)
    flags = []
    for registered in self._entities:
      geoms = [
          g for e in registered.iter_entities() for g in e.mjcf_model.geoms
      ]
      if not geoms:
        flags.append(jnp.zeros((), bool))
        continue
      xpos = physics.bind(geoms).xpos[:, : self._dims]
      inside = jnp.all((lower < xpos) & (xpos < upper), axis=-1)
      flags.append(jnp.any(inside != self._inverted))
    return jnp.stack(flags)

  def initial_state(self):
    """The per-step "seen at any sub-step" flags, when they are retained."""
    if not self._retain_substep_detections:
      return None
    return {'detected': np.zeros((len(self._entities),), bool)}

  def _retained(self, physics):
    states = physics.entity_states
    if states is None or self.full_identifier not in states:
      return None
    return physics.entity_state(self)['detected']

  def detected_entities(self, physics):
    """A bool array: is each registered entity detected (in order)."""
    if self._retain_substep_detections:
      retained = self._retained(physics)
      if retained is not None:
        return retained
    return self._instantaneous(physics)

  def activated(self, physics):
    """True when any registered entity is detected."""
    return jnp.any(self.detected_entities(physics))

  def initialize_episode(self, physics, key):
    del key
    if not self._retain_substep_detections:
      return physics
    # The task's hook (which runs first) and initializers may have moved
    # bodies with no forward pass since: the positions read here are then
    # computed for the read (`Physics.forward_stale_reads`), so detection
    # sees the new ones.
    return physics.update_entity_state(
        self, detected=self._instantaneous(physics)
    )

  def before_step(self, physics, key):
    del key
    if not self._retain_substep_detections:
      return physics
    return physics.update_entity_state(
        self, detected=jnp.zeros((len(self._entities),), bool)
    )

  def after_substep(self, physics, key):
    del key
    if not self._retain_substep_detections:
      return physics
    detected = jnp.logical_or(
        self._retained(physics), self._instantaneous(physics)
    )
    return physics.update_entity_state(self, detected=detected)

  # -- composer's static accessors ------------------------------------------

  @property
  def inverted(self):
    return self._inverted

  @property
  def lower(self):
    """The region's lower corner as built (world coordinates)."""
    return self._lower

  @property
  def upper(self):
    return self._upper

  @property
  def mid(self):
    return (self._lower + self._upper) / 2.0

  def site_pos(self, physics):
    """The zone site's model position in one world."""
    return physics.bind(self._site).pos

  @property
  def zone_site(self):
    return self._site

  @property
  def lower_site(self):
    return self._lower_site

  @property
  def mid_site(self):
    return self._mid_site

  @property
  def upper_site(self):
    return self._upper_site

  @property
  def lower_sensor(self):
    return self._lower_sensor

  @property
  def mid_sensor(self):
    return self._mid_sensor

  @property
  def upper_sensor(self):
    return self._upper_sensor
