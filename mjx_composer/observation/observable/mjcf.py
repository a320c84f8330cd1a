"""Observables bound to MjSpec elements."""

import copy

import mujoco
import numpy as np

from mjx_composer.model import pymjcf
from mjx_composer.observation.observable import base

# MjSpec handle types that can be bound. Spec-level helper types (compiler
# options, orientations, defaults) are not elements one can observe.
_NOT_ELEMENTS = ('MjsCompiler', 'MjsOrientation', 'MjsDefault', 'MjsElement')
_ELEMENT_TYPES = tuple(
    getattr(mujoco, name)
    for name in dir(mujoco)
    if name.startswith('Mjs') and name not in _NOT_ELEMENTS
)


def _is_element(obj) -> bool:
  return isinstance(obj, _ELEMENT_TYPES) or pymjcf.is_element(obj)


class MJCFFeature(base.Observable):
  """An attribute of one MjSpec element, or of a list of them, read via bind.

  `MJCFFeature('xpos', site)` reads `physics.bind(site).xpos` (shape (3,));
  with a list of elements the values are stacked. `kind` is any attribute a
  binding has: data fields (`qpos`, `xpos`, `xmat`, `sensordata`,
  `subtree_linvel`, ...) or model fields (`pos`, `size`, ...), in
  dm_control's shapes (`xmat` is a flat `(9,)`, so `feature[6:]` is the
  world z axis in the element's frame). Indexing, `feature[1:3]`, returns a
  copy that reads `binding.<kind>[1:3]`. An empty list of elements, as
  composer allows, gives an empty `(0,)` observable.

  Binding resolves the elements to static indices when the read is traced,
  so a sample costs one gather (composer re-binds once per episode instead).
  """

  def __init__(
      self,
      kind,
      mjcf_element,
      update_interval=1,
      buffer_size=None,
      delay=None,
      aggregator=None,
      corruptor=None,
      index=None,
  ):
    is_element = _is_element(mjcf_element)
    if not is_element:
      try:
        elements = list(mjcf_element)
      except TypeError:
        elements = None
      if (
          elements is None
          or isinstance(mjcf_element, str)
          or not all(_is_element(e) for e in elements)
      ):
        raise ValueError(
            'expected an `mjcf.Element` (an MjSpec element handle such as '
            '`mujoco.MjsSite`) or an iterable of them: got '
            f'{type(mjcf_element).__name__} {mjcf_element!r}.'
        )
      mjcf_element = elements
    self._kind = kind
    self._mjcf_element = mjcf_element
    self._index = index
    super().__init__(update_interval, buffer_size, delay, aggregator, corruptor)

  @property
  def kind(self):
    return self._kind

  @property
  def mjcf_element(self):
    return self._mjcf_element

  @property
  def index(self):
    return self._index

  def _callable(self, physics):
    binding = physics.bind(self._mjcf_element)
    kind, index = self._kind, self._index
    if isinstance(index, list):
      # JAX refuses a Python list as an index; an integer array means the same.
      index = np.asarray(index)
    if index is None:
      return lambda: getattr(binding, kind)
    return lambda: getattr(binding, kind)[index]

  def __getitem__(self, key):
    if self._index is not None:
      raise NotImplementedError(
          'slicing an already indexed observable is not yet supported'
      )
    indexed = copy.copy(self)
    indexed._index = key  # pylint: disable=protected-access
    return indexed
