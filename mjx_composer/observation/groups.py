"""Observation groups: named selections of observables, e.g. actor and critic.

composer returns one dict of observations. Asymmetric actor-critic training
wants two views of the same step: the policy sees (corrupted) sensor values,
the critic sees clean, possibly privileged ones. A group is a selection of
observable keys plus whether the group sees corrupted or clean values:

    groups = {
        'policy': ObservationGroup(keys=['arm/joint_pos', 'arm/touch']),
        'critic': ObservationGroup(keys=['arm/joint_pos', 'box/position'],
                                   corrupted=False),
    }
    updater = Updater(observables, n, groups=groups)
    updater.get_observation(state)   # {'policy': {...}, 'critic': {...}}

An observable is evaluated once per sample whatever the groups; its clean
value is buffered next to the corrupted one only when it has a corruptor and
some group asks for clean values. Observables that no group selects are not
evaluated at all. With `flatten=True` a group's observation is one float
vector (see `flatten.Flattener`), e.g. Brax's `{'state': ...,
'privileged_state': ...}` layout.
"""

import dataclasses
from typing import Optional, Sequence


@dataclasses.dataclass(frozen=True)
class ObservationGroup:
  """A named view of the observations.

  Attributes:
    keys: the observable keys in this group, in output order; `None` means
      every enabled observable, in the updater's order.
    corrupted: whether values pass through each observable's corruptor
      (True) or are the clean raw values (False). Buffering, delays and
      aggregation apply either way.
    flatten: return one float32 vector of shape (D,) instead of a dict.
  """

  keys: Optional[Sequence[str]] = None
  corrupted: bool = True
  flatten: bool = False

  def __post_init__(self):
    if isinstance(self.keys, (str, bytes)):
      raise TypeError(
          f'ObservationGroup: `keys` must be a sequence of observable keys, '
          f'got the string {self.keys!r}, which would read as the keys '
          f'{list(self.keys)!r}. Pass keys=[{self.keys!r}] for one key.'
      )
