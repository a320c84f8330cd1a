"""mjx_composer: dm_control composer's authoring model on MJX.

`import mjx_composer as composer` gives composer's public names: build
entities on MjSpec, compose them under a task, and get pure, batched
`reset(key)` / `step(state, action)` functions from `Environment`.
"""

from mjx_composer.arena import Arena
from mjx_composer.constants import SENSOR_SITES_GROUP
from mjx_composer.define import cached_property
from mjx_composer.define import observable
from mjx_composer.entity import Entity
from mjx_composer.entity import ModelWrapperEntity
from mjx_composer.environment import EpisodeInitializationError
from mjx_composer.environment import Environment
from mjx_composer.environment import HOOK_NAMES
from mjx_composer.environment import State
from mjx_composer.environment import StepType
from mjx_composer.host_environment import HostEnvironment
from mjx_composer.initializer import Initializer
from mjx_composer import initializers
from mjx_composer import observation
from mjx_composer.observation import FreePropObservableMixin
from mjx_composer.observation import ObservationGroup
from mjx_composer.observation import ObservationPadding
from mjx_composer.observation import Observables
from mjx_composer.physics import Physics
from mjx_composer.robot import Robot
from mjx_composer.task import NullTask
from mjx_composer.task import Task

__version__ = '0.1.0'
