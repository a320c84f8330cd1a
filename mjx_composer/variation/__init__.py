"""Variations: pure, key-driven randomization of values (composer's `variation`).

    from mjx_composer import variation
    from mjx_composer.variation import distributions

    mass = variation.evaluate(
        distributions.Uniform(0.8, 1.2) * 2.0, initial_value=jnp.ones(3),
        key=jax.random.key(0))

Everything here is a pure function of a JAX PRNG key and can be jitted and
vmapped over worlds. `base` documents the calling convention, how keys are
split, and the explicit state protocol of stateful variations
(`initial_state` / `sample`) that variators and observables build on.

`MJCFVariator` and `PhysicsVariator` bind variations to model attributes and
sample them per world, at reset or on a `Schedule` (see `variator_base`).
"""

from mjx_composer.variation import base
from mjx_composer.variation import colors
from mjx_composer.variation import deterministic
from mjx_composer.variation import distributions
from mjx_composer.variation import math
from mjx_composer.variation import noises
from mjx_composer.variation import rotations
from mjx_composer.variation import variation_broadcaster
from mjx_composer.variation import variation_values
from mjx_composer.variation.base import Variation
from mjx_composer.variation.bounds import static_bounds
from mjx_composer.variation.rounds import evaluation_round
from mjx_composer.variation.structures import evaluate
from mjx_composer.variation.structures import initial_state
from mjx_composer.variation.structures import sample

from mjx_composer.variation.mjcf_variator import MJCFVariator
from mjx_composer.variation.physics_variator import PhysicsVariator
from mjx_composer.variation.variator_base import Schedule
