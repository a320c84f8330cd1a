"""Watching a policy: rollouts, rendered on the host and written as MP4.

`make_rollout` jits one program running a policy, its mode (`MODES`) an
argument; `render_rollout` tiles each step's worlds; `write_mp4` encodes
them with imageio-ffmpeg's FFmpeg, started without a `preexec_fn` (the fork
of imageio's writer runs JAX's hook warning that forking may deadlock).
`play(run)` runs a run's policy in each mode: videos and statistics.
"""

from __future__ import annotations

import functools
import json
import math
import os
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import tqdm

from mjx_composer.adapters import brax as brax_adapter
from mjx_composer.host import rendering
from mjx_composer.suite.tasks import registry
from mjx_composer.training import policy as policy_lib

# The camera of tasks whose registry entry names none (`entry.camera`).
FREE_CAMERA = dict(
    distance=2.2, elevation=-25.0, azimuth=135.0, lookat=[0.0, 0.0, 0.25]
)
# The actions of `make_rollout`'s program, by its `mode` argument: the mode
# of the policy's action distribution, a sample of it (what training
# explored with), or zeros (a baseline: the actuators' zero command).
MODES = ('deterministic', 'sampled', 'zero')


def make_rollout(brax_env, make_policy, worlds: int, steps: int):
  """A jitted `run(params, key, mode)` of Brax's `make_policy`, `mode` an
  index into `MODES`, returning `(states, rewards, dones, metrics, obs)`:
  composer states after the reset and each step (`steps + 1` of them), then
  each step's rewards, dones, composer metrics and observation acted on.
  """

  # On a CPU the compile is nearly all of a rollout's time: at optimization
  # level 0, reach's 4-world, 60-step program compiled in 140 s against
  # 299 s, and its three runs took 6.3 s against 2.7 s.
  cpu = jax.default_backend() == 'cpu'
  options = {'xla_backend_optimization_level': 0} if cpu else None

  @functools.partial(jax.jit, compiler_options=options)
  def policy_rollout(params, key, mode):
    def one_step(state, key):
      act = lambda d: make_policy(params, d)(state.obs, key)[0]
      zero = lambda: jnp.zeros((worlds, brax_env.action_size))
      branches = [lambda: act(True), lambda: act(False), zero]
      next_state = brax_env.step(state, jax.lax.switch(mode, branches))
      inner = brax_adapter.composer_state(next_state)
      outputs = (next_state.reward, next_state.done, inner.metrics, state.obs)
      return next_state, (inner, *outputs)

    reset_key, step_key = jax.random.split(key)
    state = brax_env.reset(jax.random.split(reset_key, worlds))
    _, (inners, *outputs) = jax.lax.scan(
        one_step, state, jax.random.split(step_key, steps)
    )
    first = brax_adapter.composer_state(state)
    stack = lambda a, b: jnp.concatenate([a[None], b])
    return jax.tree.map(stack, first, inners), *outputs

  return policy_rollout


def mode_index(mode: str) -> int:
  """The `mode` argument of `make_rollout`'s program for a `MODES` name."""
  return MODES.index(mode)


def rollout(
    brax_env, make_policy, params, worlds, steps, seed, deterministic=True
):
  """`make_rollout`'s outputs on the host, run once (traced anew each call)."""
  run = make_rollout(brax_env, make_policy, worlds, steps)
  mode = mode_index('deterministic' if deterministic else 'sampled')
  return jax.device_get(run(params, jax.random.PRNGKey(seed), mode))


def task_camera(task: str):
  """The camera of `task`'s videos: its entry's, else `FREE_CAMERA`."""
  return registry.entry(task).camera or FREE_CAMERA


def render_rollout(
    env, task, states, size=(120, 160), camera=None, progress=None
):
  """uint8 frames `(T, H, W, 3)`, H and W even, of `rollout`'s states: the
  worlds tiled, each `size` (height, width), from `camera` (default:
  `task_camera(task)`); `progress(done, total)` after each frame."""
  fields = rendering.host_fields(states)
  steps, worlds = np.shape(fields['time'])
  task_state = states.task_state
  target = task_state.get('target') if isinstance(task_state, dict) else None
  if target is not None and np.shape(target)[-1:] != (3,):
    target = None  # not a position: a target height, a speed...
  images, grids = np.empty((worlds, *size, 3), np.uint8), []
  camera = task_camera(task) if camera is None else camera  # id 0 is one
  with rendering.WorldRenderer(env, *size, camera=camera) as renderer:
    for t in range(steps):
      at_t = jax.tree.map(lambda x, t=t: x[t], fields)
      markers = None if target is None else np.asarray(target[t])
      renderer.render(at_t, markers=markers, out=images)
      grids.append(rendering.image_grid(images, math.ceil(math.sqrt(worlds))))
      if progress is not None:
        progress(t + 1, steps)
  _, h, w, _ = np.shape(grids)  # padded with white to an even H and W
  return np.pad(
      grids,
      ((0, 0), (0, h % 2), (0, w % 2), (0, 0)),
      'constant',
      constant_values=255,
  )


def _ffmpeg(*arguments, data: bytes | None = None) -> bytes:
  """FFmpeg's stdout (`data` its stdin; its own session: Ctrl-C spares it)."""
  import imageio_ffmpeg  # pylint: disable=g-import-not-at-top

  command = [imageio_ffmpeg.get_ffmpeg_exe(), '-hide_banner', '-loglevel']
  result = subprocess.run(
      [*command, 'error', *arguments], input=data, capture_output=True,
      start_new_session=True, check=False,
  )  # fmt: skip
  if result.returncode:
    lines = result.stderr.decode(errors='replace').strip().splitlines()
    raise RuntimeError(
        f'FFmpeg failed (exit {result.returncode}): '
        f'{lines[-1] if lines else "no message"}'
    )
  return result.stdout


