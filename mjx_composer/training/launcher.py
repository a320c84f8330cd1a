"""One training process per GPU of this host, joined by `jax.distributed`.

`mjx-composer train TASK --processes N` starts N training processes on this
host, process i on the i-th visible GPU (its own `CUDA_VISIBLE_DEVICES`),
joined through `jax.distributed.initialize` with a coordinator on this host:
the code path of N hosts with one GPU each, where each process launches only
its own GPU's programs. Brax's `ppo.train` runs unchanged in every process:
each steps its share of `num_envs` and averages gradients with the others in
its `pmap`; process 0 evaluates and writes the run folder (metrics,
checkpoints, videos, summary); the others write their output to
`logs/process_<i>.log` in the run folder.

The launcher creates the run folder before it starts the processes, which
open it as `--resume` does, and never initializes JAX itself (so it holds no
GPU memory). The task's registry entry goes to the processes pickled (its
factory by reference, as `multiprocessing` sends functions): a task
registered by a module or by the script that calls `mjx_composer.cli.main`
is found there too (the script is loaded as `__mp_main__`, its
`if __name__ == '__main__':` block not run); a lambda factory cannot be sent.
The launcher returns when every process has ended; when one fails, or the
launcher is interrupted or terminated, it stops the others.

On several hosts, start one worker per GPU yourself with the same
`MJX_COMPOSER_PROCESS` variable (`launcher.process_spec`) naming the
coordinator, as with any `jax.distributed` program.
"""

from __future__ import annotations

import dataclasses
import os
import pickle
import runpy
import signal
import socket
import subprocess
import sys
import time

# `"<process id>/<processes>@<coordinator host:port>"` of a worker process.
PROCESS_ENV = 'MJX_COMPOSER_PROCESS'
LOG_DIR = 'logs'
_TASK_FILE = 'task.pkl'


@dataclasses.dataclass(frozen=True)
class ProcessSpec:
  """A worker's place among the training processes."""

  process_id: int
  num_processes: int
  coordinator: str

  def __str__(self):
    return f'{self.process_id}/{self.num_processes}@{self.coordinator}'

  @classmethod
  def parse(cls, text: str) -> ProcessSpec:
    """The spec of `"<id>/<processes>@<host:port>"`.

    Raises:
      ValueError: for any other text.
    """
    try:
      ids, coordinator = text.split('@')
      process_id, num_processes = (int(x) for x in ids.split('/'))
    except ValueError:
      process_id = num_processes = coordinator = None
    if (
        process_id is None
        or not 0 <= process_id < num_processes
        or ':' not in coordinator
    ):
      raise ValueError(
          f'{PROCESS_ENV}={text!r}: expected "<process id>/<processes>@'
          '<coordinator host:port>", e.g. "0/4@localhost:12345".'
      )
    return cls(process_id, num_processes, coordinator)


def process_spec() -> ProcessSpec | None:
  """This process's `ProcessSpec` from `MJX_COMPOSER_PROCESS`, if set."""
  text = os.environ.get(PROCESS_ENV)
  return ProcessSpec.parse(text) if text else None


def visible_gpus(processes: int) -> list[str | None]:
  """The GPU each of `processes` workers sees, in order.

  The ids of `CUDA_VISIBLE_DEVICES` where it is set, else 0, 1, ...; None
  for every worker where JAX runs on the CPU only (`JAX_PLATFORMS=cpu`).

  Raises:
    ValueError: where `CUDA_VISIBLE_DEVICES` names fewer GPUs than
      `processes`.
  """
  if os.environ.get('JAX_PLATFORMS', '').strip().lower() == 'cpu':
    return [None] * processes
  visible = os.environ.get('CUDA_VISIBLE_DEVICES')
  if visible is None:
    return [str(i) for i in range(processes)]
  ids = [x.strip() for x in visible.split(',') if x.strip()]
  if len(ids) < processes:
    raise ValueError(
        f'--processes {processes}, but CUDA_VISIBLE_DEVICES={visible!r} '
        f'names {len(ids)} GPUs: one process per GPU. Pass --processes '
        f'{len(ids)} or fewer, or make more GPUs visible.'
    )
  return ids[:processes]


def _free_port() -> int:
  with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
    s.bind(('localhost', 0))
    return s.getsockname()[1]


def worker_command(run_path: str, resume: bool) -> list[str]:
  """The command line of one worker process."""
  command = [sys.executable, '-m', 'mjx_composer.training.launcher', run_path]
  return command + (['--resume'] if resume else [])


def launch(run_path: str, resume: bool, processes: int, log=print) -> int:
  """Trains the run at `run_path` in `processes` processes on this host.

  Args:
    run_path: an existing run folder (its config names what to train).
    resume: continue from the run's newest checkpoint.
    processes: how many processes (one per GPU).
    log: where the launcher's own lines go.

  Returns:
    0 when every process succeeded, else the first failure's exit code.
  """
  gpus = visible_gpus(processes)
  coordinator = f'localhost:{_free_port()}'
  log_dir = os.path.join(run_path, LOG_DIR)
  os.makedirs(log_dir, exist_ok=True)
  _send_task(run_path, log_dir)
  workers, files = [], []
  for i, gpu in enumerate(gpus):
    env = dict(os.environ)
    env[PROCESS_ENV] = str(ProcessSpec(i, processes, coordinator))
    if gpu is not None:
      env['CUDA_VISIBLE_DEVICES'] = gpu
    out = None
    if i:
      out = open(os.path.join(log_dir, f'process_{i}.log'), 'w')
      files.append(out)
    workers.append(
        subprocess.Popen(
            worker_command(run_path, resume),
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT if out else None,
        )
    )
  log(
      f'Training in {processes} processes (coordinator {coordinator}; GPUs '
      f'{", ".join(g or "cpu" for g in gpus)}); processes 1.. write to '
      f'{log_dir}.'
  )

  def stop(signum, frame):  # pylint: disable=unused-argument
    _terminate(workers)
    raise SystemExit(128 + signum)

  previous = {
      s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)
  }
  try:
    return _wait(workers, log)
  finally:
    for s, handler in previous.items():
      signal.signal(s, handler)
    _terminate(workers)
    for f in files:
      f.close()


