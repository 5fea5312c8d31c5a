"""``ptm-bench demo``: the README's main job on an embedded default.

A small synthetic run (nine detections of five places, two of which look
alike) goes through the public API: the exact posterior and an MCMC PTM are
computed and compared, the top topologies and the ground-truth mass printed,
and the co-assignment matrix drawn to ``results/demo/``.

    $ ptm-bench demo
    $ ptm-bench demo --out /tmp/demo --seed 3
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import ptm
from ptm.dataset import atomic_write

TRUE_LABELS = (0, 1, 2, 3, 0, 4, 2, 1, 0)
# Place 4 looks like place 3 (perceptual aliasing).
PLACE_APPEARANCE = np.array([
    [0.42, 0.08, 0.05, 0.03, 0.02],
    [0.30, 0.02, 0.09, 0.01, 0.04],
    [0.25, 0.11, 0.02, 0.06, 0.01],
    [0.36, 0.05, 0.05, 0.05, 0.05],
    [0.36, 0.05, 0.05, 0.05, 0.05],
])


def synthetic_dataset(seed: int) -> ptm.Dataset:
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    labels = np.array(TRUE_LABELS)
    signatures = PLACE_APPEARANCE[labels] + rng.normal(0.0, 0.008, size=(len(labels), 5))
    return ptm.Dataset(signatures=np.abs(signatures), labels=labels, meta={"source": "ptm-bench demo", "seed": seed})


def run(args) -> int:
    dataset = synthetic_dataset(args.seed)
    model = ptm.AppearanceModel(mu=0.2, kappa=0.005, alpha=3.0, beta=2.0 * 0.008 ** 2)
    posterior = ptm.Posterior(dataset, ptm.PoissonPrior(rate=5.0), [model])
    exact = ptm.exact_posterior(posterior)
    sampled = ptm.mcmc(posterior, n_samples=20_000, burn_in=2_000, seed=args.seed, chains=4)

    truth = ptm.canonical(dataset.labels)
    print(f"{dataset.n} detections, true topology {truth} ({max(truth) + 1} places)\n")
    print("top topologies (exact)          probability   MCMC")
    for labels, probability in exact.top(5):
        marker = "  <- ground truth" if labels == truth else ""
        print(f"  {labels}  {probability:10.4f}  {sampled.probability(labels):8.4f}{marker}")
    print(f"\nground-truth mass: exact {exact.probability(truth):.4f}, MCMC {sampled.probability(truth):.4f}")
    print(f"total variation MCMC vs exact: {ptm.total_variation(sampled, exact):.4f}")
    print(f"MCMC: {sampled.diagnostics['steps']:,} steps in {sampled.diagnostics['wall_s']:.2f} s, "
          f"R-hat(log P) {sampled.diagnostics['rhat_log_prob']:.3f}")

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    figure_path = out / "coassignment.png"
    _draw_coassignment(exact.coassignment(), figure_path)
    print(f"\nwrote {figure_path}")
    return 0


def _draw_coassignment(matrix: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(4.5, 4))
    image = axes.imshow(matrix, vmin=0, vmax=1, cmap="viridis")
    axes.set_title("P(detections i and j are the same place)")
    axes.set_xlabel("detection j")
    axes.set_ylabel("detection i")
    figure.colorbar(image, ax=axes)
    figure.tight_layout()
    atomic_write(path, lambda handle: figure.savefig(handle, format="png", dpi=120))
    plt.close(figure)


def register(subparsers) -> None:
    parser = subparsers.add_parser("demo", help="the main job on an embedded default")
    parser.add_argument("--out", default="results/demo", help="folder for figures (default: results/demo)")
    parser.add_argument("--seed", type=int, default=0)
    parser.set_defaults(handler=run)
