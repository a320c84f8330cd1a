"""Rollouts of a policy, rendered on the host and written as MP4.

`make_rollout` jits one program that runs a policy for some control steps
on a few worlds (a `lax.scan`) and keeps every step's state, reward and
metrics; which actions it takes (the policy's mode, its samples, or zeros)
is an argument of the program, not a constant in it, so every mode runs the
same compiled program. `render_rollout` draws each step's worlds with one
`mjx_composer.host.rendering.WorldRenderer` (each world with its own
per-world model fields), tiled in a grid; `write_mp4` encodes the frames as
H.264 with the FFmpeg binary that imageio-ffmpeg ships, started without
forking this process (JAX warns that a fork of its multithreaded process
may deadlock).
"""

from __future__ import annotations

import functools
import math
import subprocess

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


# What `make_rollout`'s program does with the actions, by its `mode`
# argument: the mode of the policy's action distribution, a sample of it
# (what training explored with), or zero actions (a baseline: the
# actuators' zero command, e.g. a robot's home pose).
MODES = ('deterministic', 'sampled', 'zero')


def _compiler_options():
  """XLA options of the rollout program: on a CPU, optimization level 0.

  A rollout for a video runs a few hundred world steps once, so on a CPU
  its compile is nearly all of its time: reach's 4-world, 60-step program
  compiled in 140 s at level 0 against 299 s at XLA's default, and its
  three runs took 6.3 s against 2.7 s (a 2-core CPU). A GPU's compile is
  seconds: its defaults stay.
  """
  if jax.default_backend() == 'cpu':
    return {'xla_backend_optimization_level': 0}
  return None


def make_rollout(brax_env, make_policy, worlds: int, steps: int):
  """A jitted `run(params, key, mode)`: a policy for `steps` steps.

  The parameters and the mode are arguments of the program, not constants
  in it, so rollouts of other parameters of the same networks (each
  evaluation's video, `play`) and of every mode run one program: compiled
  once, or loaded from JAX's persistent compilation cache.

  Args:
    brax_env: the task's `BraxEnv`.
    make_policy: Brax's `make_policy(params, deterministic) -> policy`.
    worlds: the batch size.
    steps: control steps after the reset.

  Returns:
    `run(params, key, mode)`, `mode` an index into `MODES`, returning (on
    the device) `(states, rewards, dones, metrics, observations)`: the
    composer `State` after the reset and after each step, stacked on a
    leading time axis (`steps + 1`); rewards and dones `(steps, worlds)`;
    the composer metrics of each step, `{name: (steps, worlds)}`; the
    observation each action was chosen from (`steps` on the time axis).
    Episodes that end restart in the same step (same-step auto-reset). The
    same key gives every mode the same reset.
  """
  if worlds < 1 or steps < 1:
    raise ValueError(
        f'A rollout needs at least one world and one step, got {worlds} '
        f'worlds and {steps} steps.'
    )

  def act(params, obs, key, mode):
    branches = [
        lambda: make_policy(params, deterministic=True)(obs, key)[0],
        lambda: make_policy(params, deterministic=False)(obs, key)[0],
        lambda: jnp.zeros((worlds, brax_env.action_size)),
    ]
    return jax.lax.switch(mode, branches)

  @functools.partial(jax.jit, compiler_options=_compiler_options())
  def policy_rollout(params, key, mode):
    def one_step(state, key):
      next_state = brax_env.step(state, act(params, state.obs, key, mode))
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

  return policy_rollout


def mode_index(mode: str) -> int:
  """The `mode` argument of `make_rollout`'s program for a `MODES` name."""
  if mode not in MODES:
    raise ValueError(f'Unknown rollout mode {mode!r}; one of {MODES}.')
  return MODES.index(mode)


def rollout(
    brax_env,
    make_policy,
    params,
    worlds: int,
    steps: int,
    seed: int,
    deterministic: bool = True,
):
  """Runs a policy for `steps` control steps on `worlds` worlds, once.

  `make_rollout`'s program (deterministic or sampled actions), called with
  a key from `seed`; its outputs on the host. To run several modes or
  parameters, keep `make_rollout`'s function instead: this traces it again.
  """
  run = make_rollout(brax_env, make_policy, worlds, steps)
  mode = mode_index('deterministic' if deterministic else 'sampled')
  return jax.device_get(run(params, jax.random.PRNGKey(seed), mode))


def task_camera(task: str):
  """The camera videos of `task` are drawn from: its entry's, else `FREE_CAMERA`."""
  return registry.entry(task).camera or FREE_CAMERA


