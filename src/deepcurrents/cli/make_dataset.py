"""``deepcurrents-make-dataset`` (``python -m deepcurrents.cli.make_dataset``; ``make data``): writes the
human-part datasets ``<out>/<source>/<category>/NNN.ply`` from Anny bodies or FAUST
(``deepcurrents.data.human_parts_builder``), and with ``--whole-bodies N`` whole Anny bodies cut into 14 parts that
share their border loops, ``<out>/anny/bodies/NNN/`` (``deepcurrents.data.body_partition``)."""

from __future__ import annotations

import argparse
import logging
import os
import re
from collections.abc import Sequence
from pathlib import Path

from deepcurrents.cli.common import exit_on_user_error
from deepcurrents.data.body_partition import (
    BODY_PARTS,
    anny_body_partition,
    faust_body_partition,
    write_body,
    write_joined_families,
)
from deepcurrents.data.human_parts import CATEGORIES, DatasetError
from deepcurrents.data.human_parts_builder import BORDERS, anny_parts, faust_parts, write_parts

log = logging.getLogger("deepcurrents.make_dataset")


def check_out_dir(out: str) -> None:
    """One sentence unless ``out`` is, or can be made as, a writable folder; nothing is created here, so a run
    refused later (a bad FAUST file) leaves no empty folder behind."""
    path = Path(out).expanduser()
    existing = next((p for p in (path, *path.parents) if p.exists()), Path("."))
    if not existing.is_dir():
        raise DatasetError(f"--out='{out}' cannot be created: '{existing}' is a file, not a folder; choose a "
                           "writable folder.")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise DatasetError(f"--out='{out}' is not writable ('{existing}' does not take files); choose a "
                           "writable folder.")


def remove_stale_parts(folder: Path, count: int) -> list[Path]:
    """Deletes the part files ``NNN.ply`` numbered ``count`` or more in ``folder``, left by an earlier, larger
    generation: training picks a part by its rank among the folder's files, so a stale one would pass for a part of
    this dataset. Only names ``write_parts`` writes are touched. → the files removed."""
    numbered = {int(p.stem): p for p in folder.glob("*.ply")
                if re.fullmatch(r"[0-9]+", p.stem) and p.name == f"{int(p.stem):03d}.ply" and p.is_file()}
    stale = [numbered[i] for i in sorted(numbered) if i >= count]
    for path in stale:
        path.unlink()
    return stale


def writing_failed(out: str, what: str, err: OSError) -> DatasetError:
    """The one sentence for an ``--out`` folder that could not take the files (full disk, no permission, …)."""
    return DatasetError(f"--out='{out}': writing the {what} failed ({err.strerror or type(err).__name__}"
                        f"{': ' + str(err.filename) if err.filename else ''}).")


def write_joined(args: argparse.Namespace) -> None:
    """``--joined-parts N``: the two parts that ``--joint`` joins, of N bodies of ``--seed``, in each body's joint
    frame (``body_partition.write_joined_families``): two families that share their joint loop."""
    partition, bodies = anny_body_partition(args.joined_parts, args.seed)
    try:
        folder = write_joined_families(partition, bodies, Path(args.out).expanduser() / "anny" / "joined", args.joint,
                                       {"generator": "anny", "seed": args.seed})
    except OSError as err:
        raise writing_failed(args.out, "joined parts", err) from None
    log.info("joined parts: %d bodies' parts at %s under %s", len(bodies), args.joint, folder)


