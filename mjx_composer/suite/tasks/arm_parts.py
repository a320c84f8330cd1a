"""What the arm tasks (`reach`, `push`) share: argument checks, the solver's
iteration caps and the sensor noise of their observations."""

import jax
import jax.numpy as jnp

from mjx_composer.utils import validation


def gaussian_noise(scale):
  """A corruptor adding N(0, scale²) noise to every sample."""

  def corrupt(value, key):
    return value + scale * jax.random.normal(
        key, jnp.shape(value), jnp.result_type(value)
    )

  return corrupt


def check_arm_task_arguments(
    owner,
    control_timestep,
    physics_timestep,
    observation_noise,
    solver_iterations,
    solver_ls_iterations,
):
  """The arguments the arm tasks share, checked before anything is built.

  Raises:
    TypeError, ValueError: naming the argument, its value and the fix.
  """
  validation.check_positive('control_timestep', control_timestep, owner=owner)
  validation.check_positive('physics_timestep', physics_timestep, owner=owner)
  validation.check_nonnegative(
      'observation_noise',
      observation_noise,
      owner=owner,
      fix='Pass a standard deviation >= 0 (0: no noise).',
  )
  for name, value in (
      ('solver_iterations', solver_iterations),
      ('solver_ls_iterations', solver_ls_iterations),
  ):
    if value is not None:
      validation.check_integer(
          name,
          value,
          owner=owner,
          minimum=1,
          fix="Pass an int >= 1, or None to keep MuJoCo's default.",
      )


def cap_solver(arena, iterations, ls_iterations):
  """Writes the solver's iteration caps on `arena`'s spec (None: keep)."""
  option = arena.mjcf_model.option
  if iterations is not None:
    option.iterations = iterations
  if ls_iterations is not None:
    option.ls_iterations = ls_iterations