def render_rollout(
    env, task, states, size=(120, 160), camera=None, progress=None
):
  """One tiled frame per time step of `rollout`'s states.

  Every frame is drawn by one `rendering.WorldRenderer`: no OpenGL context,
  model or data is made per frame or per world.

  Args:
    env: the `Environment`.
    task: the task's registered name (its entry's `camera`, else
      `FREE_CAMERA`).
    states: `rollout`'s states (time axis first, then worlds).
    size: (height, width) of each world's image.
    camera: overrides the task's camera.
    progress: optional `progress(frames_done, frames_total)`, called after
      each frame.

  Returns:
    uint8 frames `(T, H, W, 3)`, the worlds in a near-square grid, H and W
    even (as H.264 needs).
  """
  if camera is None:
    camera = task_camera(task)
  fields = rendering.host_fields(states)
  steps, worlds = np.shape(fields['time'])
  columns = int(math.ceil(math.sqrt(worlds)))
  target = (
      states.task_state.get('target')
      if isinstance(states.task_state, dict)
      else None
  )
  if target is not None and np.shape(target)[-1:] != (3,):
    target = None  # Not a position (a target height, a speed...).
  if target is not None:
    target = np.asarray(target)
  height, width = size
  images = np.empty((worlds, height, width, 3), np.uint8)
  frames = None
  with rendering.WorldRenderer(env, height, width, camera=camera) as renderer:
    for t in range(steps):
      renderer.render(
          jax.tree.map(lambda x, t=t: x[t], fields),
          markers=None if target is None else target[t],
          out=images,
      )
      grid = rendering.image_grid(images, columns=columns)
      if frames is None:
        h, w = grid.shape[:2]
        # H.264 needs an even height and width: pad with white.
        frames = np.full((steps, h + h % 2, w + w % 2, 3), 255, np.uint8)
      frames[t, : grid.shape[0], : grid.shape[1]] = grid
      if progress is not None:
        progress(t + 1, steps)
  return frames


def _ffmpeg() -> str:
  """The FFmpeg binary imageio-ffmpeg ships."""
  try:
    import imageio_ffmpeg  # pylint: disable=g-import-not-at-top
  except ImportError as e:
    raise ImportError(
        "Videos need imageio-ffmpeg's FFmpeg: pip install "
        "'mjx-composer[train]'."
    ) from e
  return imageio_ffmpeg.get_ffmpeg_exe()


def _run_ffmpeg(arguments, data: bytes | None = None) -> bytes:
  """Runs FFmpeg with `data` on its stdin; returns its stdout.

  `subprocess` starts it without `os.fork()`'s Python-level hooks (JAX's
  warns that forking its multithreaded process may deadlock; imageio's
  writer forks through a `preexec_fn`, which runs them), in a session of
  its own so that Ctrl-C in a terminal reaches this process only.
  """
  result = subprocess.run(
      [_ffmpeg(), '-hide_banner', '-loglevel', 'error', *arguments],
      input=data,
      capture_output=True,
      start_new_session=True,
      check=False,
  )
  if result.returncode:
    message = result.stderr.decode(errors='replace').strip().splitlines()
    raise RuntimeError(
        f'FFmpeg failed (exit {result.returncode}): '
        f'{message[-1] if message else "no message"}'
    )
  return result.stdout


def write_mp4(path: str, frames, fps: float) -> str:
  """Writes uint8 frames `(T, H, W, 3)` as an H.264 MP4 at `fps`.

  H and W must be even (H.264's 4:2:0 chroma; `render_rollout` pads).
  """
  frames = np.ascontiguousarray(frames, np.uint8)
  if frames.ndim != 4 or frames.shape[-1] != 3 or not frames.shape[0]:
    raise ValueError(
        f'write_mp4 takes RGB frames (T, H, W, 3) with T >= 1, got shape '
        f'{frames.shape}.'
    )
  _, height, width, _ = frames.shape
  if height % 2 or width % 2:
    raise ValueError(
        f'H.264 needs an even height and width, got {height} x {width}: pad '
        'the frames by a row or column.'
    )
  _run_ffmpeg(
      [
          '-y',
          '-f', 'rawvideo',
          '-pix_fmt', 'rgb24',
          '-s', f'{width}x{height}',
          '-r', f'{float(fps)}',
          '-i', 'pipe:0',
          '-an',
          '-c:v', 'libx264',
          '-pix_fmt', 'yuv420p',
          path,
      ],
      frames.tobytes(),
  )  # fmt: skip
  return path


def read_mp4(path: str) -> np.ndarray:
  """The frames of an MP4 file, `(T, H, W, 3)` uint8 (for checks)."""
  # Decoded as a stream of binary PPM images: each says its own size.
  data = _run_ffmpeg(['-i', path, '-f', 'image2pipe', '-c:v', 'ppm', 'pipe:1'])
  frames = []
  offset = 0
  while offset < len(data):
    # 'P6', width, height and 255, separated by single whitespace bytes.
    fields = data[offset : offset + 64].split(maxsplit=4)
    width, height = int(fields[1]), int(fields[2])
    header = len(b' '.join(fields[:4])) + 1
    size = width * height * 3
    pixels = np.frombuffer(data, np.uint8, size, offset + header)
    frames.append(pixels.reshape(height, width, 3))
    offset += header + size
  return np.stack(frames)
