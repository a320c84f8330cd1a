"""Shared fixtures: small composed scenes compiled once per test session."""

import collections
import gc
import json
import os
import shutil
import subprocess
import sys
import tempfile

# Compile with LLVM's optimizations off (XLA's HLO passes, which decide
# fusion and the order of reductions, still run). Most tests run a few
# control steps of a few worlds and spend most of their time compiling;
# this cuts a compile by about a quarter on a CPU. Tests that run long
# (training) are marked `optimized`. Set in the environment, so the
# processes tests start (the CLI, notebook kernels, multi-device workers)
# compile the same way; JAX_DISABLE_MOST_OPTIMIZATIONS=0 switches it off.
os.environ.setdefault('JAX_DISABLE_MOST_OPTIMIZATIONS', '1')

# pylint: disable=g-import-not-at-top,wrong-import-position
import jax
import jax.numpy as jnp
import mujoco
import pytest

import mjx_composer as composer
from mjx_composer import platform

# As our scripts: keep compiled programs on disk between test runs, in the
# same folder as the scripts (`$MJX_COMPOSER_CACHE_DIR`, else
# `~/.cache/mjx_composer/jax`; MJX_COMPOSER_COMPILATION_CACHE=0 turns it
# off), so that tests that build the same environment load its programs
# instead of compiling them again, within one run and across runs: a fresh
# checkout (CI's) loads what earlier runs on the machine compiled. A cold
# cache makes a full run about three times longer on a 2-core CPU. Also
# threefry as one GPU kernel per call; Cholesky in XLA on the CPU.
platform.configure()

jax.config.update(
    'jax_disable_most_optimizations',
    os.environ['JAX_DISABLE_MOST_OPTIMIZATIONS'] not in ('', '0', 'false'),
)

# Python's cyclic garbage collector, tuned for tracing. A trace builds a
# large graph of objects (equations, tracers, abstract values) that lives
# until the trace ends, and CPython runs a full collection, which walks
# every tracked object of the process, each time the objects that outlived
# younger collections have grown by a quarter: a trace walks its own
# growing graph again and again and reclaims almost nothing (reference
# counting frees the rest). Most of the suite's time is tracing (its
# compiled programs load from the persistent cache); with CPython's
# thresholds, collections took 16% of two of its heaviest files. Full
# collections a hundred times rarer, and the imported modules frozen out of
# them, leave the young generations collected as before;
# `_free_compiled_programs` still collects everything after each module.
gc.collect()
gc.freeze()
gc.set_threshold(700, 10, 1000)


@pytest.fixture(autouse=True)
def _optimized_compiles(request):
  """Compiles fully optimized in tests marked `optimized` (see above)."""
  if request.node.get_closest_marker('optimized') is None:
    yield
    return
  before = jax.config.read('jax_disable_most_optimizations')
  jax.config.update('jax_disable_most_optimizations', False)
  try:
    yield
  finally:
    jax.config.update('jax_disable_most_optimizations', before)


@pytest.fixture(scope='module', autouse=True)
def _free_compiled_programs():
  """Drops JAX's in-memory caches after each test module.

  Without it an xdist worker holds every program and trace of every module
  it ran: about 6 GB a worker by the end of a run. Programs that later
  modules build again load from the persistent cache (above).
  """
  yield
  jax.clear_caches()
  gc.collect()


# -- the cache's use, reported at the end of the run -------------------------

_CACHE_EVENTS = {
    '/jax/compilation_cache/cache_hits': 'hits',
    '/jax/compilation_cache/cache_misses': 'misses',
}
_cache_counts = collections.Counter()
jax.monitoring.register_event_listener(
    lambda event, **_: _cache_counts.update(
        [_CACHE_EVENTS[event]] if event in _CACHE_EVENTS else []
    )
)
# One folder per run, named by the controlling process (xdist workers inherit
# its environment).
os.environ.setdefault('MJX_COMPOSER_TEST_RUN', str(os.getpid()))
_CACHE_REPORTS = os.path.join(
    tempfile.gettempdir(),
    f'mjx_composer_cache_report_{os.environ["MJX_COMPOSER_TEST_RUN"]}',
)


