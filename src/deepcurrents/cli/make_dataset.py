"""``deepcurrents-make-dataset`` (``python -m deepcurrents.cli.make_dataset``; ``make data``): writes the
human-part datasets ``<out>/<source>/<category>/NNN.ply`` from Anny bodies or FAUST (deepcurrents.data.human_parts)."""

from __future__ import annotations

import argparse
import logging
import os
from collections.abc import Sequence
from pathlib import Path

from deepcurrents.data.human_parts import (
    BORDERS,
    CATEGORIES,
    DatasetError,
    anny_parts,
    faust_parts,
    write_parts,
)
from deepcurrents.errors import UserInputError

log = logging.getLogger("deepcurrents.make_dataset")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Human-part datasets for reconstruction and families (paper §5.2).")
    parser.add_argument("--source", choices=("anny", "faust"), default="anny")
    parser.add_argument("--out", default="data", help="root folder; parts go to OUT/SOURCE/CATEGORY/NNN.ply")
    parser.add_argument("--num", type=int, default=100, help="Anny: number of bodies")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--faust-root", default=None, help="FAUST: the segmentation benchmark's root folder")
    parser.add_argument("--categories", nargs="*", default=list(CATEGORIES), choices=CATEGORIES)
    parser.add_argument("--border", choices=BORDERS, default="smooth",
                        help="smooth: cut along a level set of the skinning weights (FAUST: of the smoothed labels), "
                        "inside triangles; faces: along mesh edges, each face to its dominant bone (the former cut)")
    args = parser.parse_args(argv)
    if args.source == "anny" and args.num < 1:
        parser.error(f"--num={args.num} must be at least 1 (the number of bodies to generate).")
    try:  # before minutes of generating: the folder must exist and take files
        Path(args.out).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SystemExit(f"error: --out='{args.out}' cannot be created ({err.strerror or type(err).__name__}); "
                         "choose a writable folder.") from None
    if not os.access(args.out, os.W_OK | os.X_OK):
        raise SystemExit(f"error: --out='{args.out}' is not writable; choose a writable folder.")
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        if args.source == "anny":
            parts = anny_parts(args.num, args.seed, args.categories, border=args.border)
            meta = {"generator": "anny", "bodies": args.num, "seed": args.seed, "border": args.border}
        else:
            if not args.faust_root:
                raise DatasetError("--faust-root is required for --source faust.")
            parts = faust_parts(args.faust_root, args.categories, border=args.border)
            meta = {"generator": "faust", "root": str(args.faust_root), "border": args.border}
        files = write_parts(parts, Path(args.out), args.source, meta)
    except UserInputError as err:
        raise SystemExit(f"error: {err}") from None
    for name, (p, f, s) in parts.items():
        log.info("%s: %d meshes, %d faces each, scale %.4g", name, len(p), len(f), s)
    log.info("wrote %d meshes under %s/%s", len(files), args.out, args.source)


if __name__ == "__main__":
    main()
