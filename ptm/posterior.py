"""The unnormalised posterior over topologies (paper eq. 1-2, docs/model.md §3).

    log P(T | Z) = log P(T) + sum_models log P(Z_m | T) + const

Each model is bound to the dataset once (``model.bind(dataset)``) and gives a
*term* with ``log_likelihood(partition)``. Terms that decompose over sets also
offer ``block_log_likelihood(block)``; their sum over sets plus the prior is
the *cheap* part of the posterior, memoised per set, so a split or merge
re-scores only the sets it creates. The remaining (*global*) terms, such as
the odometry likelihood, are evaluated on whole partitions. A decomposable
term may complete a global one (``completes_global_term``: the normaliser of
the odometry ties, ``ptm.TieNormaliser``); what scores the cheap terms in
place of the whole posterior reads :meth:`Posterior.standalone_block_score`,
which leaves such terms out. A term may check the others it is combined with
(``check_terms(terms)``, called once here): the odometry term with a noise-scale
prior refuses a tie normaliser it was not told of, or the lack of one.

A global term may offer a *screen* (``screen(posterior)``): a cheap prediction
of how a move changes the global terms, from the map of the current partition
(docs/model.md §3.4, "Delayed acceptance with the odometry surrogate").
:meth:`Posterior.screen` gives it to the samplers and moves, which thus never
know a particular term.

    >>> import numpy as np
    >>> from ptm import AppearanceModel, Dataset, PoissonPrior
    >>> dataset = Dataset(signatures=np.array([[0.30, 0.10], [0.40, 0.05], [0.31, 0.11], [0.41, 0.04]]))
    >>> post = Posterior(dataset, PoissonPrior(2.0), [AppearanceModel(0.3, 0.05, 3.0, 2e-4)])
    >>> round(post.log_prob([0, 1, 0, 1]), 3), round(post.log_prob([5, 2, 5, 7]), 3)   # any integer labels
    (0.829, -11.005)
"""

from __future__ import annotations

import math

import numpy as np

from ._cache import BoundedCache
from .partitions import Partition

__all__ = ["Posterior"]