def pytest_sessionfinish(session):
  """Each process (an xdist worker too) writes its cache hits and misses."""
  del session
  os.makedirs(_CACHE_REPORTS, exist_ok=True)
  with open(os.path.join(_CACHE_REPORTS, f'{os.getpid()}.json'), 'w') as f:
    json.dump(dict(_cache_counts), f)


def pytest_terminal_summary(terminalreporter):
  """Sums the processes' reports into one line of the run's log."""
  if 'PYTEST_XDIST_WORKER' in os.environ:
    return  # The controlling process reports for the whole run.
  totals = collections.Counter()
  if os.path.isdir(_CACHE_REPORTS):
    for name in os.listdir(_CACHE_REPORTS):
      with open(os.path.join(_CACHE_REPORTS, name)) as f:
        totals.update(json.load(f))
    shutil.rmtree(_CACHE_REPORTS, ignore_errors=True)
  terminalreporter.write_line(
      f'persistent compilation cache ({jax.config.jax_compilation_cache_dir}'
      f'): {totals["hits"]} programs loaded, {totals["misses"]} compiled and '
      'written'
  )


class SpecEntity(composer.Entity):
  """A test entity whose `_build` adds elements to a spec of its own.

  A subclass's `_build` starts with `spec = self._new_spec(name)`.
  """

  def _new_spec(self, name):
    """Creates the entity's `MjSpec`, named `name`, and returns it."""
    self._spec = mujoco.MjSpec()
    self._spec.modelname = name
    return self._spec

  @property
  def mjcf_model(self):
    return self._spec


class Pendulum(SpecEntity, composer.Robot):
  """A hinged rod with a torque motor and, by default, a tip site.

  The constructor's arguments: `name`; `damping` of the hinge; `tip`, whether
  to add the site 'tip' at the rod's end; `ctrllimited` of the motor;
  `free_spin`, whether to add a second, unactuated hinge 'free_spin' (about x,
  with no range: `self.unlimited`); and more attributes of the hinge
  (`range`, `frictionloss`, ...).
  """

  def _build(
      self,
      name='pendulum',
      damping=0.1,
      tip=True,
      ctrllimited=True,
      free_spin=False,
      **hinge,
  ):
    spec = self._new_spec(name)
    body = spec.worldbody.add_body(name='rod', pos=[0, 0, 1])
    self.joint = body.add_joint(
        name='hinge',
        type=mujoco.mjtJoint.mjJNT_HINGE,
        axis=[0, 1, 0],
        damping=damping,
        **hinge,
    )
    self.geom = body.add_geom(
        name='rod',
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        size=[0.02, 0, 0],
        fromto=[0, 0, 0, 0, 0, -0.5],
        contype=0,
        conaffinity=0,
    )
    if tip:
      self.tip = body.add_site(name='tip', pos=[0, 0, -0.5])
    self.motor = spec.add_actuator(
        name='motor',
        target='hinge',
        trntype=mujoco.mjtTrn.mjTRN_JOINT,
        ctrlrange=[-1, 1],
        ctrllimited=ctrllimited,
    )
    if free_spin:
      self.unlimited = body.add_joint(
          name='free_spin', type=mujoco.mjtJoint.mjJNT_HINGE, axis=[1, 0, 0]
      )

  @property
  def actuators(self):
    return (self.motor,)


class Ball(SpecEntity):
  """A body 'body' with one sphere geom 'geom'.

  It weighs `mass`, or has `density` where one is given (with neither,
  MuJoCo's default density); `collides=False` sets contype = conaffinity = 0.
  """

  def _build(
      self, name='ball', radius=0.05, mass=0.1, density=None, collides=True
  ):
    spec = self._new_spec(name)
    geom = {} if collides else dict(contype=0, conaffinity=0)
    if density is not None:
      geom['density'] = density
    elif mass is not None:
      geom['mass'] = mass
    self.body = spec.worldbody.add_body(name='body')
    self.geom = self.body.add_geom(
        name='geom',
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[radius, 0, 0],
        **geom,
    )


