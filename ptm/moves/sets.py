"""The move sets a sampler runs (docs/model.md §3.4): which moves, with which weights, and what screens their
proposals in delayed acceptance's first stage.

* ``"default"``: the paper's split/merge and single-detection Gibbs reassignment, half and half; where the
  posterior has a screen (:meth:`ptm.Posterior.screen`, the odometry's), ``MAP_WINDOW_SHARE`` of the steps are
  the map-steered window, which closes a loop whose single closures are each worse than none. Delayed
  acceptance screens with the cheap terms alone.
* ``"paper"``: the paper's split/merge alone (an ablation).
* ``"guided"``: the data-driven moves for many detections (guided split-merge, reassignment by the current map,
  Gibbs reassignment, and the window reallocation steered by the cheap terms), delayed acceptance screened by
  the posterior's screen.
* ``"auto"``: ``"guided"`` from ``GUIDED_FROM_N`` detections on, else ``"default"``. Below it the guided moves
  mixed worst (12-detection runs with shared decors); from 25 detections on the default ones leave a chain at
  all-one-place, with odometry and with appearance alone.

A list of moves or (move, weight) pairs is run as given, screened by the cheap terms.

    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> chosen = move_set("auto", Posterior(Dataset(labels=[0] * 25), PoissonPrior(2.0)))
    >>> chosen.name, [type(move).__name__ for move, _ in chosen.moves], chosen.screen
    ('guided', ['GuidedSplitMerge', 'MapReassign', 'GibbsReassign', 'WindowReallocation'], None)
"""

from __future__ import annotations

from dataclasses import dataclass

from .gibbs import GibbsReassign
from .guided_split_merge import GuidedSplitMerge
from .map_reassign import MapReassign
from .map_window import MapWindowReallocation
from .mixture import weighted_moves
from .split_merge import SplitMerge
from .window import WindowReallocation

__all__ = ["GUIDED_FROM_N", "MAP_WINDOW_SHARE", "MOVE_SETS", "MoveSet", "checked_moves", "default_moves",
           "guided_moves", "move_set", "paper_moves"]

#: ``moves="auto"`` runs the guided moves from this many detections on, the default ones below.
GUIDED_FROM_N = 20
#: Share of the steps of :func:`default_moves` with a screen that are the map-steered window.
MAP_WINDOW_SHARE = 0.1
#: The move sets by name.
MOVE_SETS = ("auto", "default", "paper", "guided")


@dataclass(frozen=True)
class MoveSet:
    """Moves resolved for one posterior: ``name`` ("default", "paper", "guided", or "custom" for a list),
    ``moves`` ((move, weight) pairs or moves) and the ``screen`` of delayed acceptance's first stage (None: the
    cheap terms alone)."""

    name: str
    moves: tuple
    screen: object = None


def default_moves(screen=None) -> list:
    """The paper's split/merge mixed with single-detection Gibbs reassignment; with ``screen`` (the posterior's,
    :meth:`ptm.Posterior.screen`), ``MAP_WINDOW_SHARE`` of the steps are the map-steered window
    (:class:`ptm.moves.MapWindowReallocation`)."""
    if screen is None:
        return [(SplitMerge(), 0.5), (GibbsReassign(), 0.5)]
    rest = 0.5 * (1.0 - MAP_WINDOW_SHARE)
    return [(SplitMerge(), rest), (GibbsReassign(), rest), (MapWindowReallocation(screen), MAP_WINDOW_SHARE)]


def paper_moves() -> list:
    """The paper's split/merge alone (Algorithm 2)."""
    return [(SplitMerge(), 1.0)]


def guided_moves(posterior, screen) -> list:
    """Data-driven moves for many detections: the guided split-merge (anchors by the pairs' Bayes factors),
    reassignment by the current map (``screen``, the posterior's, :meth:`ptm.Posterior.screen`; None: by the cheap
    conditional), Gibbs reassignment, and the joint reallocation of a window of consecutive detections (a retraced
    corridor) steered by the cheap terms."""
    return [(GuidedSplitMerge(posterior), 0.35), (MapReassign(screen), 0.2), (GibbsReassign(), 0.35),
            (WindowReallocation(), 0.1)]


def checked_moves(moves):
    """``moves`` as a sampler keeps it: a name of :data:`MOVE_SETS`, or a tuple of moves or (move, weight) pairs
    (checked by :func:`ptm.moves.mixture.weighted_moves`); else ``ValueError`` naming ``moves``."""
    if isinstance(moves, str):
        if moves not in MOVE_SETS:
            raise ValueError(f"moves must be one of {', '.join(MOVE_SETS)} or a list of moves, got {moves!r}")
        return moves
    try:
        moves = tuple(moves)
    except TypeError:
        raise ValueError(f"moves must be one of {', '.join(MOVE_SETS)} or a list of moves, got {moves!r}") from None
    weighted_moves(moves)
    return moves


def move_set(moves, posterior) -> MoveSet:
    """The :class:`MoveSet` that ``moves`` (checked, :func:`checked_moves`) stands for on ``posterior``."""
    if not isinstance(moves, str):
        return MoveSet("custom", tuple(moves))
    name = ("guided" if posterior.n >= GUIDED_FROM_N else "default") if moves == "auto" else moves
    if name == "guided":
        screen = posterior.screen()
        return MoveSet(name, tuple(guided_moves(posterior, screen)), screen)
    if name == "paper":
        return MoveSet(name, tuple(paper_moves()))
    return MoveSet(name, tuple(default_moves(posterior.screen())))
