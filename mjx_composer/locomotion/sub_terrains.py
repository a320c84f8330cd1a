"""Kept for this release: `mjx_composer.locomotion.terrain.sub_terrains`.

The sub-terrains moved into the terrain package; import them from there.
"""

import warnings

from mjx_composer.locomotion.terrain.sub_terrains import *  # pylint: disable=wildcard-import,unused-wildcard-import

warnings.warn(
    'mjx_composer.locomotion.sub_terrains moved to '
    'mjx_composer.locomotion.terrain.sub_terrains; import it from there.',
    DeprecationWarning,
    stacklevel=2,
)
