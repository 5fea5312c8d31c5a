"""``ptm-bench generate``: simulate one run and write its dataset file (docs/model.md §5, §2.2).

    $ ptm-bench generate --world office --aliasing 0.2 --noise 1 --seed 0 --out office.npz
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ptm_bench.cli.options import dataset_output
from ptm_bench.simulation.generate import generate_dataset


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "generate",
        help="simulate one run and write its dataset file",
        description="Drive the robot through a world and write a ptm.Dataset .npz file (atomically).",
    )
    parser.add_argument("--world", required=True, help="a preset name (see `ptm-bench worlds`) or a floor .toml file")
    parser.add_argument("--aliasing", type=float, required=True, help="aliasing level in [0, 1]")
    parser.add_argument("--noise", type=float, required=True, help="odometry noise level >= 0 (1 = defaults)")
    parser.add_argument("--seed", type=int, required=True, help="root random seed (>= 0)")
    parser.add_argument("--out", required=True, type=Path, help="output .npz path")
    parser.add_argument("--no-images", action="store_true", help="do not store the panoramas (signatures are kept)")
    parser.add_argument("--miss-rate", type=float, default=0.0, help="probability that a visit is not detected")
    parser.add_argument("--false-rate", type=float, default=0.0, help="false detections per metre driven")
    parser.set_defaults(handler=_run_generate)


def _run_generate(args) -> int:
    out = dataset_output(args.out)
    started = time.perf_counter()
    dataset = generate_dataset(args.world, args.aliasing, args.noise, args.seed, images=not args.no_images,
                               progress=sys.stderr.isatty(), miss_rate=args.miss_rate, false_rate=args.false_rate)
    try:
        dataset.save(out)
    except OSError as error:
        raise ValueError(f"out: cannot write {out}: {error}") from None
    meta = dataset.meta
    false = len(meta["detector"]["false_detections"])
    print(
        f"wrote {out}: {meta['world']}, {dataset.n} detections of {len(set(dataset.labels.tolist())) - false} places"
        f"{f' + {false} false' if false else ''} ({meta['n_palettes']} palettes), "
        f"aliasing {meta['aliasing']:g}, noise {meta['noise']:g}, "
        f"seed {meta['seed']}, route {meta['route_length']:.0f} m, {time.perf_counter() - started:.1f} s"
    )
    return 0
