"""Observations: observables, the pure batched updater, groups, flattening."""

from mjx_composer.observation import contact_sensor
from mjx_composer.observation import contacts
from mjx_composer.observation import observable
from mjx_composer.observation.contact_sensor import ContactSensor
from mjx_composer.observation.flatten import Flattener
from mjx_composer.observation.flatten import flatten_spec
from mjx_composer.observation.groups import ObservationGroup
from mjx_composer.observation.observable import FreePropObservableMixin
from mjx_composer.observation.observable import Observables
from mjx_composer.observation.updater import DEFAULT_BUFFER_SIZE
from mjx_composer.observation.updater import DEFAULT_DELAY
from mjx_composer.observation.updater import DEFAULT_UPDATE_INTERVAL
from mjx_composer.observation.updater import ObservationPadding
from mjx_composer.observation.updater import Updater
from mjx_composer.observation.updater import UpdaterState