def write_mp4(path: str, frames, fps: float) -> str:
  """Writes uint8 frames `(T, H, W, 3)`, H and W even, as H.264 at `fps`."""
  frames = np.ascontiguousarray(frames, np.uint8)
  if frames.ndim != 4 or frames.shape[-1] != 3 or not frames.shape[0]:
    raise ValueError(
        f'write_mp4 takes frames (T, H, W, 3), got {frames.shape}.'
    )
  _, height, width, _ = frames.shape
  if height % 2 or width % 2:
    raise ValueError(
        f'H.264 needs an even height and width: {height} x {width}.'
    )
  _ffmpeg(
      '-y', '-f', 'rawvideo', '-pix_fmt', 'rgb24', '-s', f'{width}x{height}',
      '-r', f'{float(fps)}', '-i', 'pipe:0', '-an', '-c:v', 'libx264',
      '-pix_fmt', 'yuv420p', path, data=frames.tobytes(),
  )  # fmt: skip
  return path


def read_mp4(path: str) -> np.ndarray:
  """The frames of an MP4 file, `(T, H, W, 3)` uint8 (for checks)."""
  data = _ffmpeg('-i', path, '-f', 'image2pipe', '-c:v', 'ppm', 'pipe:1')
  # Binary PPM images of one size: 'P6 W H 255', one whitespace, the pixels.
  fields = data[:64].split(maxsplit=4)
  width, height = int(fields[1]), int(fields[2])
  header = len(b' '.join(fields[:4])) + 1
  frame = header + width * height * 3
  frames = np.frombuffer(data, np.uint8).reshape(-1, frame)
  return frames[:, header:].reshape(-1, height, width, 3)


def play(
    run_path, worlds=4, steps=None, out=None, seed=1, render=True, verbose=False
):
  """Plays the run's newest policy; returns `{mode: statistics}`.

  `steps` defaults to one episode, `out` to the run's `videos/`; `seed`
  seeds the reset and the samples. The statistics are written to
  `json_path(out, step)` too (docs/training.md).
  """
  if worlds < 1:
    raise ValueError(f'--worlds must be at least 1, got {worlds}.')
  if steps is not None and steps < 1:
    raise ValueError(f'--steps must be at least 1, got {steps}.')
  log = functools.partial(print, flush=True) if verbose else lambda _: None
  run, config, checkpoint, env, brax_env = policy_lib.load(run_path)
  steps = steps or brax_env.episode_length
  out = out or run.video_dir
  os.makedirs(out, exist_ok=True)
  run_program = make_rollout(
      brax_env, policy_lib.make_inference(config, checkpoint), worlds, steps
  )
  log(
      f'Building the rollout program of {worlds} worlds x {steps} steps of '
      f'{config.task!r}, one for the {", ".join(MODES)} runs: tracing the '
      "environment's step (tens of seconds on a CPU), then compiling it "
      '(minutes) or loading it from the compilation cache...'
  )
  result = {}
  for mode in MODES:
    start = time.perf_counter()
    key = jax.random.PRNGKey(seed)
    outputs = run_program(checkpoint.params, key, mode_index(mode))
    states, rewards, dones, metrics, _ = jax.device_get(outputs)
    log(
        f'{"Ran" if result else "Built the program and ran"} the {mode} '
        f'rollout in {time.perf_counter() - start:.1f}s.'
    )
    ended = np.asarray(dones) > 0
    mean = lambda x, ended=ended: float(np.asarray(x)[ended].mean())
    stats = {
        'episodes': int(ended.sum()),
        'mean_reward_per_step': float(np.mean(rewards)),
        'mean_return': mean(metrics['episode_return']) if ended.any() else None,
        'mean_length': mean(metrics['episode_length']) if ended.any() else None,
        'step': checkpoint.step,
        # Over every step of every world (worlds restart in the same step);
        # integer entries (episode lengths) left out.
        'metrics': {
            name: float(np.mean(value))
            for name, value in metrics.items()
            if np.issubdtype(np.asarray(value).dtype, np.floating)
        }
        | {'reward': float(np.mean(rewards))},
    }
    if render and mode != 'zero':  # a baseline for the numbers only
      start = time.perf_counter()
      with tqdm.tqdm(
          total=steps + 1, unit='frame', desc=f'rendering {mode}',
          file=sys.stdout, mininterval=1.0, disable=not verbose,
      ) as bar:  # fmt: skip
        progress = lambda done, _: bar.update(done - bar.n)
        size = config.video_size
        frames = render_rollout(env, config.task, states, size, None, progress)
      fps = 1.0 / env.control_timestep()
      name = os.path.join(out, f'play_{mode}_step_{checkpoint.step:012d}.mp4')
      stats['video'] = write_mp4(name, frames, fps)
      log(
          f'Wrote {stats["video"]} ({len(frames)} frames in '
          f'{time.perf_counter() - start:.1f}s).'
      )
    result[mode] = stats
  path = json_path(out, checkpoint.step)
  with open(path, 'w') as f:
    payload = {'worlds': worlds, 'steps': steps, 'seed': seed}
    json.dump({**payload, 'modes': result}, f, indent=1)
  log(f'Wrote {path}.')
  return result


def json_path(out: str, step: int) -> str:
  """Where `play` writes the statistics and metrics of a checkpoint's step."""
  return os.path.join(out, f'play_step_{step:012d}.json')
