"""Give bundles their training captions, so a prompt unlike all of them gets a warning (stablemo.text.familiar).

    .venv/bin/python scripts/text/familiarity.py --data data/synth --threshold 0.65 \
        stablemo/assets/demo_bundle stablemo/assets/demo_student stablemo/assets/demo_controlnet

Reads the captions of the data's train split (HumanML3D layout: texts/<id>.txt, `caption#tokens#...`
per line), embeds them with the first bundle's frozen text encoder, keeps a deduplicated set, writes
`familiar.safetensors` into every bundle given (they must share that encoder: a student or a
ControlNet of the same teacher) and adds `familiarity` to their config.json. Then it prints the
nearest-caption similarity of the val and test captions and of two lists of prompts outside the
vocabulary, one to choose the threshold on (--threshold) and one held out, so the choice can be checked.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

OUT_OF_VOCABULARY_TUNE = [
    "a person plays the guitar", "asdf qwerty zzz", "a person swims in a pool", "someone rides a bicycle",
    "a person types on a keyboard", "a dog runs", "a person cooks dinner", "a person reads a book",
    "a person climbs a ladder", "a person brushes their teeth", "the person drinks from a cup",
    "a person plays the violin", "someone juggles three balls", "a person throws a baseball",
    "a person does a cartwheel"]
OUT_OF_VOCABULARY_HELD_OUT = [
    "a person plays the drums", "hello world", "a man paints a wall", "someone skis down a slope",
    "a person rows a boat", "a woman sews a dress", "a person shoots a basketball", "a person lifts a heavy box",
    "a person sweeps the floor", "a person answers the phone", "a person is knitting", "the cat sleeps",
    "a person plays tennis", "someone opens a door", "a person pours water"]


def captions(data: Path, split: str) -> list[str]:
    out = []
    for clip in (data / f"{split}.txt").read_text().split():
        for line in (data / "texts" / f"{clip}.txt").read_text().splitlines():
            if line.strip():
                out.append(line.split("#")[0].strip())
    return list(dict.fromkeys(out))


def main(argv=None) -> int:
    from stablemo.inference.pipeline import Pipeline
    from stablemo.io import write_text
    from stablemo.text.familiar import Familiarity, sentence_embeddings

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bundles", nargs="+")
    ap.add_argument("--data", default="data/synth")
    ap.add_argument("--threshold", type=float, default=0.65)
    args = ap.parse_args(argv)
    data = Path(args.data)
    pipe = Pipeline.from_bundle(args.bundles[0])
    encoder = pipe._frozen_encoders[0]
    train = captions(data, "train")
    fam = Familiarity.build(encoder, train, args.threshold)
    print(f"{len(train)} unique training captions, {len(fam.captions)} kept", flush=True)
    for bundle in args.bundles:
        config_path = Path(bundle) / "config.json"
        config = json.loads(config_path.read_text())
        config["familiarity"] = fam.write(bundle)
        write_text(config_path, json.dumps(config, indent=2) + "\n")
    for name, texts in (("val captions", captions(data, "val")), ("test captions", captions(data, "test")),
                        ("out of vocabulary (threshold chosen on these)", OUT_OF_VOCABULARY_TUNE),
                        ("out of vocabulary, held out", OUT_OF_VOCABULARY_HELD_OUT)):
        sims = (sentence_embeddings(encoder, texts) @ fam.embeddings.T).max(1).values
        flagged = int((sims < fam.threshold).sum())
        print(f"{name}: {len(texts)}, nearest-caption similarity min {sims.min():.3f} median {sims.median():.3f} "
              f"max {sims.max():.3f}; below {fam.threshold}: {flagged}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