class PendulumTask(composer.Task):
  """A task on `self.pendulum` (a `Pendulum`) in `self.arena`; it observes
  the pendulum's tip ('tip')."""

  @property
  def root_entity(self):
    return self.arena

  @property
  def task_observables(self):
    tip = composer.observation.observable.Generic(
        lambda physics: physics.bind(self.pendulum.tip).xpos
    )
    tip.enabled = True
    return {'tip': tip}


class SwingTask(PendulumTask):
  """Swing the pendulum tip high; a free ball drops on the floor.

  Terminates when the tip passes `terminate_above` (if set); the target
  height is per-world task state, sampled per episode.
  """

  def __init__(self, terminate_above=None):
    self.arena = composer.Arena()
    self.arena.mjcf_model.worldbody.add_geom(
        name='floor', type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1]
    )
    self.pendulum = Pendulum()
    self.arena.attach(self.pendulum)
    self.ball = Ball()
    self.arena.add_free_entity(self.ball)
    self.terminate_above = terminate_above
    self.set_timesteps(control_timestep=0.01, physics_timestep=0.005)

  def initial_task_state(self):
    return {'target': jnp.zeros(())}

  def initialize_episode(self, physics, key):
    angle_key, target_key, ball_key = jax.random.split(key, 3)
    physics = physics.bind(self.pendulum.joint).set(
        qpos=jax.random.uniform(angle_key, (1,), minval=-1, maxval=1)
    )
    physics = self.ball.set_pose(
        physics,
        position=jnp.concatenate(
            [
                jax.random.uniform(ball_key, (2,), minval=-1, maxval=1),
                jnp.array([0.3]),
            ]
        ),
    )
    return physics.update_task_state(
        target=jax.random.uniform(target_key, (), minval=0.6, maxval=0.9)
    )

  def get_reward(self, physics):
    return (
        physics.bind(self.pendulum.tip).xpos[2] - physics.task_state['target']
    )

  def should_terminate_episode(self, physics):
    if self.terminate_above is None:
      return False
    return physics.bind(self.pendulum.tip).xpos[2] > self.terminate_above

  def get_discount(self, physics):
    return jnp.where(self.should_terminate_episode(physics), 0.0, 1.0)


def make_swing_env(**kwargs):
  task_kwargs = {k: kwargs.pop(k) for k in ('terminate_above',) if k in kwargs}
  task = SwingTask(**task_kwargs)
  return composer.Environment(task, **kwargs)


@pytest.fixture(scope='session')
def swing_env():
  return make_swing_env(time_limit=0.05)


@pytest.fixture(scope='session')
def swing_fns(swing_env):
  """Jitted single-world and batched reset/step of `swing_env`."""
  return {
      'reset': jax.jit(swing_env.reset),
      'step': jax.jit(swing_env.step),
      'vreset': jax.jit(jax.vmap(swing_env.reset)),
      'vstep': jax.jit(jax.vmap(swing_env.step)),
  }


def run_script(script, argument, tmp_path, *, drop=(), env=None):
  """Runs `script` in a fresh CPU process; returns its last line as JSON.

  The process gets `json.dumps(argument)` as its argument, this repository
  on PYTHONPATH, none of the variables in `drop`, `XDG_CACHE_HOME` inside
  `tmp_path` (never the user's own cache folder), then `env`.
  """
  repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
  full_env = {k: v for k, v in os.environ.items() if k not in drop}
  full_env['JAX_PLATFORMS'] = 'cpu'
  full_env['XDG_CACHE_HOME'] = str(tmp_path / 'xdg')
  full_env['PYTHONPATH'] = os.pathsep.join(
      [repo] + [p for p in [os.environ.get('PYTHONPATH')] if p]
  )
  full_env.update(env or {})
  result = subprocess.run(
      [sys.executable, '-c', script, json.dumps(argument)],
      env=full_env,
      cwd=tmp_path,
      capture_output=True,
      text=True,
      timeout=300,
      check=False,
  )
  assert result.returncode == 0, result.stderr
  return json.loads(result.stdout.strip().splitlines()[-1])
