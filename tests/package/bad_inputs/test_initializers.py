"""Initializers refuse poses of the wrong size before anything is placed."""

import jax
import pytest

import mjx_composer as composer
from mjx_composer import initializers
from mjx_composer.suite.entities import props
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions


def _sphere():
  return props.Sphere(radius=0.05, name='ball')


@pytest.mark.parametrize(
    'argument, value, match',
    [
        ('position', (0, 0), r'`position` must be 3 numbers.*\(2,\)'),
        ('position', [[0, 0, 1], [0, 0, 2]], r'`position`.*\(2, 3\)'),
        ('quaternion', (1, 0, 0), r'`quaternion` must be 4 numbers.*\(3,\)'),
    ],
)
def test_prop_placer_refuses_a_fixed_pose_of_another_size(
    argument, value, match
):
  """A 2-vector position failed inside JAX's broadcasting at reset."""
  with pytest.raises(ValueError, match=match + r'.*Pass'):
    initializers.PropPlacer(
        [_sphere()], **{'position': (0, 0, 1), argument: value}
    )


def test_prop_placer_keeps_poses_that_broadcast():
  placer = initializers.PropPlacer([_sphere()], position=0.5)
  assert placer.props[0].name == 'ball'


class _Placing(composer.NullTask):
  """Places a free ball from a position variation at every reset."""

  def __init__(self, position):
    arena = composer.Arena()
    self._ball = _sphere()
    arena.add_free_entity(self._ball)
    super().__init__(arena)
    self._placer = initializers.PropPlacer(
        [self._ball], position=position, ignore_collisions=True
    )

  def initialize_episode(self, physics, key):
    return self._placer(physics, key)


@pytest.mark.parametrize(
    'position, match',
    [
        (
            deterministic.Sequence([(0, 0), (1, 1)]),
            r'`position` must be 3 numbers.*Sequence.*which drew a value of '
            r'shape \(2,\)\. Pass 3 numbers',
        ),
        (
            distributions.Uniform((0, 0), (1, 1)),
            r'`position` Uniform.* could not be drawn for a position of shape '
            r'\(3,\): Uniform: .*shape \(2,\) does not broadcast',
        ),
    ],
)
def test_prop_placer_names_a_variation_that_draws_another_size(position, match):
  """Refused while the reset is traced, before any world runs."""
  env = composer.Environment(_Placing(position))
  with pytest.raises(ValueError, match=match):
    jax.eval_shape(env.reset, jax.random.key(0))


def test_prop_placer_draws_a_variation_of_three():
  env = composer.Environment(
      _Placing(distributions.Uniform((0, 0, 1), (1, 1, 2)))
  )
  state = jax.jit(env.reset)(jax.random.key(0))
  z = env.physics(state).bind(env.task._ball.freejoint).qpos[2]
  assert 1.0 <= float(z) < 2.0
