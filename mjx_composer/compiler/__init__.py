"""A slice of MuJoCo's model compiler, as pure JAX functions, for variations.

We compile an MjSpec once. To vary an MJCF attribute per world and still get
the model that MuJoCo would compile from the edited spec (`MJCFVariator`),
this package maps each supported attribute onto the compiled fields it sets
and recomputes, on the device, every field that the compiler derives from
it:

* `attributes`: the catalogue, one record per supported attribute (value
  shape, spec read/write, compiled fields, device write, effects, bind-time
  refusals); `effects` names what an attribute makes the compiler
  recompute;
* `writes` and `frames`: attribute transforms: frames of attached entities
  and `MjsFrame`s (a compiled pose is `frame * local pose`), degrees to
  radians for joint ranges, `fromto`-fixed geom sizes, normalized
  quaternions;
* `geoms`: geom mass and inertia from size, density or mass
  (`mjCGeom::SetInertia`), `geom_rbound` and `geom_aabb`;
* `inertia`: the body inertial frame inferred from its geoms (total mass,
  centre of mass, principal axes by MuJoCo's own Jacobi iteration,
  `mjuu_eig3`), or an explicit inertial, with `boundmass`, `boundinertia`
  and `balanceinertia`, batched over all re-derived bodies;
  `body_subtreemass`;
* `set_const`: `mj_setConst` at qpos0, with MJX's kinematics;
* `structure`: what cannot be made equal is refused when binding (or, when
  it depends on the composed model, when reset is traced), with a message:
  attributes that change the structure MJX fixes at `put_model` time,
  meshes and height fields, and attributes the compiler overrides;
* `planner`: `ModelCompiler`, which decides statically from the bound
  attributes which of these run, and returns only fields that can change
  (so only they become per-world); `context` holds what it reads (the
  compiled host model and spec handles) and what one call writes;
* `options`: MJX's static rules for `MjSpec.option` (fluid forces).

The derivations follow MuJoCo's `user_objects.cc` (`mjCGeom::Compile`,
`mjCBody::Compile`, `InertiaFromGeom`), `user_util.cc` (`mjuu_eig3`) and
`engine_setconst.c`, and are checked field by field against the compiler in
`tests/compiler/test_compiler.py`, which is the reference when the two
disagree (e.g. the dampratio formula differs from newer sources).

Float32 on the device against the compiler's float64 agrees to about 1e-6
relative. Where the answer is not unique the result may differ in a way that
is physically the same: the sign of a quaternion, or the principal axes of an
inertia with (nearly) equal principal moments.
"""

from mjx_composer.compiler import attributes
from mjx_composer.compiler import effects
from mjx_composer.compiler import inertia
from mjx_composer.compiler import options
from mjx_composer.compiler import planner
from mjx_composer.compiler import set_const
from mjx_composer.compiler import structure
from mjx_composer.compiler.attributes import CATALOGUE
from mjx_composer.compiler.attributes import Attribute
from mjx_composer.compiler.attributes import check_attribute
from mjx_composer.compiler.attributes import kind_of
from mjx_composer.compiler.attributes import set_spec_value
from mjx_composer.compiler.attributes import spec_value
from mjx_composer.compiler.attributes import supported_text
from mjx_composer.compiler.effects import Effect
from mjx_composer.compiler.inertia import eig3
from mjx_composer.compiler.planner import ModelCompiler

__all__ = [
    'Attribute',
    'CATALOGUE',
    'Effect',
    'ModelCompiler',
    'attributes',
    'check_attribute',
    'effects',
    'eig3',
    'inertia',
    'kind_of',
    'options',
    'planner',
    'set_const',
    'set_spec_value',
    'spec_value',
    'structure',
    'supported_text',
]
