"""Evaluation of nested structures of variations.

Kept as a module so that code written against composer's
`variation.variation_values.evaluate` ports unchanged; the implementation
lives in `base` (see its docstring for the key and state protocols).
"""

from mjx_composer.variation.structures import evaluate
from mjx_composer.variation.structures import initial_state
from mjx_composer.variation.structures import sample

__all__ = ["evaluate", "initial_state", "sample"]
