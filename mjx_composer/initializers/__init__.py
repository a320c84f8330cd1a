"""Bundled initializers (composer's `composer.initializers`)."""

from mjx_composer.initializers.prop_initializer import PropPlacer