def _send_task(run_path: str, log_dir: str) -> None:
  """Pickles the run's task entry (and this script's path) for the workers.

  Raises:
    ValueError: for a factory that cannot be pickled (a lambda, a local
      function), with the fix.
  """
  # pylint: disable=g-import-not-at-top
  from mjx_composer.suite.tasks import registry
  from mjx_composer.training import run_folder

  # pylint: enable=g-import-not-at-top
  entry = registry.entry(run_folder.open_run(run_path).read_config().task)
  main = sys.modules.get('__main__')
  try:
    pickled_entry = pickle.dumps(entry)
  except (pickle.PicklingError, AttributeError, TypeError) as e:
    raise ValueError(
        f'Task {entry.name!r} cannot be sent to the training processes: its '
        f'factory {entry.factory!r} is not importable by name ({e}). '
        'Register it with a module-level function or class to train it with '
        '--processes.'
    ) from e
  # Two layers: the script's path is read before the entry, whose factory
  # may live in the script.
  payload = {'main': getattr(main, '__file__', None), 'entry': pickled_entry}
  with open(os.path.join(log_dir, _TASK_FILE), 'wb') as f:
    pickle.dump(payload, f)


class _TaskUnpickler(pickle.Unpickler):
  """Finds the launching script's names (`__main__`) in `__mp_main__`."""

  def __init__(self, file, main_path):
    super().__init__(file)
    self._main_path = main_path

  def find_class(self, module, name):
    if module == '__main__' and self._main_path:
      if '__mp_main__' not in sys.modules:
        namespace = runpy.run_path(self._main_path, run_name='__mp_main__')
        main = type(sys)('__mp_main__')
        main.__dict__.update(namespace)
        sys.modules['__mp_main__'] = main
      return getattr(sys.modules['__mp_main__'], name)
    return super().find_class(module, name)


def _receive_task(run_path: str) -> None:
  """Registers the launcher's task entry here, unless it is registered."""
  # pylint: disable=g-import-not-at-top
  import io

  from mjx_composer.suite.tasks import registry

  # pylint: enable=g-import-not-at-top
  path = os.path.join(run_path, LOG_DIR, _TASK_FILE)
  if not os.path.exists(path):
    return  # started by hand: the task is registered where it is imported
  with open(path, 'rb') as f:
    payload = pickle.load(f)
  entry = _TaskUnpickler(io.BytesIO(payload['entry']), payload['main']).load()
  if entry.name not in registry.names():
    registry.register(
        entry.name,
        entry.factory,
        description=entry.description,
        distance=entry.distance,
    )


def _wait(workers, log) -> int:
  """Waits for every worker; on a failure, stops the rest."""
  while True:
    codes = [w.poll() for w in workers]
    failed = [(i, c) for i, c in enumerate(codes) if c not in (None, 0)]
    if failed:
      i, code = failed[0]
      log(f'Training process {i} failed (exit code {code}): stopping the rest.')
      return code
    if all(c == 0 for c in codes):
      return 0
    time.sleep(0.2)


def _terminate(workers, grace_s: float = 10.0) -> None:
  for w in workers:
    if w.poll() is None:
      w.terminate()
  deadline = time.monotonic() + grace_s
  for w in workers:
    try:
      w.wait(max(0.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
      w.kill()
      w.wait()


def run_worker(run_path: str, resume: bool) -> None:
  """One worker: joins the others, then trains its share of the run."""
  spec = process_spec()
  if spec is None:
    raise ValueError(
        f'A training worker needs {PROCESS_ENV}; start workers through '
        '`mjx-composer train ... --processes N`.'
    )
  # pylint: disable=g-import-not-at-top
  import jax

  from mjx_composer.training import run_folder
  from mjx_composer.training import trainer

  # pylint: enable=g-import-not-at-top
  # CPU processes reduce across processes through Gloo (GPUs through NCCL).
  jax.config.update('jax_cpu_collectives_implementation', 'gloo')
  jax.distributed.initialize(
      coordinator_address=spec.coordinator,
      num_processes=spec.num_processes,
      process_id=spec.process_id,
  )
  # After joining: the task's module may touch JAX's devices on import.
  _receive_task(run_path)
  run = run_folder.open_run(run_path)
  trainer.train(run.read_config(), run, resume=resume)


def main(argv) -> int:
  """A worker's entry point: `python -m mjx_composer.training.launcher RUN
  [--resume]`."""
  # pylint: disable=g-import-not-at-top
  from mjx_composer.training import run_folder

  # pylint: enable=g-import-not-at-top
  try:
    run_worker(argv[0], '--resume' in argv[1:])
  except (run_folder.RunFolderError, ValueError) as e:
    print(f'error: {e}', file=sys.stderr)
    return 2
  return 0


if __name__ == '__main__':
  sys.exit(main(sys.argv[1:]))
