"""What the device runs per control step: kernels, copies, and idle time.

For the bundled reach task (no time limit, domain randomization off) at one
number of worlds, three programs from the same reset states:

* raw:           raw MJX (`common.raw_rollout`);
* raw_in_state:  raw MJX's control step on a composed `State`'s data
                 (`step_parts.py`);
* step:          `vmap(env.step)`.

Each is compiled, run twice, timed once (`wall_us`) and profiled once
(`jax.profiler`). Per control step it reports the device's operations by
stream and kind (kernels, memory copies), their summed duration, the time
the device was busy (the union of the operations' intervals: `busy_us`), and
counts of the compiled program's `copy`, `while` and `conditional`
instructions. Wall-clock minus busy time is the device idling between
operations: where a program of many small kernels loses to one of fewer
(launch latency, host round trips of data-dependent loops). The compiled
programs' HLO text is written next to `--out` (`hlo_<program>.txt`).

    python benchmarks/device_events.py --worlds 8192

On a CPU the profile has no device rows: only the wall-clock and HLO
counts are filled in.
"""

import collections
import os
import re
import tempfile
import time

import jax

import common  # benchmarks/common.py
import step_parts  # benchmarks/step_parts.py


def _events(trace_dir):
  """The device rows' complete events of the newest Perfetto trace."""
  events = common.perfetto_events(trace_dir)
  processes = common.metadata_names(events, 'process_name')
  threads = common.metadata_names(events, 'thread_name')
  device = {p for p, name in processes.items() if '/device:' in name}
  return [
      (threads.get((e['pid'], e['tid']), ''), e)
      for e in events
      if e.get('ph') == 'X' and e.get('pid') in device
  ]


def _summary(events, steps):
  counts, durations = collections.Counter(), collections.Counter()
  spans = []
  for stream, e in events:
    name = e.get('name', '')
    kind = 'memcpy' if 'emcpy' in name else 'kernel'
    counts[f'{stream[:40]}|{kind}'] += 1
    durations[f'{stream[:40]}|{kind}'] += float(e.get('dur', 0))
    start = float(e['ts'])
    spans.append((start, start + float(e.get('dur', 0))))
  spans.sort()
  busy, end = 0.0, None
  for start, stop in spans:
    if end is None or start > end:
      busy, end = busy + stop - start, stop
    elif stop > end:
      busy, end = busy + stop - end, stop
  return {
      'busy_us': busy / steps,
      'operations': {k: v / steps for k, v in counts.items()},
      'operation_us': {k: v / steps for k, v in durations.items()},
  }


def main():
  parser = common.make_parser(__doc__, worlds=[8192], out='device_events.json')
  parser.add_argument('--steps', type=int, default=20)
  args = parser.parse_args()
  device = common.print_device()
  worlds, steps = args.worlds[0], args.steps
  env = common.make_env('reach', randomize=False, time_limit=float('inf'))
  keys = jax.random.split(jax.random.key(0), worlds)
  states = jax.jit(jax.vmap(env.reset))(keys)
  actions = common.random_actions(env, worlds)
  n = env.n_sub_steps
  programs = {
      'raw': (common.raw_rollout(env.mjx_model, n, steps), states.data),
      'raw_in_state': (step_parts.state_rollout(env, steps), states),
      'step': (common.env_rollout(env, steps), states),
  }
  results = {}
  for name, (fn, start) in programs.items():
    compiled = fn.lower(start, actions).compile()
    hlo = compiled.as_text()
    with open(
        os.path.join(os.path.dirname(args.out) or '.', f'hlo_{name}.txt'), 'w'
    ) as f:
      f.write(hlo)
    out = jax.block_until_ready(compiled(start, actions))
    out = jax.block_until_ready(compiled(*out))
    t0 = time.perf_counter()
    out = jax.block_until_ready(compiled(*out))
    wall = time.perf_counter() - t0
    trace_dir = tempfile.mkdtemp(prefix='device_events_')
    with jax.profiler.trace(trace_dir, create_perfetto_trace=True):
      out = jax.block_until_ready(compiled(*out))
    results[name] = {
        'wall_us': wall * 1e6 / steps,
        **_summary(_events(trace_dir), steps),
        'hlo_copies': len(re.findall(r' copy\(', hlo)),
        'hlo_while_loops': len(re.findall(r' while\(', hlo)),
        'hlo_conditionals': len(re.findall(r' conditional\(', hlo)),
    }
    row = results[name]
    print(
        f'{name}: wall {row["wall_us"]:,.0f} us, busy {row["busy_us"]:,.0f} us'
        f' per control step; {row["operations"]}',
        flush=True,
    )
  common.write_json(
      args.out,
      {
          'device': device.device_kind,
          'jax': jax.__version__,
          'worlds': worlds,
          'steps': steps,
          'results': results,
      },
  )


if __name__ == '__main__':
  main()
