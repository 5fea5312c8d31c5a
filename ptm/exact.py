"""Exact posterior by enumerating every partition (docs/model.md §3.5).

All Bell(N) partitions are visited depth-first as restricted growth strings
(iteratively, in lexicographic order): detection i joins one of the sets
opened so far or opens a new one. The
score of the decomposable terms is carried along the enumeration — adding i
to set j changes only that set's score — and each set's score is memoised by
its bitmask, so each of the 2^N - 1 possible sets is scored once. Global
terms (odometry) are evaluated afterwards. Bell(10) = 115 975,
Bell(12) = 4 213 597; sizes above ``max_n`` are refused.

*The work, told up front.* The enumeration costs about ``SECONDS_PER_PARTITION`` a partition (without the
global terms) and N + 8 bytes of arrays a partition. Beyond ``WARN_ABOVE_N`` = 12 detections (the default
``max_n``, so only a caller who raised it), it warns (``UserWarning``) with that estimate before it starts;
beyond ``MAX_N`` = 14 (Bell(15): 3.8 hours and 32 GB) it refuses (``ValueError``) whatever ``max_n`` says.

*Bounded skipping of global terms.* When every global term offers an upper
bound B on its log-likelihood over all partitions (the odometry term's is its
all-singletons value without penalty), the partitions are visited in
decreasing cheap score c(T) (prior + appearance) and evaluated until the
remaining ones, even at the bound, could hold at most e^-SKIP_NATS of the
mass already found: log sum_{rest} exp(c(T) + B) < log Z_evaluated -
``SKIP_NATS``. The skipped partitions are left out of the PTM (probability 0
where the true value is below e^-40 relative), and the diagnostics report
how many were evaluated and the bound on the skipped mass. Since an
estimate (importance sampling) could in principle exceed the bound, any
evaluated value above B + ``BOUND_SLACK_NATS`` turns skipping off for the
rest of the enumeration. With appearance at low aliasing most partitions are
skipped; with odometry alone (a prior that depends on the number of places
only) few are.

    >>> import numpy as np
    >>> from ptm import Dataset, PoissonPrior, Posterior
    >>> prior_only = Posterior(Dataset(labels=np.zeros(4, dtype=int)), PoissonPrior(2.0))   # N <= 12
    >>> exact = exact_posterior(prior_only)
    >>> len(exact), exact.map(), round(exact.expected_num_places(), 3)                      # Bell(4) = 15
    (15, (0, 0, 0, 0), 1.871)
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from scipy.special import logsumexp

from ._validation import count, flag, instance
from .partitions import Partition, bell
from .posterior import Posterior
from .result import PTM

__all__ = ["BOUND_SLACK_NATS", "MAX_N", "SECONDS_PER_PARTITION", "SKIP_NATS", "WARN_ABOVE_N", "ExactBudgetExceeded",
           "exact_posterior"]

#: Partitions whose total mass, even at the global terms' upper bound, is below e^-SKIP_NATS of the mass
#: already evaluated are not evaluated.
SKIP_NATS = 40.0
#: An evaluated global log-likelihood this far above its bound turns skipping off (the bound was not one).
BOUND_SLACK_NATS = 1.0
#: The enumeration's cost a partition without the global terms [s]: 6-9 us measured on one core (CPython 3.12).
SECONDS_PER_PARTITION = 1e-5
#: Larger enumerations (Bell(13) = 27 644 437 partitions and up, about 5 min) warn with their estimated time and
#: memory before they start.
WARN_ABOVE_N = 12
#: Larger enumerations are refused whatever ``max_n`` says: Bell(15) partitions would take about 3.8 hours and
#: 32 GB of arrays.
MAX_N = 14


class ExactBudgetExceeded(ValueError):
    """The global terms would be evaluated on more partitions than ``max_global_evaluations`` allows."""


def exact_posterior(posterior, max_n: int = 12, skip: bool = True, max_global_evaluations: int | None = None) -> PTM:
    """Enumerate and normalise the posterior over all partitions of N detections.

    ``skip=False`` evaluates the global terms on every partition even when a bound allows skipping.
    ``max_global_evaluations``: a budget of global-term evaluations. After the first one the skip rule
    gives how many partitions may still need them; more than the budget (or reaching it) raises
    :class:`ExactBudgetExceeded` at once, so a caller can fall back to sampling without paying for it.

    N above ``WARN_ABOVE_N`` warns (``UserWarning``) with the estimated time and memory before the enumeration
    starts; N above ``MAX_N`` is refused. Arguments of the wrong type raise ``TypeError``, bad values
    ``ValueError``, naming the argument.
    """
    instance("posterior", posterior, Posterior)
    max_n = count("max_n", max_n, 1)
    skip = flag("skip", skip)
    if max_global_evaluations is not None:
        max_global_evaluations = count("max_global_evaluations", max_global_evaluations, 1)
    n = posterior.n
    if n > max_n:
        raise ValueError(f"exact enumeration of N={n} detections means {_partitions(n)} partitions; "
                         f"the limit is max_n={max_n} (raise it deliberately, or use ptm.mcmc)")
    if n > MAX_N:
        raise ValueError(f"exact enumeration of N={n} detections means {_partitions(n)} partitions, beyond "
                         f"MAX_N = {MAX_N} whatever max_n says{_cost(posterior) if n <= 30 else ''}; use ptm.mcmc")
    if n > WARN_ABOVE_N:
        warnings.warn(f"exact enumeration of N={n} detections visits {_partitions(n)} partitions{_cost(posterior)}",
                      stacklevel=2)
    total = bell(n)
    started = time.perf_counter()
    partitions = np.empty((total, n), dtype=np.int8 if n < 128 else np.int16)
    log_probs = np.empty(total)
    log_prior = posterior.log_prior_by_size
    bits = [1 << i for i in range(n)]
    mask_scores: dict[int, float] = {0: 0.0}

    def score(mask: int) -> float:
        value = mask_scores.get(mask)
        if value is None:
            value = posterior.block_score(tuple(i for i in range(n) if mask & bits[i]))
            mask_scores[mask] = value
        return value

    # Depth-first over restricted growth strings without recursion: labels[d] is the set detection d
    # is in (-1 before its first choice), running[d] the score of the sets of detections 0..d-1,
    # replaced[d] the mask detection d's choice extended (None when it opened a new set).
    labels = [-1] * n
    running = [0.0] * (n + 1)
    replaced: list[int | None] = [None] * n
    sets_before = [0] * n
    masks: list[int] = []
    leaf = 0
    detection = 0
    while detection >= 0:
        choice = labels[detection]
        if choice >= 0:  # undo the previous choice of this detection
            if replaced[detection] is None:
                masks.pop()
            else:
                masks[choice] = replaced[detection]
        choice += 1
        if choice > sets_before[detection]:  # every choice tried: back up
            labels[detection] = -1
            detection -= 1
            continue
        labels[detection] = choice
        bit = bits[detection]
        if choice < sets_before[detection]:  # join set `choice`
            old = masks[choice]
            replaced[detection] = old
            masks[choice] = old | bit
            running[detection + 1] = running[detection] - score(old) + score(old | bit)
        else:  # open a new set
            replaced[detection] = None
            masks.append(bit)
            running[detection + 1] = running[detection] + score(bit)
        if detection + 1 < n:
            detection += 1
            sets_before[detection] = len(masks)
            continue
        partitions[leaf] = labels
        log_probs[leaf] = log_prior[len(masks)] + running[n]
        leaf += 1

    diagnostics = {"partitions": total}
    if posterior.has_global_terms:
        evaluated, skipped_mass = _add_global_terms(posterior, partitions, log_probs, skip, max_global_evaluations)
        partitions, log_probs = partitions[evaluated], log_probs[evaluated]
        diagnostics.update(global_evaluations=int(evaluated.size), skipped_mass_bound=skipped_mass)
    log_normaliser = float(logsumexp(log_probs))
    if not np.isfinite(log_normaliser):
        raise ValueError("every partition has zero posterior probability")
    probabilities = np.exp(log_probs - log_normaliser)
    diagnostics.update(log_normaliser=log_normaliser, wall_s=time.perf_counter() - started)
    diagnostics.update(posterior.diagnostics())
    return PTM(partitions, probabilities, "exact", diagnostics)


def _partitions(n: int) -> str:
    """Bell(``n``) written out, or a bound where computing it would itself take long."""
    return f"{bell(n):,}" if n <= 100 else f"Bell({n}) > 10^115"


def _cost(posterior) -> str:
    """The estimated time and memory of enumerating ``posterior``'s partitions (Bell(N) x the cost of one)."""
    total = bell(posterior.n)
    seconds = total * SECONDS_PER_PARTITION
    duration = (f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min" if seconds < 7200
                else f"{seconds / 3600:.3g} h")
    rest = ", plus the global terms on each partition their bound does not skip" if posterior.has_global_terms else ""
    return f": about {duration} and {total * (posterior.n + 8) / 1e9:.3g} GB of arrays{rest}"


