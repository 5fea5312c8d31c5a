"""``ptm-bench export``: a topology's optimised map as g2o, TUM trajectories and GraphML (:mod:`ptm.export`).

The topology is the MAP of a saved PTM (``--ptm``, a file of ``PTM.save``),
or given as labels (``--labels``: "0,1,0,2", a file of integers, or "truth"
for the dataset's own labels). Its map is the Laplace mode of the pose graph
(docs/model.md §3.3) under the odometry model that a sweep's cells use, made by the
same builder (:func:`ptm_bench.evaluation.models.build_models`) from the harness's
defaults (:data:`ptm_bench.evaluation.settings.DEFAULTS`) and the dataset's sensor
specification: by default the map a sweep scored, with the tie sigma_topology = the
detector's radius / sqrt 2. ``--sigma-xy``, ``--sigma-theta`` and ``--sigma-topology``
override the defaults, as a config's ``[odometry]`` may (a sweep records the values
it used in cells.csv). The export has no held-out runs: the landmark-density penalty,
which the map does not depend on, is off, and the command prints every parameter
it used with its source. Writes map.g2o, map.tum, dead_reckoning.tum, reference.tum
(when the dataset has true poses) and topology.graphml into ``--out``, each file
atomically.

    $ ptm-bench import-carmen intel --out intel.npz
    $ ptm-bench export intel.npz --labels truth --out intel_map
    $ evo_ape tum intel_map/reference.tum intel_map/map.tum --align
    $ ptm-bench export run.npz --ptm result.npz --sigma-topology 3 --out run_map
"""

from __future__ import annotations

import time
from pathlib import Path

import ptm
from ptm.export import export_map
from ptm_bench.cli.options import output_folder, print_parameters
from ptm_bench.evaluation.models import Models, build_models
from ptm_bench.evaluation.settings import DEFAULTS, OdometrySettings, Variant

#: The harness's defaults of the parameters that shape the map.
DEFAULT_ODOMETRY = DEFAULTS["odometry"]


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "export",
        help="a topology's optimised map as g2o, TUM trajectories (for evo) and GraphML (needs networkx)",
        description="Write the optimised map of a topology of a dataset (the mode of its pose graph, "
                    "docs/model.md section 3.3) as map.g2o, map.tum, dead_reckoning.tum, reference.tum (with true "
                    "poses) and topology.graphml. The TUM timestamps are the dataset's detection times when it "
                    "has them (meta['timestamps'], as import-carmen records), else the detection index.",
    )
    parser.add_argument("dataset", type=Path,
                        help="a dataset .npz (ptm.Dataset.save, ptm-bench generate or import-carmen)")
    topology = parser.add_mutually_exclusive_group(required=True)
    topology.add_argument("--ptm", type=Path, help="a saved PTM (.npz, PTM.save): its MAP topology is exported")
    topology.add_argument("--labels", help="the topology: comma-separated place labels (0,1,0,2), a file of "
                                           "integers, or 'truth' for the dataset's labels")
    parser.add_argument("--out", required=True, type=Path, help="output folder (created if needed)")
    parser.add_argument("--sigma-xy", type=float, default=DEFAULT_ODOMETRY["sigma_xy"],
                        help=f"per-step odometry sd [m] where the dataset has no odometry_cov "
                             f"(default {DEFAULT_ODOMETRY['sigma_xy']:g}, as a sweep)")
    parser.add_argument("--sigma-theta", type=float, default=DEFAULT_ODOMETRY["sigma_theta"],
                        help=f"per-step heading sd [rad] where the dataset has no odometry_cov "
                             f"(default {DEFAULT_ODOMETRY['sigma_theta']:g}, as a sweep)")
    parser.add_argument("--sigma-topology", type=float, default=DEFAULT_ODOMETRY["sigma_topology"],
                        help="sd [m] of the tie between detections of one place (default, as a sweep: the "
                             "detector's radius in the dataset's meta / sqrt 2)")
    parser.set_defaults(handler=_run_export)


def _run_export(args) -> int:
    started = time.perf_counter()
    dataset = ptm.Dataset.load(args.dataset)
    labels, source = _topology(args, dataset)
    built = map_models(dataset, sigma_xy=args.sigma_xy, sigma_theta=args.sigma_theta,
                       sigma_topology=args.sigma_topology)
    model = built.models[0]
    written = export_map(output_folder(args.out, "--out"), dataset, labels, model)
    places = len(set(ptm.canonical(labels)))
    print(f"exported {source}: N = {dataset.n} detections, {places} places, {written.loop_closures} same-place "
          f"edges (sigma_topology {model.sigma_topology:g} m); TUM timestamps: {written.timestamps}; "
          f"{time.perf_counter() - started:.2f} s")
    print("the map's odometry model:")
    print_parameters(built.used)
    for path in written.files.values():
        print(f"  {path}")
    return 0


def map_models(dataset: ptm.Dataset, **odometry) -> Models:
    """The models of the map of ``dataset``: :func:`ptm_bench.evaluation.models.build_models` of the odometry
    model alone at the harness's defaults, ``odometry`` (keys of ``[odometry]``) overriding them, without held-out
    runs (the first model is the :class:`ptm.OdometryModel` whose mode is the map)."""
    settings = OdometrySettings(**{**DEFAULT_ODOMETRY, **odometry})
    return build_models(Variant("export", models=("odometry",), odometry=settings), dataset, held_out=None)


def _topology(args, dataset) -> tuple[list[int], str]:
    """The labels to export and a description of where they came from."""
    if args.ptm is not None:
        result = ptm.PTM.load(args.ptm)
        if result.n != dataset.n:
            raise ValueError(f"--ptm {args.ptm} is over {result.n} detections, the dataset {args.dataset} has "
                             f"{dataset.n}")
        return list(result.map()), f"the MAP topology of {args.ptm} (p = {result.probability(result.map()):.3f})"
    if args.labels == "truth":
        if dataset.labels is None:
            raise ValueError(f"--labels truth: the dataset {args.dataset} has no labels")
        return dataset.labels.tolist(), "the dataset's true topology"
    path = Path(args.labels)
    in_file = path.is_file()
    cells = (path.read_text() if in_file else args.labels).replace(",", " ").split()
    try:
        labels = [int(cell) for cell in cells]
    except ValueError:
        raise ValueError(f"--labels: expected integers separated by commas or spaces (or a file of them, or "
                         f"'truth'), got {args.labels!r}") from None
    return labels, f"the topology in {path}" if in_file else "the given topology"
