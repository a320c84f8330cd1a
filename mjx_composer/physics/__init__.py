"""`Physics`: one world as hooks read and write it, and what bindings read.

`physics.Physics` (the world: its model, data and state, with
dm_control-style access) and the per-world fields that the runtime carries
(`WorldFields`, `PhysicsCarry`) are in `world`; what `physics.bind(...)` and
`physics.named` read and write in `bindings`.
"""

from mjx_composer.physics import bindings
from mjx_composer.physics.world import Binding
from mjx_composer.physics.world import changed_model_fields
from mjx_composer.physics.world import EmptyBinding
from mjx_composer.physics.world import FLAT_MATRIX_FIELDS
from mjx_composer.physics.world import ON_DEMAND_FIELDS
from mjx_composer.physics.world import Physics
from mjx_composer.physics.world import PhysicsCarry
from mjx_composer.physics.world import ReadOnlyPhysicsError
from mjx_composer.physics.world import StaleReadError
from mjx_composer.physics.world import STATE_INPUT_FIELDS
from mjx_composer.physics.world import WorldFields
