"""Write the vocabularies under artifacts/vocab/ from the paper's table and the shared data.

Run: python scripts/make_vocab.py   (deterministic; re-run after changing a source list, then
scripts/make_glosses.py; glosses already in a file are kept for the names it still lists)

Sources: the paper's "Concepts used in static and real-world evaluation" table (transcribed
below), ../shared/data/imagenet_affordance/{verbs.txt,objects.tsv}, the simulation assets in
../shared/assets/objects (plain names below), and the Zhu et al. 2014 dev matrix.
"""

from __future__ import annotations

import argparse
import csv

from craft_e.paths import VOCAB_DIR, existing_vocab_dir, shared_dir
from craft_e.schemas.names import normalize_name, normalize_verb

PAPER_STATIC_VERBS = (
    "brush, carry, clean, clip, comb, contain, cut, drink, eat, erase, fasten, hang, hammer, "
    "illuminate, mix, open, pour, press, pull, scoop, scrub, shave, spin, stir, tighten, "
    "transfer, use, wear, wipe"
)
PAPER_STATIC_OBJECTS = (
    "bottle, bowl, brush, can, cellphone, clip, comb, cup, flashlight, fork, glue, hammer, "
    "hanger, knife, marker, mask, mouse, mug, pencil, pen, remote, rope, scissors, screw, "
    "screwdriver, shaver, soap, sponge, spoon, stapler"
)
PAPER_REAL_VERBS = (
    "play, contain, construct, support, design, serve, transfer, grow, install, activate, "
    "cover, cut, write, feed, pick, open, wear, pull, eat, rotate"
)
PAPER_REAL_OBJECTS = (
    "bowl, juice box, corn, broccoli, drumstick, fish, crab, lobster, tomato, carrot, patty, "
    "eggplant, tape measure, drill, chasen, toy car, glue, sponge, bottle, goggles, wrench, "
    "hammer, plier, screwdriver, clamp, shaker, egg, knife, ladle, spatula, fork, pot, gamepad, "
    "dry eraser, eraser, block, marker, tape, spoon"
)
# Simulation asset id -> plain name (YCB + OCRTOC in ../shared/assets/objects).
SIM_OBJECTS = {
    "a_colored_wood_blocks": "toy block",
    "a_cups": "cup",
    "a_lego_duplo": "lego brick",
    "a_marbles": "marbles",
    "a_toy_airplane": "toy airplane",
    "adjustable_wrench": "wrench",
    "apple": "apple",
    "banana": "banana",
    "baseball": "baseball",
    "bleach_cleanser": "bleach bottle",
    "bowl": "bowl",
    "chain": "chain",
    "cracker_box": "cracker box",
    "dice": "dice",
    "extra_large_clamp": "clamp",
    "flat_screwdriver": "screwdriver",
    "foam_brick": "foam brick",
    "fork": "fork",
    "gelatin_box": "gelatin box",
    "golf_ball": "golf ball",
    "hammer": "hammer",
    "knife": "knife",
    "large_clamp": "clamp",
    "large_marker": "marker",
    "lemon": "lemon",
    "master_chef_can": "coffee can",
    "medium_clamp": "clamp",
    "mini_soccer_ball": "soccer ball",
    "mug": "mug",
    "mustard_bottle": "mustard bottle",
    "nine_hole_peg_test": "peg board",
    "orange": "orange",
    "padlock": "padlock",
    "peach": "peach",
    "pear": "pear",
    "phillips_screwdriver": "screwdriver",
    "pitcher_base": "pitcher",
    "plate": "plate",
    "plum": "plum",
    "potted_meat_can": "meat can",
    "power_drill": "drill",
    "pudding_box": "pudding box",
    "racquetball": "racquetball",
    "rubiks_cube": "rubik's cube",
    "scissors": "scissors",
    "skillet_lid": "skillet lid",
    "softball": "softball",
    "spatula": "spatula",
    "sponge": "sponge",
    "spoon": "spoon",
    "strawberry": "strawberry",
    "sugar_box": "sugar box",
    "tennis_ball": "tennis ball",
    "tomato_soup_can": "soup can",
    "tuna_fish_can": "tuna can",
    "windex_bottle": "spray bottle",
    "wood_block": "wood block",
    "black_marker": "marker",
    "blue_cup": "cup",
    "blue_marker": "marker",
    "correction_fluid": "correction fluid",
    "doraemon_bowl": "bowl",
    "glue_1": "glue",
    "glue_2": "glue",
    "green_cup": "cup",
    "mini_claw_hammer_1": "hammer",
    "poker_1": "playing card",
    "red_marker": "marker",
    "remote_controller_1": "remote",
    "shampoo": "shampoo bottle",
    "soap": "soap",
    "stapler_1": "stapler",
    "stapler_2": "stapler",
    "toothpaste_1": "toothpaste",
}
ZHU_VERBS = {
    "Grasp": "grasp",
    "Lift": "lift",
    "Throw": "throw",
    "Push": "push",
    "Fix": "fix",
    "Ride": "ride",
    "Play": "play",
    "Watch": "watch",
    "SitOn": "sit on",
    "Feed": "feed",
    "Row": "row",
    "PourFrom": "pour from",
    "LookThrough": "look through",
    "WriteWith": "write with",
    "TypeOn": "type on",
}


