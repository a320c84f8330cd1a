"""The analyses' answers kept on disk (`platform.answer_cache`), as
`runtime.data_reads.PerStructure` uses them."""

import json
import sys

import jax
import pytest

from mjx_composer.platform import answer_cache
from mjx_composer.runtime import carried_stage
from mjx_composer.runtime import data_reads
from mjx_composer.runtime import reset_forward
from tests import conftest


@pytest.fixture(name='folder')
def _folder(tmp_path, monkeypatch):
  """Answers kept in `tmp_path`, as if the compilation cache were there."""
  monkeypatch.setattr(answer_cache, 'folder', lambda: str(tmp_path))
  return tmp_path


class _Counted:
  """`compute` for `PerStructure`: returns `answer`, counting the calls."""

  def __init__(self, answer):
    self.answer = answer
    self.calls = 0

  def __call__(self):
    self.calls += 1
    return self.answer


_KEY = ('full', True, (3, 4), ((2,), 'float32'))
_ANSWER = frozenset({'qpos', 'xpos', '_impl.efc_J'})


def test_a_later_process_reads_the_answer_instead_of_computing(folder):
  compute = _Counted(_ANSWER)
  assert data_reads.PerStructure('test')(_KEY, compute) == _ANSWER
  assert data_reads.PerStructure('test')(_KEY, compute) == _ANSWER
  assert compute.calls == 1
  (kept,) = folder.glob('*.json')
  assert json.loads(kept.read_text()) == {'set': sorted(_ANSWER)}
  # Another question, or the same one asked by another analysis, is its own.
  assert data_reads.PerStructure('test')(('other',), compute) == _ANSWER
  assert data_reads.PerStructure('another')(_KEY, compute) == _ANSWER
  assert compute.calls == 3


def test_tuples_of_sets_are_kept_whole(folder):
  del folder
  answer = (frozenset({'qpos'}), frozenset(), frozenset({'a', 'b'}))
  compute = _Counted(answer)
  for _ in range(2):
    assert data_reads.PerStructure('test')(_KEY, compute) == answer
  assert compute.calls == 1


@pytest.mark.parametrize(
    'content', ['', '{"set": ["qpos"', '{"set": [1]}', '[]', '{"list": []}']
)
def test_an_unreadable_answer_is_computed_and_written_afresh(folder, content):
  compute = _Counted(_ANSWER)
  data_reads.PerStructure('test')(_KEY, compute)
  (kept,) = folder.glob('*.json')
  kept.write_text(content)
  assert data_reads.PerStructure('test')(_KEY, compute) == _ANSWER
  assert compute.calls == 2
  assert json.loads(kept.read_text()) == {'set': sorted(_ANSWER)}


def test_without_a_kind_or_a_folder_nothing_is_kept(folder, monkeypatch):
  compute = _Counted(_ANSWER)
  data_reads.PerStructure()(_KEY, compute)
  data_reads.PerStructure()(_KEY, compute)
  monkeypatch.setattr(answer_cache, 'folder', lambda: None)
  data_reads.PerStructure('test')(_KEY, compute)
  data_reads.PerStructure('test')(_KEY, compute)
  assert compute.calls == 4
  assert not list(folder.iterdir())


def test_the_digest_changes_with_the_code(tmp_path, monkeypatch):
  """Editing a source file of a package the answers depend on, or asking
  another question, gives another file name."""
  package = tmp_path / 'traced_package'
  package.mkdir()
  (package / '__init__.py').write_text('')
  (package / 'stage.py').write_text('WRITES = "qpos"\n')
  monkeypatch.syspath_prepend(str(tmp_path))
  monkeypatch.setattr(answer_cache, '_SOURCE_PACKAGES', ('traced_package',))
  answer_cache.code_fingerprint.cache_clear()
  try:
    before = answer_cache.question_digest('test', _KEY)
    assert answer_cache.question_digest('test', _KEY) == before
    assert answer_cache.question_digest('test', _KEY[:-1]) != before
    assert answer_cache.question_digest('other', _KEY) != before
    (package / 'stage.py').write_text('WRITES = "qvel"\n')
    answer_cache.code_fingerprint.cache_clear()
    assert answer_cache.question_digest('test', _KEY) != before
  finally:
    answer_cache.code_fingerprint.cache_clear()
    sys.modules.pop('traced_package', None)


def _swing_step_program():
  """The tests' swing environment's batched step, traced: its jaxpr's text."""
  env = conftest.make_swing_env(time_limit=0.05)
  keys = jax.random.split(jax.random.key(0), 2)
  states = jax.eval_shape(jax.vmap(env.reset), keys)
  actions = jax.ShapeDtypeStruct((2,) + env.action_spec().shape, 'float32')
  return str(jax.make_jaxpr(jax.vmap(env.step))(states, actions))


# In a fresh process whose compilation cache is $MJX_COMPOSER_CACHE_DIR:
# the analyses it computed, and `_swing_step_program()`.
_SCRIPT = """
import json

from mjx_composer.runtime import data_reads
computed = []
kept_or_computed = data_reads.PerStructure._kept_or_computed
def counted(self, key, compute):
  return kept_or_computed(
      self, key, lambda: computed.append(self._kind) or compute())
data_reads.PerStructure._kept_or_computed = counted

from tests import conftest  # configures the compilation cache, as tests do
from tests.platform import test_answer_cache
program = test_answer_cache._swing_step_program()
print(json.dumps({'computed': computed, 'step': program}))
"""


def test_a_later_process_traces_no_analysis_and_the_same_program(
    tmp_path, monkeypatch
):
  cache = tmp_path / 'cache'
  folder = cache / answer_cache.FOLDER
  monkeypatch.setattr(answer_cache, 'folder', lambda: str(folder))
  # This process's analyses, with nothing in memory, computed and kept.
  computed = []
  for module, name in (
      (reset_forward, '_WRITTEN'),
      (carried_stage, '_STAGE_IO'),
  ):
    kind = getattr(module, name)._kind  # pylint: disable=protected-access
    fresh = data_reads.PerStructure(kind)
    monkeypatch.setattr(
        module,
        name,
        lambda key, compute, fresh=fresh: fresh(
            key, lambda: computed.append(key) or compute()
        ),
    )
  program = _swing_step_program()
  assert computed and len(list(folder.glob('*.json'))) == len(computed)
  later = conftest.run_script(
      _SCRIPT,
      None,
      tmp_path,
      drop=_CACHE_VARS,
      env={'MJX_COMPOSER_CACHE_DIR': str(cache)},
  )
  assert later['computed'] == []
  assert later['step'] == program


_CACHE_VARS = (
    'MJX_COMPOSER_CACHE_DIR',
    'MJX_COMPOSER_COMPILATION_CACHE',
    'JAX_COMPILATION_CACHE_DIR',
    'JAX_ENABLE_COMPILATION_CACHE',
)


def test_a_folder_others_can_write_keeps_nothing(tmp_path):
  cache = tmp_path / 'cache'
  (cache / answer_cache.FOLDER).mkdir(parents=True, mode=0o700)
  cache.chmod(0o700)
  assert answer_cache.folder(str(cache)) == str(cache / answer_cache.FOLDER)
  (cache / answer_cache.FOLDER).chmod(0o770)
  assert answer_cache.folder(str(cache)) is None
  (cache / answer_cache.FOLDER).chmod(0o700)
  cache.chmod(0o777)
  assert answer_cache.folder(str(cache)) is None
  assert answer_cache.folder(str(tmp_path / 'missing')) is None
