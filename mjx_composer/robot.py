"""`Robot`: an entity with actuators that an agent controls."""

import abc

import numpy as np

from mjx_composer import entity

# The orientation that points a tool's z-axis at the floor (composer's).
DOWN_QUATERNION = np.array([0.0, 0.70710678118, 0.70710678118, 0.0])


class Robot(entity.Entity, metaclass=abc.ABCMeta):
  """An entity whose actuators an agent drives."""

  @property
  @abc.abstractmethod
  def actuators(self):
    """The robot's `MjsActuator` handles, in action order."""