class Posterior:
    """log P(T | Z) up to a constant, for one dataset, prior and list of models.

    Parameters
    ----------
    dataset : ptm.Dataset
    prior : object with ``log_prob(n, m)`` (e.g. :class:`ptm.PoissonPrior`)
        Read through its ``table(n)`` (entry m: ``log_prob(n, m)``) when it has one.
    models : iterable of models (with ``bind(dataset)``) or of already bound terms
    block_cache_size : int
        Bound on the memo of per-set scores.
    """

    def __init__(self, dataset, prior, models=(), block_cache_size: int = 500_000):
        self.dataset = dataset
        self.n = dataset.n
        self.prior = prior
        self.terms = [model.bind(dataset) if hasattr(model, "bind") else model for model in models]
        for term in self.terms:
            if not hasattr(term, "log_likelihood"):
                raise ValueError(f"{term!r} has no log_likelihood(partition) method")
        for term in self.terms:
            if hasattr(term, "check_terms"):  # a term may refuse the terms it is combined with
                term.check_terms(self.terms)
        self.block_terms = [term for term in self.terms if hasattr(term, "block_log_likelihood")]
        self.global_terms = [term for term in self.terms if not hasattr(term, "block_log_likelihood")]
        self.completing_terms = [term for term in self.block_terms if getattr(term, "completes_global_term", False)]
        by_size = prior.table(self.n) if hasattr(prior, "table") else [-math.inf] + [
            prior.log_prob(self.n, m) for m in range(1, self.n + 1)]
        self.log_prior_by_size = [-math.inf] + [_checked(value, "prior") for value in by_size[1:]]
        self._block_cache = BoundedCache(block_cache_size)
        self._screen = _UNBUILT

    # -- the pieces the samplers use ------------------------------------------------------------

    def block_score(self, block) -> float:
        """Sum of the decomposable terms for one set (a sorted tuple of detections), memoised."""
        block = tuple(block)
        score = self._block_cache.get(block)
        if score is None:
            score = 0.0
            for term in self.block_terms:
                score += _checked(term.block_log_likelihood(block), term)
            self._block_cache.put(block, score)
        return score

    def standalone_block_score(self, block) -> float:
        """:meth:`block_score` less the terms that complete a global term (``completes_global_term``): the
        decomposable terms that mean something without the global ones, for a score that stands in for the
        whole posterior (where a chain start places new detections by the cheap terms, :mod:`ptm.starts`). Equal
        to :meth:`block_score` when there are none."""
        score = self.block_score(block)
        for term in self.completing_terms:
            score -= _checked(term.block_log_likelihood(tuple(block)), term)
        return score

    def cheap_log_prob(self, partition: Partition) -> float:
        """log P(T) plus the decomposable terms."""
        return self.log_prior_by_size[partition.m] + sum(self.block_score(block) for block in partition.blocks)

    def global_log_prob(self, partition: Partition) -> float:
        """Sum of the terms that do not decompose over sets (0 when there are none)."""
        total = 0.0
        for term in self.global_terms:
            total += _checked(term.log_likelihood(partition), term)
        return total

    def global_log_prob_upper_bound(self) -> np.ndarray | None:
        """Upper bounds on :meth:`global_log_prob` over the partitions of m places, indexed by m = 0 .. N, or None
        if a global term offers none (``log_likelihood_upper_bound(num_places)``)."""
        if not all(hasattr(term, "log_likelihood_upper_bound") for term in self.global_terms):
            return None
        return np.array([sum(_checked(term.log_likelihood_upper_bound(m), term) for term in self.global_terms)
                         for m in range(self.n + 1)])

    @property
    def has_global_terms(self) -> bool:
        return bool(self.global_terms)

    def screen(self):
        """The screen of the global terms, built by the first global term that offers ``screen(posterior)``
        (the odometry term's map-based prediction), memoised; None where no term offers one.

        A screen predicts how a move changes the global terms: ``screening_change(partition, removed, added)``
        (the prediction at the screen's ``screening_trust``; optionally ``screening_change_bound``, an upper
        bound that is cheaper to find), ``predicted_change`` (the prediction itself), ``conditioned_map``,
        ``join_estimates`` and ``opened_place_change`` for the map-guided moves and the online mapper, and
        ``diagnostics()``. It only steers and screens: delayed acceptance's second stage corrects its error
        exactly (docs/model.md §3.4).
        """
        if self._screen is _UNBUILT:
            self._screen = next((term.screen(self) for term in self.global_terms if hasattr(term, "screen")), None)
        return self._screen

    # -- public ------------------------------------------------------------------------------------

    def partition(self, labels) -> Partition:
        """Canonicalise and check a label sequence against this dataset."""
        if isinstance(labels, Partition):
            partition = labels
        else:
            partition = Partition.from_labels(labels)
        if partition.n != self.n:
            raise ValueError(f"a partition of this dataset has {self.n} labels, got {partition.n}")
        return partition

    def log_prob(self, labels) -> float:
        """Unnormalised log posterior of any label sequence of length N."""
        partition = self.partition(labels)
        return self.cheap_log_prob(partition) + self.global_log_prob(partition)

    def log_likelihoods(self, labels) -> dict:
        """Each term's log-likelihood and the log prior, by name (for reports)."""
        partition = self.partition(labels)
        parts = {"prior": self.log_prior_by_size[partition.m]}
        for term in self.terms:
            parts[_name(term)] = _checked(term.log_likelihood(partition), term)
        return parts

    def diagnostics(self) -> dict:
        """Diagnostics of the terms that report them, plus the per-set memo."""
        report = {"block_cache": self._block_cache.stats()}
        for term in self.terms:
            if hasattr(term, "diagnostics"):
                report[_name(term)] = term.diagnostics()
        return report

    def __repr__(self) -> str:
        return f"Posterior(n={self.n}, prior={self.prior!r}, terms={[_name(t) for t in self.terms]})"


_UNBUILT = object()  # Posterior.screen() not asked yet


def _name(term) -> str:
    return getattr(term, "name", type(term).__name__)


def _checked(value, source) -> float:
    value = float(value)
    if math.isnan(value) or value == math.inf:
        label = source if isinstance(source, str) else _name(source)
        raise ValueError(f"the {label} term returned {value}: a log-probability must be finite or -inf")
    return value