def build(args: argparse.Namespace) -> None:
    """Generates or reads the bodies, cuts their parts and writes them (a DatasetError for any bad input)."""
    check_out_dir(args.out)  # before minutes of generating
    if args.joined_parts and args.source != "anny":
        raise DatasetError(f"--joined-parts={args.joined_parts} needs --source anny: the parts are cut from Anny's "
                           "skinning.")
    if args.whole_bodies:
        write_bodies(args)
    if args.joined_parts:
        write_joined(args)
    if not args.categories:
        return
    if args.source == "anny":
        parts = anny_parts(args.num, args.seed, args.categories, border=args.border)
        meta = {"generator": "anny", "bodies": args.num, "seed": args.seed, "border": args.border}
    else:
        if not args.faust_root:
            raise DatasetError("--faust-root is required for --source faust.")
        parts = faust_parts(args.faust_root, args.categories, border=args.border)
        meta = {"generator": "faust", "root": str(args.faust_root), "border": args.border}
    try:
        files = write_parts(parts, Path(args.out).expanduser(), args.source, meta)
        for name, (p, _, _) in parts.items():
            folder = Path(args.out).expanduser() / args.source / name
            stale = remove_stale_parts(folder, len(p))
            if stale:
                names = stale[0].name if len(stale) == 1 else f"{stale[0].name} to {stale[-1].name}"
                log.info("%s: removed %d part file(s) of an earlier, larger generation (%s)", folder, len(stale), names)
    except OSError as err:
        raise writing_failed(args.out, "parts", err) from None
    for name, (p, f, s) in parts.items():
        log.info("%s: %d meshes, %d faces each, scale %.4g", name, len(p), len(f), s)
    log.info("wrote %d meshes under %s/%s", len(files), args.out, args.source)


def write_bodies(args: argparse.Namespace) -> None:
    """``--whole-bodies N``: N bodies of ``--seed`` (random phenotypes and mild poses, as for the parts), each
    partitioned."""
    if args.source == "faust":
        if not args.faust_root:
            raise DatasetError("--faust-root is required for --source faust.")
        partition, bodies = faust_body_partition(args.faust_root)
        bodies = bodies[:args.whole_bodies]
        meta = {"generator": "faust", "root": str(args.faust_root)}
    else:
        partition, bodies = anny_body_partition(args.whole_bodies, args.seed)
        meta = {"generator": "anny", "seed": args.seed}
    root = Path(args.out).expanduser() / args.source / "bodies"
    try:
        for i, body in enumerate(bodies):
            write_body(partition, body, root / f"{i:03d}", {**meta, "index": i})
    except OSError as err:
        raise writing_failed(args.out, "bodies", err) from None
    log.info("bodies: %d whole bodies of %d parts and %d shared loops under %s", len(bodies), len(partition.parts),
             len(partition.loops), root)


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
    parser.add_argument("--whole-bodies", type=int, default=0,
                        help="also write this many whole bodies cut into 14 parts that share their border loops "
                        "(OUT/SOURCE/bodies/NNN/: body.ply, parts/*.ply, loops.json), for experiment=stitched_body; "
                        "Anny: cut along its skinning; FAUST: along its segmentation, the first N registrations")
    parser.add_argument("--joined-parts", type=int, default=0,
                        help="Anny: also write the two parts that --joint joins, of this many bodies, in each body's "
                        "joint frame (OUT/anny/joined/JOINT/: two families sharing the loop, and their curves)")
    limb_joints = [p.joint for p in BODY_PARTS if p.parent not in (None, "torso")]  # a parent with one other loop
    parser.add_argument("--joint", default="wrist.L", choices=limb_joints,
                        help="the loop of --joined-parts (default wrist.L: the hand and the forearm)")
    args = parser.parse_args(argv)
    if not args.categories and not args.whole_bodies and not args.joined_parts:  # nothing would be written
        parser.error(f"--categories needs at least one of {', '.join(CATEGORIES)} (or give --whole-bodies N or "
                     "--joined-parts N).")
    if args.joined_parts < 0:
        parser.error(f"--joined-parts={args.joined_parts} must be at least 0 (the number of bodies).")
    if args.whole_bodies < 0:
        parser.error(f"--whole-bodies={args.whole_bodies} must be at least 0 (the number of whole bodies to write).")
    if args.source == "anny" and args.num < 1:
        parser.error(f"--num={args.num} must be at least 1 (the number of bodies to generate).")
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    exit_on_user_error(build, args)  # bad inputs: one sentence and status 2, as argparse's own


if __name__ == "__main__":
    main()
