"""Give bundles a length predictor, so a motion asked for without a length gets the text's (stablemo.text.length).

    .venv/bin/python scripts/text/length_predictor.py --data data/synth \
        stablemo/assets/demo_bundle stablemo/assets/demo_student stablemo/assets/demo_controlnet

Pairs every caption of the data's training items (whole clips and sub-captioned windows, as training
reads them: stablemo.data.dataset.build_items) with the item's length, embeds the captions with the
first bundle's frozen text encoder, trains the predictor on the train split (settings:
configs/text/length_predictor.yaml, the epoch picked on the val split), writes `length.safetensors`
into every bundle given (they must share that encoder and length range: a student or a ControlNet of
the same teacher) and adds `length_predictor` to their config.json, with the held-out numbers. It
prints the val and test numbers, those of the test captions that name a count, and the lengths
predicted for counted prompts (a count's length should grow with the count).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import torch

COUNTED = {  # one action, counts in order: the predicted lengths should not shrink as the count grows
    "jumps in place": ["a person jumps in place once", "a person jumps in place twice",
                       "a person jumps in place three times"],
    "claps": ["a person claps once", "a person claps twice", "a person claps three times", "a person claps four times"],
    "squats": ["a person squats down once", "a person squats twice", "a person squats three times"],
    "hops": ["a person hops on the left leg twice", "a person hops on the left leg three times",
             "a person hops on the left leg four times"],
    "punches": ["a person punches once with the right hand", "a person punches twice with the right hand",
                "a person punches three times with the right hand"],
    "jumps forward": ["a person jumps forward once", "a person jumps forward twice"],
}
OTHERS = ["a person walks forward", "a person walks forward, then waves their right hand", "a person turns left",
          "a person bows"]
NAMES_A_COUNT = re.compile(r"\b(twice|times|two|three|four|five)\b")


def pairs(data: Path, split: str, dataset: str) -> tuple[list[str], torch.Tensor]:
    """(caption, length in frames) of every caption of every training item of the split."""
    from stablemo.data.cache import load_split
    from stablemo.data.dataset import build_items
    from stablemo.data.layout import get_spec

    spec = get_spec(dataset)
    items = build_items(load_split(data, split, spec, progress=False), spec)
    texts, frames = [], []
    for caps, n in zip(items.captions, items.length.tolist()):
        for cap in caps:
            texts.append(cap.text)
            frames.append(n)
    return texts, torch.tensor(frames)


def embed(encoder, texts: list[str]) -> torch.Tensor:
    """(N, D): each distinct text embedded once."""
    from stablemo.text.familiar import sentence_embeddings

    unique = list(dict.fromkeys(texts))
    emb = sentence_embeddings(encoder, unique)
    row = {t: i for i, t in enumerate(unique)}
    return emb[[row[t] for t in texts]]


def text_and_range(bundle: str) -> tuple:
    """((text encoder, text variant), (min_length, max_length), dataset) of a bundle's config.json."""
    from stablemo.errors import StableMoError
    from stablemo.inference.bundle import load_bundle
    from stablemo.inference.config import InferenceConfig

    config, source = load_bundle(bundle).config, str(Path(bundle) / "config.json")
    text = config.get("model", {}).get("text")
    if not isinstance(text, dict) or not isinstance(text.get("encoder"), str):
        raise StableMoError(f"{source}: the model has no text encoder ('model' -> 'text' -> 'encoder')")
    inference = InferenceConfig.from_bundle(config, source)
    return ((text["encoder"], text.get("variant", "stablemo")), (inference.min_length, inference.max_length),
            config.get("dataset", "humanml3d"))


def main(argv=None) -> int:
    import yaml

    from stablemo.errors import StableMoError
    from stablemo.io import write_text
    from stablemo.text.conditioner import frozen_encoder
    from stablemo.text.length import ENTRY, LengthBins, LengthFit, LengthPredictor

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bundles", nargs="+")
    ap.add_argument("--data", default="data/synth")
    ap.add_argument("--config", default=str(Path(__file__).resolve().parents[2] / "configs/text/length_predictor.yaml"))
    args = ap.parse_args(argv)
    # the encoder reads one text at a time (stablemo.text.encoders): more threads only synchronise
    # (the training captions had not been embedded after 14 min with 2 threads on the loaded 2-core
    # machine; 2 min with one)
    torch.set_num_threads(1)
    try:
        settings = LengthFit(**yaml.safe_load(Path(args.config).read_text()))
    except (OSError, TypeError, yaml.YAMLError) as err:
        raise StableMoError(f"--config {args.config}: not a length predictor's settings ({err})") from None
    data = Path(args.data)
    # one predictor for all: the same text path and length range (a bundle's own predictor, even a
    # broken one, is not read: this script writes it again)
    described = [text_and_range(bundle) for bundle in args.bundles]
    for bundle, other in zip(args.bundles[1:], described[1:]):
        if other != described[0]:
            raise StableMoError(f"{bundle}: text encoder and length range {other} differ from "
                                f"{args.bundles[0]}'s {described[0]}")
    (name, variant), (min_length, max_length), dataset = described[0]
    encoder = frozen_encoder(name, variant)
    bins = LengthBins(min_length, max_length, settings.bin_frames)
    splits = {}
    for split in ("train", "val", "test"):
        texts, frames = pairs(data, split, dataset)
        splits[split] = (texts, embed(encoder, texts), frames)
        print(f"{split}: {len(texts)} (caption, length) pairs, {len(set(texts))} distinct captions, "
              f"lengths {int(frames.min())}-{int(frames.max())} frames", flush=True)
    predictor, fit = LengthPredictor.fit(splits["train"][1:], splits["val"][1:], bins, encoder.name, settings,
                                         log=lambda line: print(line, flush=True))
    report = {"fit": {"data": str(data), **fit}}
    for split in ("val", "test"):
        report[split] = predictor.measure(*splits[split][1:])
        print(f"{split}: {report[split]}", flush=True)
    texts, emb, frames = splits["test"]
    counted = torch.tensor([bool(NAMES_A_COUNT.search(t)) for t in texts])
    print(f"test captions naming a count: {predictor.measure(emb[counted], frames[counted])}", flush=True)
    grow = never_shrink = 0
    for action, prompts in COUNTED.items():
        lengths = predictor.predict(encoder, prompts)
        grow += all(a < b for a, b in zip(lengths, lengths[1:]))
        never_shrink += all(a <= b for a, b in zip(lengths, lengths[1:]))
        print(f"{action}: " + ", ".join(f"{p.split(action)[-1].strip() or p}: {n}" for p, n in zip(prompts, lengths)))
    print(f"actions whose lengths grow with the count: {grow} of {len(COUNTED)}; never shrink: {never_shrink}")
    for prompt, n in zip(OTHERS, predictor.predict(encoder, OTHERS)):
        print(f"{prompt!r}: {n} frames")
    for bundle in args.bundles:
        config_path = Path(bundle) / "config.json"
        config = json.loads(config_path.read_text())
        config[ENTRY] = predictor.write(bundle, report)
        write_text(config_path, json.dumps(config, indent=2) + "\n")
        print(f"{bundle}: {(Path(bundle) / 'length.safetensors').stat().st_size} bytes", flush=True)
    return 0


if __name__ == "__main__":
    from stablemo.errors import run_script

    sys.exit(run_script(main, "/".join(Path(__file__).parts[-2:]), sys.argv[1:]))
