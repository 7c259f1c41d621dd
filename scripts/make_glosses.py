"""Write artifacts/vocab/wordnet_glosses.tsv: object name -> WordNet 3.0 gloss (its sense).

Run: python scripts/make_glosses.py [--wordnet /usr/share/wordnet]   (Debian: wordnet-base),
after scripts/make_vocab.py; ``--verbs-only`` rewrites only the verbs files' glosses from
artifacts/vocab/written_verb_glosses.tsv and needs no WordNet. It also writes
artifacts/vocab/default_objects.txt (the union plus artifacts/vocab/household_objects.txt) and
rewrites artifacts/vocab/union_objects.txt as ``name<TAB>gloss`` (WordNet first, then the written glosses): the default objects file of
``craftc build``, so every shipped object is asked about in one stated sense.

Senses come from the vocabularies' own WordNet ids, never guessed: ImageNet classes from the wnid
in ../shared/data/imagenet_affordance/objects.tsv (a name with two wnids, e.g. crane, gets both
glosses joined by "; or: "), Zhu et al. objects from artifacts/vocab/zhu_synsets.tsv. Names in
neither have a gloss written by the curators in artifacts/vocab/written_glosses.tsv.
"""

from __future__ import annotations

import argparse
import csv
import re
from pathlib import Path

from craft_e.paths import VOCAB_DIR, existing_vocab_dir, shared_dir
from craft_e.schemas.names import normalize_name, normalize_verb

EXAMPLE = re.compile(r';?\s*"[^"]*"')


def read_noun_glosses(wordnet: Path) -> dict[str, str]:
    """data.noun: synset offset (8 digits) -> gloss (the text after ' | ')."""
    glosses: dict[str, str] = {}
    with (wordnet / "data.noun").open(encoding="latin-1") as handle:
        for line in handle:
            if line.startswith("  ") or " | " not in line:
                continue
            # Keep the definition, drop WordNet's quoted usage examples ('; "the cabinetmaker ..."').
            gloss = line.split(" | ", 1)[1].strip()
            glosses[line[:8]] = EXAMPLE.sub("", gloss).strip().rstrip(";").strip()
    return glosses


def read_noun_index(wordnet: Path) -> dict[str, list[str]]:
    """index.noun: lemma -> synset offsets in sense order (sense n.01 first)."""
    index: dict[str, list[str]] = {}
    with (wordnet / "index.noun").open(encoding="latin-1") as handle:
        for line in handle:
            if line.startswith("  "):
                continue
            fields = line.split()
            lemma, synset_count = fields[0], int(fields[2])
            index[lemma] = fields[-synset_count:]
    return index


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--wordnet", type=Path, default=Path("/usr/share/wordnet"))
    parser.add_argument("--verbs-only", action="store_true",
                        help="only gloss the verbs files from written_verb_glosses.tsv (no WordNet needed)")
    args = parser.parse_args()
    existing_vocab_dir()
    if args.verbs_only:
        write_verb_glosses()
        return
    if not (args.wordnet / "data.noun").is_file():
        parser.error(f"no WordNet 3.0 at {args.wordnet} (data.noun): install the Debian package "
                     "wordnet-base or pass --wordnet DIR; --verbs-only needs none")
    glosses = read_noun_glosses(args.wordnet)
    index = read_noun_index(args.wordnet)
    by_name: dict[str, list[str]] = {}
    source: dict[str, str] = {}
    objects_tsv = shared_dir() / "data" / "imagenet_affordance" / "objects.tsv"
    with objects_tsv.open(encoding="utf-8") as handle:
        for row in csv.DictReader(handle, delimiter="\t"):
            gloss = glosses[row["wnid"].lstrip("n")]
            name = normalize_name(row["object"])
            by_name.setdefault(name, []).append(gloss)
            source[name] = "wordnet-3.0:imagenet-wnid"
    with (VOCAB_DIR / "zhu_synsets.tsv").open(encoding="utf-8") as handle:
        for row in csv.DictReader(handle, delimiter="\t"):
            name = normalize_name(row["name"])
            if name in by_name:
                continue
            lemma, _, sense = row["synset"].rsplit(".", 2)
            by_name[name] = [glosses[index[lemma][int(sense) - 1]]]
            source[name] = f"wordnet-3.0:{row['synset']}"
    lines = ["name\tgloss\tsource"]
    for name in sorted(by_name):
        lines.append(f"{name}\t{'; or: '.join(by_name[name])}\t{source[name]}")
    (VOCAB_DIR / "wordnet_glosses.tsv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {len(by_name)} glosses to {VOCAB_DIR / 'wordnet_glosses.tsv'}")
    written: dict[str, str] = {}
    with (VOCAB_DIR / "written_glosses.tsv").open(encoding="utf-8") as handle:
        for row in csv.DictReader(handle, delimiter="\t"):
            written[normalize_name(row["name"])] = row["gloss"].strip()
    union = VOCAB_DIR / "union_objects.txt"
    names = [ln.split("\t", 1)[0].strip() for ln in union.read_text(encoding="utf-8").splitlines()]
    names = [n for n in names if n]
    missing = [n for n in names if n not in by_name and n not in written]
    if missing:
        raise SystemExit(f"no gloss for {missing}: add them to {VOCAB_DIR / 'written_glosses.tsv'}")
    # A name with a WordNet sense *and* a written one (an ImageNet class whose synset gloss
    # differs from the object another vocabulary means, e.g. ImageNet "cup" is n07930864, a
    # punch, while the simulation's cup is a drinking cup) is asked in both senses, like crane.
    senses = {n: by_name.get(n, []) + ([written[n]] if n in written else []) for n in names}
    union.write_text("".join(f"{n}\t{'; or: '.join(senses[n])}\n" for n in names), encoding="utf-8")
    print(f"wrote {len(names)} glossed names to {union}")
    # The shipped default KB's objects: the benchmark union plus a household robot's everyday
    # objects (COCO categories, kitchen, office, workshop, bathroom; written glosses).
    household = (VOCAB_DIR / "household_objects.txt").read_text(encoding="utf-8").splitlines()
    default = VOCAB_DIR / "default_objects.txt"
    default.write_text(union.read_text(encoding="utf-8") + "\n".join(household) + "\n", encoding="utf-8")
    print(f"wrote {len(names) + len(household)} glossed names to {default}")
    write_verb_glosses()


def write_verb_glosses() -> None:
    """Gloss the verbs that artifacts/vocab/written_verb_glosses.tsv names, in every verbs file
    holding them. A verb is glossed only where its unglossed prompt reads it in another sense
    than its vocabulary means (Zhu et al.'s verbs say what is done *to* the object) or its
    unglossed answer mixed senses (spin: whirling and spinning yarn); every other verb stays
    unglossed and keeps its answers."""
    with (VOCAB_DIR / "written_verb_glosses.tsv").open(encoding="utf-8") as handle:
        senses = {normalize_verb(r["verb"]): r["gloss"].strip() for r in csv.DictReader(handle, delimiter="\t")}
    for path in sorted(VOCAB_DIR.glob("*_verbs.txt")):
        names = [ln.split("\t", 1)[0].strip() for ln in path.read_text(encoding="utf-8").splitlines()]
        names = [n for n in names if n]
        if not set(names) & senses.keys():
            continue
        path.write_text(
            "".join(f"{n}\t{senses[n]}\n" if n in senses else f"{n}\n" for n in names),
            encoding="utf-8",
        )
        print(f"glossed {len(set(names) & senses.keys())} verbs in {path}")


if __name__ == "__main__":
    main()
