"""Adapters from a composed `Environment` to other training frameworks.

* `mjx_composer.adapters.brax`: a Brax `Env` for `brax.training` agents
  (needs the optional `brax` extra: `pip install mjx-composer[brax]`).

Adapters are imported by their module path, so that importing
`mjx_composer` never imports an optional framework.
"""
