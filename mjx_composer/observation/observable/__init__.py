"""Observable kinds and the per-entity `Observables` collection."""

from mjx_composer.observation.observable.base import AGGREGATORS
from mjx_composer.observation.observable.base import Aggregator
from mjx_composer.observation.observable.base import Generic
from mjx_composer.observation.observable.base import MujocoFeature
from mjx_composer.observation.observable.base import Observable
from mjx_composer.observation.observable.base import OPTION_NAMES
from mjx_composer.observation.observable.collection import FreePropObservableMixin
from mjx_composer.observation.observable.collection import Observables
from mjx_composer.observation.observable.contact import ContactFeature
from mjx_composer.observation.observable.mjcf import MJCFFeature
from mjx_composer.observation.observable.camera import MJCFCamera
from mjx_composer.observation.observable.camera import MujocoCamera
