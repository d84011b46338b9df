"""The base class of a swarm behaviour: parameters, messages, a rate and one step.

A behaviour is a class. The UAV process makes one instance of it per UAV, with the scenario's
``mission.params`` validated into its :attr:`Behaviour.Params`, calls :meth:`Behaviour.setup`
once the mission starts, then :meth:`Behaviour.step` at :attr:`Behaviour.rate_hz` with a fresh
:class:`~uav_stack.sdk.context.Context`. The step returns an intent
(:mod:`uav_stack.sdk.intents`) or None to keep flying the last one.

The step runs in the UAV process's control loop: it must return within its time budget
(``mission.budget_ms`` of CPU time, 20 ms by default). An exception or an overrun is counted; several in a
row and the UAV holds its position, then lands, and the run's summary lists an incident
(:mod:`uav_stack.sdk.adapter`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar, Generic, TypeVar

import msgspec

if TYPE_CHECKING:
    from uav_stack.sdk.context import Context
    from uav_stack.sdk.intents import Intent


class NoParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The parameters of a behaviour that takes none."""


P = TypeVar("P", bound=msgspec.Struct)


class Behaviour(Generic[P]):
    """Subclass it, set the class attributes you need, write :meth:`step`.

    Class attributes:

    - ``Params``: a ``msgspec.Struct`` (frozen, ``forbid_unknown_fields=True`` recommended) the
      scenario's ``mission.params`` are validated into; a bad value is an error naming the field
      (``mission.params.speed: ...``) when the scenario is loaded, before any UAV starts.
    - ``messages``: topic -> ``msgspec.Struct`` type of what the behaviour sends and receives on
      that topic (``"flock/heading"``: up to 64 characters of ``[A-Za-z0-9_-]`` separated by
      ``/``). A message that does not decode into its type is rejected and counted per topic.
    - ``max_message_bytes``: the largest encoded message (bytes), at most the swarm's limit (64 KiB).
    - ``rate_hz``: how often :meth:`step` runs (Hz); at most the agent's control rate (10 Hz by
      default), where the agent flies the last intent between two steps.
    - ``avoidance``: False opts out of collision avoidance and no-fly zones (the intent is
      flown as it is). Leave it True unless the behaviour keeps its own separation.
    """

    Params: ClassVar[type[msgspec.Struct]] = NoParams
    messages: ClassVar[dict[str, type[msgspec.Struct]]] = {}
    max_message_bytes: ClassVar[int] = 4096
    rate_hz: ClassVar[float] = 10.0
    avoidance: ClassVar[bool] = True

    def __init__(self, params: P) -> None:
        self.params: P = params

    def setup(self, ctx: Context) -> None:
        """Called once, at the first step of the mission (the UAV is airborne at its altitude)."""

    def step(self, ctx: Context) -> Intent | None:
        """One decision: what to fly until the next step (None: keep the last intent; at first, hover)."""
        raise NotImplementedError

    @property
    def done(self) -> bool:
        """True once the behaviour has finished: the UAV hovers (or lands, ``mission.land_when_done``)."""
        return False

    @property
    def status(self) -> str:
        """A short word for the UAV's state detail, as ground stations show it (default: the class name)."""
        return type(self).__name__
