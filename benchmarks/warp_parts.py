"""Packs warp-lang for a GPU machine that takes at most 64 MiB per call.

The warp-lang 1.18.0 wheel is about 149 MB, and a device call carries at most
64 MiB (see `../shared/gpu/README.md`). This script unpacks the wheel without
its examples and tests, compresses it with xz (about 100 MB), and writes it
as parts of at most `--part-mb` MB into `.wp1/`, `.wp2/`, ... in the project
root (add them to `.git/info/exclude`). Carry one part per call, back to
back while the machine is warm (files outside `$OUT` stay on a warm machine;
it is released after about 30 s idle), copying each to `/tmp/wp/`; then join
and unpack them there:

    python benchmarks/warp_parts.py                  # here: .wp1, .wp2, ...
    # device call k (carry [".wpk"]): mkdir -p /tmp/wp && cp .wpk/* /tmp/wp/
    # last call: python3 benchmarks/warp_parts.py --join /tmp/wp /tmp/warpsite
    # then: export PYTHONPATH=/tmp/site:/tmp/warpsite:$PWD

Used at stop 20 for `benchmarks/backends.py` and `train_ppo.py --impl warp`
on one H200.
"""

import argparse
import glob
import io
import lzma
import os
import subprocess
import sys
import tarfile
import tempfile
import zipfile

WHEEL = 'warp-lang==1.18.0'
# Not needed to run MuJoCo Warp (and the bulk of what is not warp.so).
SKIP = ('warp/examples/', 'warp/tests/')


def pack(out_root, part_bytes):
  with tempfile.TemporaryDirectory() as tmp:
    subprocess.run(
        [sys.executable, '-m', 'pip', 'download', '-q', '--no-deps',
         '--only-binary=:all:', '-d', tmp, WHEEL],
        check=True,
    )  # fmt: skip
    (wheel,) = glob.glob(os.path.join(tmp, '*.whl'))
    buffer = io.BytesIO()
    with (
        zipfile.ZipFile(wheel) as z,
        tarfile.open(fileobj=buffer, mode='w') as tar,
    ):
      for info in z.infolist():
        if info.is_dir() or info.filename.startswith(SKIP):
          continue
        data = z.read(info)
        entry = tarfile.TarInfo(info.filename)
        entry.size = len(data)
        entry.mode = 0o755 if info.filename.endswith('.so') else 0o644
        tar.addfile(entry, io.BytesIO(data))
  packed = lzma.compress(buffer.getvalue(), preset=6)
  parts = [
      packed[i : i + part_bytes] for i in range(0, len(packed), part_bytes)
  ]
  for k, part in enumerate(parts, start=1):
    folder = os.path.join(out_root, f'.wp{k}')
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, f'part{k:02d}'), 'wb') as f:
      f.write(part)
  print(
      f'{len(packed) / 1e6:.1f} MB in {len(parts)} parts: '
      + ', '.join(f'.wp{k}' for k in range(1, len(parts) + 1))
  )


def join(parts_dir, target):
  names = sorted(glob.glob(os.path.join(parts_dir, 'part*')))
  if not names:
    sys.exit(f'No part files in {parts_dir}.')
  packed = b''.join(open(name, 'rb').read() for name in names)
  with tarfile.open(fileobj=io.BytesIO(lzma.decompress(packed))) as tar:
    tar.extractall(target, filter='data')
  print(f'{len(names)} parts unpacked into {target}')


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument(
      '--out', default='.', help='where .wp1, .wp2, ... go (project root)'
  )
  parser.add_argument('--part-mb', type=float, default=55.0)
  parser.add_argument(
      '--join',
      nargs=2,
      metavar=('PARTS_DIR', 'TARGET'),
      help='on the GPU machine: join the parts and unpack them',
  )
  args = parser.parse_args()
  if args.join:
    join(*args.join)
  else:
    pack(args.out, int(args.part_mb * 1e6))


if __name__ == '__main__':
  main()
