"""`stablemo data check DIR [--dataset humanml3d|kit]`, `stablemo data synth --out DIR [--num N] [--seed S] [--rest varied|tight] [--captions plain|varied] [--path-walks SHARE]`,
`stablemo data preview OUT.png`, `stablemo data glove-words GLOVE_DIR`, `stablemo data shard SRC [SRC ...] --out DIR` (stablemo/data/shards.py) and `stablemo data import-bvh DIR --out DATASET [--texts CSV] [--map YAML]` (stablemo/data/bvh_import.py)."""

from __future__ import annotations

import argparse
import os

from stablemo.data.layout import DATASETS
from stablemo.data.synth.captions import CAPTION_MODES, DEFAULT_CAPTIONS
from stablemo.data.synth.idle import DEFAULT_REST, REST_MODES
from stablemo.errors import StableMoError


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="stablemo data", description="dataset tools")
    sub = parser.add_subparsers(dest="command", required=True)
    check = sub.add_parser("check", help="validate a dataset folder (HumanML3D layout) or a shard folder "
                                         "(`data shard`) and print a summary")
    check.add_argument("dir", help="dataset folder, or shard folder (path or URL)")
    check.add_argument("--dataset", default="humanml3d", choices=sorted(DATASETS),
                       help="feature width, length limits and fps to check against (default: humanml3d)")
    check.add_argument("--all-problems", action="store_true", help="list every problem (default: the first 30)")
    check.add_argument("--no-cache", action="store_true", help="read every file without using or writing the cache")
    synth = sub.add_parser("synth", help="write the procedural synthetic dataset in the HumanML3D layout")
    synth.add_argument("--out", required=True,
                       help="output folder: new, empty, or a dataset this command wrote (replaced whole; "
                            "refused if it holds any other file)")
    synth.add_argument("--num", type=int, default=None,
                       help="number of motions, 3 to 100000 (default: the generator's, 2000; ~210 kB each)")
    synth.add_argument("--seed", type=int, default=0, help="random seed (same seed, same dataset)")
    synth.add_argument("--rest", default=None, choices=list(REST_MODES),
                       help="idle rest around each action: " + "; ".join(f"{k}: {v}" for k, v in REST_MODES.items())
                            + f" (default: the generator's, {DEFAULT_REST})")
    synth.add_argument("--captions", default=DEFAULT_CAPTIONS, choices=list(CAPTION_MODES),
                       help="the captions' vocabulary: " + "; ".join(f"{k}: {v}" for k, v in CAPTION_MODES.items())
                            + f" (default {DEFAULT_CAPTIONS}). The motions are the same in either")
    synth.add_argument("--path-walks", type=float, default=0.0, metavar="SHARE",
                       help="share of the motions, 0 to 1, that walk forward along random curved paths in any "
                            "direction (for path-control training; default 0: none). The others are the dataset's "
                            "without them, file for file")
    imp = sub.add_parser("import-bvh", help="turn a folder of BVH mocap into a HumanML3D-layout dataset")
    imp.add_argument("dir", help="folder searched recursively for .bvh files")
    imp.add_argument("--out", required=True, help="new dataset folder")
    imp.add_argument("--texts", default=None, help="CSV 'file,text' with one caption per row (default: captions from the file names)")
    imp.add_argument("--map", default=None, help="YAML {our joint name: file joint name} (default: ours/Mixamo or CMU names)")
    imp.add_argument("--up", default="y", choices=["y", "z"], help="the files' up axis (default y)")
    imp.add_argument("--seed", type=int, default=0, help="seed of the train/val/test split")
    shard = sub.add_parser("shard", help="turn dataset folders (HumanML3D layout) into compressed shards + manifest")
    shard.add_argument("sources", nargs="+", metavar="SRC", help="dataset folders; several are merged in this order")
    shard.add_argument("--out", required=True, help="shard folder: new or empty, or the same command's unfinished run "
                                                    "(it continues)")
    shard.add_argument("--dataset", default="humanml3d", choices=sorted(DATASETS), help="feature width and limits")
    shard.add_argument("--licence", nargs="+", default=None,
                       help="licence of the sources: one for all or one per source (default: the first line "
                            "of a LICENCE/LICENSE file in the source, else 'unknown'); give it after the SRC folders")
    shard.add_argument("--clips-per-shard", type=int, default=None, help="clips per shard file (default 512)")
    shard.add_argument("--skip-bad", action="store_true", help="skip unreadable clips (listed in the manifest)")
    shard.add_argument("--workers", type=int, default=None,
                       help="processes writing shards in parallel (default: the CPU count, at most 8)")
    glove = sub.add_parser("glove-words", help="write GLOVE_DIR/our_vab_words.txt from the published GloVe .pkl "
                                               "files (parsed, never unpickled), for the Guo et al. evaluator")
    glove.add_argument("dir", help="folder holding our_vab_words.pkl (and our_vab_idx.pkl)")
    glove.add_argument("--prefix", default="our_vab", help="file name prefix (default our_vab)")
    preview = sub.add_parser("preview", help="a PNG contact sheet of one synthetic motion per action")
    preview.add_argument("out", help="PNG path")
    preview.add_argument("--seed", type=int, default=0)
    preview.add_argument("--frames", type=int, default=8, help="frames per row")
    preview.add_argument("--only", nargs="*", help="restrict to these actions")
    return parser


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    if args.command == "preview":
        from stablemo.data.synth.preview import write_contact_sheet
        from stablemo.io import check_output_file

        check_output_file(args.out, "out")
        if args.frames < 1:
            raise StableMoError(f"--frames: must be >= 1, got {args.frames}")
        print(f"wrote {write_contact_sheet(args.out, args.seed, args.frames, args.only)}")
        return 0
    if args.command == "glove-words":
        from stablemo.eval.word_vectorizer import convert_words_to_text

        print(f"wrote {convert_words_to_text(args.dir, args.prefix)}")
        return 0
    if args.command == "check":
        from stablemo.data.shard_check import check_shards, format_shard_report, is_shard_folder

        if is_shard_folder(args.dir):  # written by `data shard`: the manifest names the dataset
            report = check_shards(args.dir)
            print(format_shard_report(report, max_problems=len(report.problems) if args.all_problems else 30))
            return 0 if report.ok else 1
        from stablemo.data.check import check_dataset, format_report

        report = check_dataset(args.dir, args.dataset, cache=not args.no_cache)
        print(format_report(report, max_problems=len(report.problems) if args.all_problems else 30))
        return 0 if report.ok else 1
    if args.command == "shard":
        from stablemo.data.shards import CLIPS_PER_SHARD, write_shards

        manifest, kept = write_shards(args.sources, args.out, dataset=args.dataset, licences=args.licence,
                                      clips_per_shard=CLIPS_PER_SHARD if args.clips_per_shard is None else args.clips_per_shard,
                                      skip_bad=args.skip_bad,
                                      workers=min(os.cpu_count() or 1, 8) if args.workers is None else args.workers)
        splits = manifest["splits"]
        shards = sum(len(s["shards"]) for s in splits.values())
        counts = ", ".join(f"{name} {entry['clips']} clips" for name, entry in splits.items())
        print(f"wrote {shards} shards ({counts}) to {args.out}" + (f"; {kept} kept from the unfinished run" if kept else ""))
        return 0
    if args.command == "import-bvh":
        from stablemo.data.bvh_import import import_bvh_dir  # owned by the BVH module

        if args.seed < 0:
            raise StableMoError(f"--seed={args.seed}: must be >= 0")
        clips = import_bvh_dir(args.dir, args.out, texts=args.texts, name_map=args.map, up=args.up, seed=args.seed)
        print(f"wrote {len(clips)} clips ({sum(len(c.features) for c in clips)} frames at 20 fps) to {args.out}")
        return 0
    from stablemo.data.synth.writer import (  # owned by the synthetic-dataset module
        check_num,
        check_share,
        write_dataset,
    )

    if args.num is not None:
        check_num(args.num, "--num")  # the cap and the minimum, before anything else
    if args.seed < 0:
        raise StableMoError(f"--seed={args.seed}: must be >= 0")
    check_share(args.path_walks, "--path-walks")
    options = {} if args.rest is None else {"rest": args.rest}
    options.update(path_walks=args.path_walks, captions=args.captions)
    if args.num is None:
        write_dataset(args.out, seed=args.seed, flag="--out", **options)
    else:
        write_dataset(args.out, args.num, args.seed, flag="--out", **options)
    print(f"wrote synthetic dataset to {args.out}")
    return 0
