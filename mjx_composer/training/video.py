"""Rollouts of a policy, rendered on the host and written as MP4.

`rollout` runs a policy for some control steps on a few worlds (one jitted
`lax.scan`) and keeps every step's state and reward; `render_rollout` draws
each step's worlds with `mjx_composer.host.rendering` (each world with its
own per-world model fields), tiled in a grid; `write_mp4` encodes the frames
with imageio's FFmpeg plugin (imageio-ffmpeg ships the FFmpeg binary).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from mjx_composer.adapters import brax as brax_adapter
from mjx_composer.host import rendering
from mjx_composer.suite.tasks import registry

# The camera of tasks whose registry entry names none, looking at the
# workspace (a task's own camera, e.g. one following its robot in MuJoCo's
# 'trackcom' mode, is its entry's `camera`).
FREE_CAMERA = dict(
    distance=2.2, elevation=-25.0, azimuth=135.0, lookat=[0.0, 0.0, 0.25]
)


def rollout(
    brax_env,
    make_policy,
    params,
    worlds: int,
    steps: int,
    seed: int,
    deterministic: bool = True,
):
  """Runs a policy for `steps` control steps on `worlds` worlds.

  The parameters are an argument of the jitted rollout, not constants in
  it, so rollouts of other parameters of the same networks (each
  evaluation's video, `play`) run the same program: compiled once, or
  loaded from JAX's persistent compilation cache.

  Args:
    brax_env: the task's `BraxEnv`.
    make_policy: Brax's `make_policy(params, deterministic) -> policy`.
    params: the `(normalizer, policy, value)` parameters.
    worlds: the batch size.
    steps: control steps after the reset.
    seed: seeds the reset and the policy's sampling.
    deterministic: the distribution's mode (True) or samples.

  Returns:
    `(states, rewards, dones, metrics, observations)`: the composer `State`
    after the reset and after each step, stacked on a leading time axis
    (`steps + 1`); rewards and dones `(steps, worlds)`; the composer metrics
    of each step, `{name: (steps, worlds)}`; the observation each action was
    chosen from (`steps` on the time axis). Episodes that end restart in the
    same step (same-step auto-reset).
  """

  @jax.jit
  def run(params, key):
    policy = make_policy(params, deterministic=deterministic)

    def one_step(state, key):
      action, _ = policy(state.obs, key)
      next_state = brax_env.step(state, action)
      inner = brax_adapter.composer_state(next_state)
      return next_state, (
          inner,
          next_state.reward,
          next_state.done,
          inner.metrics,
          state.obs,
      )

    reset_key, step_key = jax.random.split(key)
    state = brax_env.reset(jax.random.split(reset_key, worlds))
    _, (inners, rewards, dones, metrics, observations) = jax.lax.scan(
        one_step, state, jax.random.split(step_key, steps)
    )
    first = brax_adapter.composer_state(state)
    inners = jax.tree.map(
        lambda a, b: jnp.concatenate([a[None], b]), first, inners
    )
    return inners, rewards, dones, metrics, observations

  return jax.device_get(run(params, jax.random.PRNGKey(seed)))


def _state_at(states, t):
  return jax.tree.map(lambda x: x[t], states)


def render_rollout(env, task, states, size=(120, 160), camera=None):
  """One tiled frame per time step of `rollout`'s states.

  Args:
    env: the `Environment`.
    task: the task's registered name (its entry's `camera`, else
      `FREE_CAMERA`).
    states: `rollout`'s states (time axis first, then worlds).
    size: (height, width) of each world's image.
    camera: overrides the task's camera.

  Returns:
    uint8 frames `(T, H, W, 3)`, the worlds in a near-square grid, H and W
    even (as H.264 needs).
  """
  if camera is None:
    camera = registry.entry(task).camera or FREE_CAMERA
  steps = np.shape(states.data.time)[0]
  worlds = np.shape(states.data.time)[1]
  columns = int(math.ceil(math.sqrt(worlds)))
  frames = []
  for t in range(steps):
    state = _state_at(states, t)
    target = (
        state.task_state.get('target')
        if isinstance(state.task_state, dict)
        else None
    )
    if target is not None and np.shape(target)[-1:] != (3,):
      target = None  # Not a position (a target height, a speed...).
    images = rendering.render(
        env,
        state,
        height=size[0],
        width=size[1],
        camera=camera,
        markers=target,
    )
    frames.append(rendering.image_grid(images, columns=columns))
  frames = np.stack(frames)
  h, w = frames.shape[1:3]
  return np.pad(
      frames, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)), constant_values=255
  )


def write_mp4(path: str, frames, fps: float) -> str:
  """Writes uint8 frames `(T, H, W, 3)` as an H.264 MP4 at `fps`."""
  try:
    import imageio.v2 as imageio  # pylint: disable=g-import-not-at-top
  except ImportError as e:
    raise ImportError(
        'Videos need imageio and imageio-ffmpeg: pip install '
        "'mjx-composer[train]'."
    ) from e
  imageio.mimwrite(
      path,
      list(np.asarray(frames, np.uint8)),
      fps=float(fps),
      codec='libx264',
      macro_block_size=1,
      ffmpeg_log_level='error',
  )
  return path


def read_mp4(path: str) -> np.ndarray:
  """The frames of an MP4 file, `(T, H, W, 3)` uint8 (for checks)."""
  import imageio.v2 as imageio  # pylint: disable=g-import-not-at-top

  return np.stack(imageio.mimread(path, memtest=False))
