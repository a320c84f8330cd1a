"""Bundled initializers (composer's `composer.initializers`)."""

from mjx_composer.initializers.prop_initializer import PropPlacer
from mjx_composer.initializers.tcp_initializer import ToolCenterPointInitializer
