"""Incremental mapping (docs/model.md §3.7): grow the posterior one detection at a time.

When detection k arrives, the models are bound again on the first k
detections and the sampler continues from the previous PTM's top topologies
(``ptm.mcmc(..., start=previous_ptm)``, :mod:`ptm.starts`), each extended with the new detection,
instead of starting over. The result after adding detections one by one must
agree with sampling the full dataset from scratch and with the exact posterior.

    previous = ptm.mcmc(posterior_of(dataset.head(k - 1)), 4_000, seed=k - 1)
    current = ptm.mcmc(posterior_of(dataset.head(k)), 4_000, seed=k, start=previous)
"""

import numpy as np
import pytest

import ptm
from test_odometry import TOLERANCE, mixed_dataset, mixed_posterior_of, mixed_target
from test_sampler import visit_frequencies  # noqa: F401 (an autouse fixture)

FIRST, LAST = 4, 7
# Measured with 20 000 samples x 2 chains per detection (seeds 21, 31, 41): TV of the final
# incremental PTM to the exact posterior 0.012, 0.013, 0.050; incremental vs from scratch 0.028-0.040.
# The bound is the shared TOLERANCE of the sampler tests (0.06); the chains are not extended and are judged by
# their visit frequencies, as there, and every proposal is evaluated exactly: screened by the cheap terms first
# (delayed acceptance), the chains accept less often and mix more slowly at these lengths.
# The test is of the starts, not of the moves: split/merge and Gibbs reassignment alone (the default set adds the
# map-steered window, which costs a Laplace fit per step and more than doubles the test's time).
FIXED = {"max_doublings": 0, "delayed_acceptance": False,
         "moves": [(ptm.moves.SplitMerge(), 0.5), (ptm.moves.GibbsReassign(), 0.5)]}


def grow_incrementally(dataset, samples_per_detection, seed, posterior_of=None):
    """A PTM over ``dataset``, built by adding detections FIRST+1..N one at a time.

    ``posterior_of(k)`` is the posterior of the first k detections (default: :func:`mixed_posterior_of`
    ``(dataset.head(k))``).
    """
    posterior_of = posterior_of or (lambda count: mixed_posterior_of(dataset.head(count)))
    seeds = np.random.SeedSequence(seed).spawn(dataset.n - FIRST + 1)
    current = ptm.mcmc(posterior_of(FIRST), samples_per_detection, burn_in=0, seed=seeds[0], chains=2,
                       start="dispersed", **FIXED)
    history = [current]
    for count, chain_seed in zip(range(FIRST + 1, dataset.n + 1), seeds[1:]):
        posterior = posterior_of(count)
        current = ptm.mcmc(posterior, samples_per_detection, burn_in=200, seed=chain_seed, chains=2, start=current,
                           **FIXED)
        history.append(current)
    return history


@pytest.mark.slow  # four exact enumerations with odometry, N = 4..7 (the last shared with test_odometry)
def test_adding_detections_one_by_one_agrees_with_sampling_from_scratch():
    dataset = mixed_dataset(LAST)
    full_posterior, full_exact = mixed_target(LAST)  # the same dataset and models as mixed_posterior_of(dataset)
    # Each size's chain runs on the posterior that was enumerated: its odometry memo then holds every
    # partition, which the chain reads instead of evaluating them again (the values depend on the partition alone).
    targets = {LAST: (full_posterior, full_exact)}
    for count in range(FIRST, LAST):
        posterior = mixed_posterior_of(dataset.head(count))
        targets[count] = posterior, ptm.exact_posterior(posterior)
    history = grow_incrementally(dataset, 20_000, seed=21, posterior_of=lambda count: targets[count][0])
    assert [current.n for current in history] == list(range(FIRST, LAST + 1))
    for current in history:  # every intermediate map is right, not only the last
        exact = targets[current.n][1]
        assert ptm.total_variation(current, exact) < TOLERANCE, current.n
    incremental = history[-1]
    scratch = ptm.mcmc(full_posterior, 20_000, burn_in=1_000, seed=22, chains=2, start="dispersed", **FIXED)
    assert ptm.total_variation(scratch, exact) < TOLERANCE
    assert ptm.total_variation(incremental, scratch) < TOLERANCE
