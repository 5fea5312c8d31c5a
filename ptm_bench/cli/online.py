"""``ptm-bench online``: replay a dataset through the online mapper, one detection at a time.

The mapper's models are the harness's defaults (:data:`ptm_bench.evaluation.settings.DEFAULTS`), built by the
builder a sweep's cells use and calibrated on labelled held-out datasets (``--calibration``, never the replayed
one nor a copy of it, compared by content: :mod:`ptm_bench.evaluation.held_out`), as a sweep calibrates them
(:mod:`ptm_bench.evaluation.online`). It prints the latency of each update every ``--every`` detections, then the
latency summary, the most probable topologies and, where the dataset has labels, the final MAP's adjusted Rand
index and the ground truth's mass; ``--ptm-out`` keeps the final PTM (for ``ptm-bench export --ptm``).

    $ ptm-bench import-carmen intel --out intel.npz      # and aces, fhw, acapulco likewise
    $ ptm-bench online intel.npz --calibration aces.npz fhw.npz acapulco.npz --ptm-out intel_ptm.npz
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import ptm
from ptm_bench.cli.options import positive_int, print_parameters
from ptm_bench.evaluation.held_out import refuse_scored_run
from ptm_bench.evaluation.online import calibrated_mapper, collapse_warning, replay
from ptm_bench.evaluation.scoring import adjusted_rand_index
from ptm_bench.evaluation.settings import MODEL_NAMES, Variant


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "online",
        help="replay a dataset through the online mapper (one detection at a time), with its latency per update",
        description="Feed a dataset's detections one at a time to ptm.OnlineMapper (sequential Monte Carlo, "
                    "docs/model.md §3.8), its parameters calibrated on labelled held-out datasets.",
    )
    parser.add_argument("dataset", type=Path, help="a ptm.Dataset .npz (ptm-bench generate / import-carmen)")
    parser.add_argument("--calibration", type=Path, nargs="+", required=True, metavar="DATASET",
                        help="labelled held-out datasets to calibrate on (not the replayed one, nor a copy of it)")
    parser.add_argument("--models", nargs="+", choices=MODEL_NAMES, default=list(MODEL_NAMES),
                        help="likelihood models (default: both)")
    parser.add_argument("--particles", type=positive_int, default=128, help="particles of the mapper (default 128)")
    parser.add_argument("--seed", type=int, default=0, help="the mapper's seed (default 0)")
    parser.add_argument("--every", type=positive_int, default=10, help="print a line every this many detections")
    parser.add_argument("--ptm-out", type=Path, help="write the final PTM to this .npz file")
    parser.set_defaults(handler=_run_online)


def _run_online(args) -> int:
    dataset = ptm.Dataset.load(args.dataset)
    held_out = [ptm.Dataset.load(path) for path in args.calibration]
    refuse_scored_run(dataset, f"the replayed dataset {args.dataset}", dict(zip(map(str, args.calibration), held_out)))
    if args.ptm_out is not None and args.ptm_out.suffix != ".npz":
        raise ValueError(f"--ptm-out: PTM files end in .npz, got {args.ptm_out.name!r}")
    mapper, used = calibrated_mapper(dataset, held_out, Variant("online", models=tuple(args.models)),
                                     particles=args.particles, seed=args.seed)
    print(f"{args.dataset.name}: N = {dataset.n} detections, models {' + '.join(args.models)}, "
          f"{args.particles} particles, calibrated on {len(held_out)} held-out run(s)")
    print_parameters(used)

    def report(n: int, result: ptm.PTM) -> None:
        if n % args.every == 0 or n == dataset.n:
            latency = result.diagnostics["latency_s"][-1]
            map_probability = result.top(1)[0][1]
            print(f"  n = {n:4d}: update {latency:6.2f} s, ESS {result.diagnostics['ess'][-1]:6.1f}, "
                  f"MAP {len(set(result.map()))} places, P(MAP) {map_probability:.3f}", flush=True)

    result = replay(dataset, mapper, report)
    latency = np.array(result.diagnostics["latency_s"])
    print(f"latency per update: median {np.median(latency):.2f} s, 90th percentile {np.quantile(latency, 0.9):.2f} s, "
          f"largest {latency.max():.2f} s; {result.diagnostics['resamplings']} resamplings")
    warning = collapse_warning(result)
    if warning is not None:
        print(f"warning: {warning}")
    for rank, (labels, probability) in enumerate(result.top(3), start=1):
        print(f"  top {rank}: P = {probability:.3f}, {len(set(labels))} places")
    if dataset.labels is not None:
        truth = ptm.canonical(dataset.labels)
        print(f"final MAP: ARI {adjusted_rand_index(result.map(), dataset.labels):.3f} against the labels; "
              f"ground truth's mass {result.probability(truth):.3f}")
    if args.ptm_out is not None:
        print(f"wrote {result.save(args.ptm_out)}")
    return 0