def split(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def unique(names: list[str]) -> list[str]:
    return list(dict.fromkeys(names))


def write(name: str, items: list[str]) -> None:
    """Write one vocabulary, keeping the ``name<TAB>gloss`` glosses the file already has for the
    names it still lists: scripts/make_glosses.py adds them afterwards, so re-running this script
    must not strip the senses the shipped builds ask in."""
    path = VOCAB_DIR / name
    glosses: dict[str, str] = {}
    if path.is_file():
        for line in path.read_text(encoding="utf-8").splitlines():
            item, tab, gloss = line.partition("\t")
            if tab and gloss:
                glosses[item] = gloss
    lines = [f"{item}\t{glosses[item]}" if item in glosses else item for item in items]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    kept = sum(item in glosses for item in items)
    print(f"{path}: {len(items)}" + (f" ({kept} glosses kept; scripts/make_glosses.py rewrites them)" if kept else ""))


def zhu_objects() -> dict[str, str]:
    path = shared_dir() / "data/affordance_dev/zhu2014_affordance_matrix.csv"
    with path.open(newline="") as handle:
        rows = list(csv.reader(handle))
    return {row[0]: normalize_name(row[0].split(".")[0]) for row in rows[1:] if row and row[0]}


def main() -> None:
    # no options, but --help must describe, not rewrite the vocabularies (it ran them before)
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    existing_vocab_dir()
    imagenet = shared_dir() / "data/imagenet_affordance"
    sets: dict[str, tuple[list[str], list[str]]] = {
        "paper_static": (
            [normalize_verb(v) for v in split(PAPER_STATIC_VERBS)],
            [normalize_name(o) for o in split(PAPER_STATIC_OBJECTS)],
        ),
        "paper_realworld": (
            [normalize_verb(v) for v in split(PAPER_REAL_VERBS)],
            [normalize_name(o) for o in split(PAPER_REAL_OBJECTS)],
        ),
        "imagenet": (
            [normalize_verb(v) for v in imagenet.joinpath("verbs.txt").read_text().split()],
            [
                normalize_name(line.split("\t")[0])
                for line in imagenet.joinpath("objects.tsv").read_text().splitlines()[1:]
                if line.strip()
            ],
        ),
        "zhu": (list(ZHU_VERBS.values()), list(zhu_objects().values())),
        "sim": ([], [normalize_name(n) for n in SIM_OBJECTS.values()]),
    }
    all_verbs: list[str] = []
    all_objects: list[str] = []
    for name, (verbs, objects) in sets.items():
        if verbs:
            write(f"{name}_verbs.txt", unique(verbs))
        write(f"{name}_objects.txt", unique(objects))
        all_verbs += verbs
        all_objects += objects
    # The simulation scenes use every verb we evaluate on.
    write("sim_verbs.txt", unique(sets["paper_static"][0] + sets["paper_realworld"][0]))
    write("union_verbs.txt", sorted(set(all_verbs)))
    write("union_objects.txt", sorted(set(all_objects)))
    (VOCAB_DIR / "sim_assets.tsv").write_text(
        "asset\tname\n"
        + "".join(f"{a}\t{normalize_name(n)}\n" for a, n in sorted(SIM_OBJECTS.items()))
    )
    (VOCAB_DIR / "zhu_synsets.tsv").write_text(
        "synset\tname\n" + "".join(f"{s}\t{n}\n" for s, n in zhu_objects().items())
    )


if __name__ == "__main__":
    main()
