"""`SpecRobot`: the bundled robots' common ground, an MjSpec and its handles.

Each bundled robot builds one `mujoco.MjSpec` in `_build` (in code, or from
a vendored XML) and keeps the handles of its joints and actuators.
`SpecRobot` answers `mjcf_model`, `joints` and `actuators` from
`self._spec`, `self._joints` and `self._actuators`, which `_build` sets;
`free_at_origin` is the change a vendored robot's XML needs to be composed.
"""

import mujoco

from mjx_composer import robot


class SpecRobot(robot.Robot):
  """A `Robot` whose `_build` sets `_spec`, `_joints` and `_actuators`."""

  @property
  def mjcf_model(self):
    return self._spec

  @property
  def joints(self):
    """The robot's joints (`MjsJoint`), in the model's (qpos) order."""
    return self._joints

  @property
  def actuators(self):
    """The robot's actuators (`MjsActuator`), in action order."""
    return self._actuators


def free_at_origin(spec, body):
  """Removes `body`'s free joint and moves it to the entity's origin.

  An XML's floating base carries its own free joint at a height above its
  floor; composed, the arena gives the robot its free joint
  (`arena.add_free_entity(robot)`), so the body sits at the attachment
  frame, which goes where the XML had the body.

  Returns:
    The body's height in the XML, metres: where to put the free frame.
  """
  for joint in list(body.joints):
    if joint.type == mujoco.mjtJoint.mjJNT_FREE:
      spec.delete(joint)
  height = float(body.pos[2])
  body.pos = [0.0, 0.0, 0.0]
  return height
