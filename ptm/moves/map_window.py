"""The window reallocation steered by the map of the sets left behind (beyond the paper; docs/model.md §3.4,
"The map-steered window").

The map is that of T0 + the window's detections each alone (the window dead-reckoned from the detection before
it), the same from T and from T', so the Hastings ratio stays a replay of T's allocation. Each member's option
of joining a set is raised by ``trust`` times its estimated change of the global terms under that map,
conditioned on the joins made so far in the window (the screen's ``conditioned_map``: the tie's Occam factor
and misfit, and the landmark-density penalty it gives back); a new set by nothing. q then follows the window's
conditional given the rest, and a retraced corridor closes in one move with no appearance at all, where each
single closure is worse than none (the first one bends the map against the others).

    >>> move = MapWindowReallocation(screen=None, window=4)        # a screen: ptm.Posterior.screen()
    >>> move.window, move.trust
    (4, 1.0)
"""

from __future__ import annotations

import numpy as np

from .._validation import share
from ..partitions import Partition
from .window import WindowReallocation

__all__ = ["MapWindowReallocation"]


class MapWindowReallocation(WindowReallocation):
    """:class:`ptm.moves.WindowReallocation` steered by the map of the sets left behind.

    ``screen``: the posterior's screen (:meth:`ptm.Posterior.screen`), whose ``conditioned_map(partition)``
    scores joins under the map of ``partition`` and conditions it on each join made.
    """

    name = "map_window_reallocation"

    def __init__(self, screen, window: int = 8, trust: float = 1.0):
        super().__init__(window)
        self.screen, self.trust = screen, share("trust", trust)

    def _steer(self, left_behind, window):
        open_window = Partition(tuple(sorted(left_behind + tuple((detection,) for detection in window))))
        return _MapSteering(self.screen.conditioned_map(open_window), self.trust)


class _MapSteering:
    """The steering of one :class:`MapWindowReallocation` allocation: weights from a conditioned map, which
    each join then conditions."""

    def __init__(self, conditioned, trust: float):
        self.conditioned, self.trust = conditioned, trust

    def weights(self, detection: int, sets) -> np.ndarray:
        return self.trust * self.conditioned.join_changes(detection, sets)

    def joined(self, detection: int, set_index: int) -> None:
        self.conditioned.tie(detection, set_index)