def _add_global_terms(posterior, partitions: np.ndarray, log_probs: np.ndarray, skip: bool,
                      budget: int | None) -> tuple[np.ndarray, float]:
    """Add the global terms to ``log_probs`` in place, best cheap score first, skipping what the bound allows.

    Returns the indices of the evaluated partitions (in enumeration order) and the bound on the skipped
    mass relative to the evaluated mass (0 when nothing was skipped).
    """
    bounds = posterior.global_log_prob_upper_bound() if skip else None
    # each partition's bound depends on its number of places; the order and the rest follow the bounded mass
    bound = np.zeros(len(log_probs)) if bounds is None else bounds[partitions.max(axis=1).astype(np.intp) + 1]
    order = np.argsort(-(log_probs + bound), kind="stable")
    # rest[k]: log of the bounded mass (cheap score + global bound) of the partitions from the k-th on
    rest = np.append(np.logaddexp.accumulate((log_probs + bound)[order][::-1])[::-1], -np.inf)
    log_evaluated = -np.inf
    count = 0
    for index in order:
        if bounds is not None and rest[count] < log_evaluated - SKIP_NATS:
            break
        value = posterior.global_log_prob(Partition.from_labels(partitions[index]))
        if bounds is not None and value > bound[index] + BOUND_SLACK_NATS:
            bounds = None  # not a bound after all: evaluate everything
        log_probs[index] += value
        log_evaluated = np.logaddexp(log_evaluated, log_probs[index])
        count += 1
        if budget is not None and (count == 1 or count >= budget):
            # the evaluations the skip rule may still need: up to the first k whose rest falls below its threshold
            needed = order.size if bounds is None else int(np.argmax(rest < log_evaluated - SKIP_NATS))
            if needed > budget:
                raise ExactBudgetExceeded(f"exact enumeration would evaluate the global terms on up to {needed:,} of "
                                          f"{order.size:,} partitions; the budget is {budget:,} "
                                          "(max_global_evaluations)")
    skipped_mass = 0.0 if count == order.size else float(np.exp(rest[count] - log_evaluated))
    return np.sort(order[:count]), skipped_mass
