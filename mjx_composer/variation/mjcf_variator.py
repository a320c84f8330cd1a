"""`MJCFVariator`: variations bound to MJCF (MjSpec) attributes, per world.

    class RandomizedTask(composer.Task):

      def __init__(self, robot, arena):
        ...
        self._mjcf_variator = variation.MJCFVariator()
        for geom in robot.mjcf_model.geoms:
          self._mjcf_variator.bind_attributes(
              geom, rgba=colors.RgbVariation(...),
              size=noises.Multiplicative(distributions.Uniform(0.9, 1.1)))

      def initialize_episode(self, physics, key):
        return self._mjcf_variator.apply_variations(physics, key)

composer's MJCFVariator edits the MJCF and recompiles every episode. We
compile once, so the variator maps each supported attribute onto the
compiled model fields it sets and re-derives on the device everything that
MuJoCo's compiler computes from it (inertia from geom sizes and densities,
`body_subtreemass`, `geom_rbound`, `mj_setConst`'s `*_invweight0`, ...; see
`mjx_composer.compiler`). A world varied this way equals, to float32 precision, the
model you get by setting the same values on the MjSpec and recompiling.

Elements are the handles of your entities' own specs (geoms, bodies, sites,
joints, actuators) and the root entity's `mjcf_model.option`. Values are in
spec units (e.g. degrees for the joint ranges of a spec whose compiler uses
degrees). Position actuators also take `kp` (gainprm[0], with
biasprm[1] = -kp) and `kv` (biasprm[2] = -kv). Attributes that cannot be
made equal are refused with a message (`compiler.attributes.CATALOGUE` lists
the supported ones).

Where to call it: composer's `apply_variations(random_state)` in an
`initialize_episode_mjcf` hook works as in composer. That hook runs once, on
the host, when the environment is built; the call records this variator,
and every reset applies it on the device, per world, before the
`initialize_episode` hooks (where composer's recompiled model is in place),
with a key of its own (`collecting_episode_calls`). Or call
`apply_variations(physics, key)` in `initialize_episode` yourself, where
other hooks' writes decide the order.

Differences from composer:

* initial values are the attribute values of the compiled spec, read when
  reset is traced (composer reads them when binding);
* the world's current values (what cumulative variations build on) are
  carried in its persistent state, so they survive auto-resets, where a
  draw reads them: a schedule other than every episode, a cumulative noise
  or a callable that reads its `current_value` (`variator_base.
  draws_read_current`); the varied model fields hold what was drawn;
* other hooks' writes to the fields this variator derives (e.g. a
  PhysicsVariator on `body_mass` before it) are overwritten: apply the
  MJCFVariator first;
* the model's `qpos0` follows varied free-body poses, but `Environment`
  starts every episode from the compiled `qpos0`: set the free joint's qpos
  yourself if you want the varied pose as the initial state.

See `variator_base` for schedules (`Schedule`) and state, and for invalid
draws (values outside their catalogue record's `bound`, or not finite, e.g.
a negative mass or size): at reset they fail the episode's initialization
(the environment resamples it, as recompiling would refuse the MJCF), in
step they are dropped.
"""

from __future__ import annotations

import contextlib
import contextvars

import jax.numpy as jnp
import numpy as np

from mjx_composer import compiler
from mjx_composer.compiler import attributes
from mjx_composer.model import pymjcf
from mjx_composer.physics import bindings
from mjx_composer.variation import variator_base


class _Plan:
  """Trace-time resolution of an MJCFVariator's bindings."""

  def __init__(self, variator, physics):
    bindings = variator.bindings
    self._compiler = compiler.ModelCompiler(
        physics.index,
        [
            (physics.index.spec_handle(b.element), b.attr, b.describe())
            for b in bindings
        ],
        owner=variator.label,
    )
    self.initial_values = self._compiler.initial_values
    self.bounds = [
        attributes.bound_for(attributes.bound_of(b.element, b.attr), initial)
        for b, initial in zip(bindings, self.initial_values)
    ]
    # The world's current values are kept (in its persistent entry) where a
    # later draw reads them: a schedule that keeps values between draws, or
    # a variation that builds on them. Elsewhere they would be state that
    # nothing reads, each leaf one more output of the reset and the step.
    self.keeps_values = variator.schedule.mode != 'episode' or (
        variator_base.draws_read_current(bindings, self.initial_values)
    )

  def read_current(self, physics, entry):
    del physics
    if entry is None or 'values' not in entry:
      return [jnp.asarray(v) for v in self.initial_values]
    return list(entry['values'])

  def write(self, physics, values):
    fields = self._compiler(physics.model, values)
    # What the write makes stale, as a binding's model write records it.
    stale = [f for f in fields if bindings.marks_stale('model', f)]
    written = physics.replace(model=physics.model.replace(**fields))
    written = written.mark_written(*physics.unsynced_writes, *stale)
    return written, ({'values': tuple(values)} if self.keeps_values else {})


# The variators that composer's `apply_variations(random_state)` named,
# while `collecting_episode_calls` collects them (None elsewhere).
_EPISODE_CALLS = contextvars.ContextVar('mjcf_episode_calls', default=None)


@contextlib.contextmanager
def collecting_episode_calls():
  """Collects the variators whose `apply_variations(random_state)` (composer's
  call) runs inside: what an `initialize_episode_mjcf` hook asks for.

  Yields the list they are appended to, in call order; the environment
  applies each per episode (`apply_variations(physics, key)`).
  """
  calls = []
  token = _EPISODE_CALLS.set(calls)
  try:
    yield calls
  finally:
    _EPISODE_CALLS.reset(token)


class MJCFVariator(variator_base.Variator):
  """Binds variations to MJCF attributes; recompile-equivalent per world.

  Args:
    schedule: when to draw (`variation.Schedule`); every episode by default.
    name: the name of this variator's persistent entry (derived from its
      bindings by default).
  """

  def apply_variations(self, physics, key=None, *, in_step: bool = False):
    """Samples the bound attributes for this world (see `Variator`'s).

    `apply_variations(random_state)`, composer's call from an
    `initialize_episode_mjcf` hook, records this variator instead, to be
    applied per episode by the environment (module docstring), and returns
    None as composer's does.

    Raises:
      TypeError: `apply_variations(random_state)` outside an
        `initialize_episode_mjcf` hook run by an `Environment`.
    """
    if not isinstance(physics, np.random.RandomState):
      return super().apply_variations(physics, key, in_step=in_step)
    calls = _EPISODE_CALLS.get()
    if calls is None or key is not None or in_step:
      raise TypeError(
          f"{self.label}: apply_variations(random_state), composer's call, "
          'works in an initialize_episode_mjcf hook, which the Environment '
          'runs when it is built: it then applies this variator at every '
          'reset, per world. Elsewhere call apply_variations(physics, key) '
          'from initialize_episode.'
      )
    calls.append(self)
    return None

  def _check_binding(self, element, attr, variation):
    spec = None  # Keeps a converted PyMJCF model alive for its handle.
    if pymjcf.is_element(element):
      # The checks read MjSpec attributes: those of the element converted.
      spec, element = pymjcf.spec_handle_of(element)
    kind = compiler.check_attribute(element, attr)
    initial = compiler.spec_value(element, kind, attr)
    variator_base.check_static_shape(
        variation,
        initial,
        variator_base.describe_element(element) + '.' + attr,
        self.label,
    )
    del spec

  def _bound(self, element, attr):
    return attributes.bound_of(element, attr)

  def _prepare(self, physics):
    return _Plan(self, physics)
