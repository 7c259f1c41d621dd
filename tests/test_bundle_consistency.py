"""Bundle verification refuses bundles whose files disagree with each other or the manifest.

Each case edits a small bundle and reseals it (every sha256 and the content hash consistent
again, as a buggy or hostile writer would leave it), so only the content checks can catch it
(``runtime/kb/content.py``). Each passed ``craftc validate``, ``craftc pack`` and ``craft install``
before; now ``load_bundle`` and ``verify_files`` (what pack and install run) refuse it, naming the
file and the record. Also: ``--trusted-key`` on ``craftc validate``/``explain``/``diff``, a folder
where a bundle file should be, and a manifest that is no JSON object.
"""

from __future__ import annotations

import hashlib
import importlib
import io
import json
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from safetensors.numpy import load_file, save
from typer.testing import CliRunner, Result

from craft_e.compiler.cli import app as craftc_app
from craft_e.compiler.emit import model_json
from craft_e.compiler.pack import UnverifiedBundleError, keygen, pack_bundle
from craft_e.runtime.kb.bundle import BundleError, load_bundle, read_manifest, verify_files
from craft_e.schemas.generate import SCHEMA_DIR
from craft_e.schemas.names import is_normalized
from craft_e.schemas.v1.bundle import MANIFEST_FILE, FileDigest, sealed
from craft_e.schemas.v1.open_world import OpenWorld

make_bundle = importlib.import_module(
    f"{__package__}.test_pack_package" if __package__ else "test_pack_package"
).make_bundle
ROOT = Path(__file__).resolve().parents[1]
Edit = Callable[[Path], None]


def reseal(folder: Path, name: str, data: bytes) -> None:
    """Replace (or add) a bundle file and make every hash consistent again."""
    (folder / name).write_bytes(data)
    manifest = read_manifest(folder)
    files = {**manifest.files, name: FileDigest(sha256=hashlib.sha256(data).hexdigest(), bytes=len(data))}
    (folder / MANIFEST_FILE).write_bytes(model_json(sealed(manifest.model_copy(update={"files": files}))))


def edit_manifest(change: Callable[[dict[str, Any]], None]) -> Edit:
    def edit(folder: Path) -> None:
        data = json.loads((folder / MANIFEST_FILE).read_bytes())
        change(data)
        manifest = read_manifest(folder).model_validate(data)
        (folder / MANIFEST_FILE).write_bytes(model_json(sealed(manifest)))

    return edit


def edit_graph(change: Callable[[dict[str, Any]], None]) -> Edit:
    def edit(folder: Path) -> None:
        graph = json.loads((folder / "graph.json").read_bytes())
        change(graph)
        reseal(folder, "graph.json", json.dumps(graph).encode())

    return edit


def set_energy(change: Callable[[np.ndarray[Any, Any]], None]) -> Edit:
    def edit(folder: Path) -> None:
        energy = np.load(folder / "affordance_energy.npy")
        change(energy)
        buf = io.BytesIO()
        np.save(buf, energy, allow_pickle=False)
        reseal(folder, "affordance_energy.npy", buf.getvalue())

    return edit


def write_json(name: str, value: Any) -> Edit:
    return lambda folder: reseal(folder, name, json.dumps(value).encode())


def forbid_cut_bowl(folder: Path) -> None:
    """A consistent "never pick" pair: marked on the verb node and E_aff = +1 in its cell."""
    edit_graph(lambda g: _node(g, "verb:cut").update(forbidden_objects=["bowl"]))(folder)
    set_energy(lambda e: e.__setitem__((0, 2), 1.0))(folder)


def _node(graph: dict[str, Any], nid: str) -> dict[str, Any]:
    node: dict[str, Any] = next(n for n in graph["nodes"] if n["id"] == nid)
    return node


def _index_embeddings(reorder: bool) -> Edit:
    """Record the rows' names in the tensors' metadata as craftc does (then, with ``reorder``,
    swap two objects in the manifest only)."""
    def edit(folder: Path) -> None:
        manifest = read_manifest(folder)
        index = {"encoder": manifest.text_encoder.id, "verbs": manifest.verbs, "objects": manifest.objects,
                 "properties": manifest.properties, "verb_template": manifest.text_encoder.verb_template}
        blob = save(load_file(folder / "embeddings.safetensors"), metadata={"index": json.dumps(index)})
        reseal(folder, "embeddings.safetensors", blob)
        if reorder:
            edit_manifest(lambda m: m.update(objects=["spoon", "knife", "bowl"]))(folder)

    return edit


def _zero_object_row(folder: Path) -> None:
    tensors = load_file(folder / "embeddings.safetensors")
    tensors["object"][1] = 0.0
    reseal(folder, "embeddings.safetensors", save(tensors))


def _shipped_open_world() -> dict[str, Any]:
    data: dict[str, Any] = json.loads((ROOT / "artifacts/kb/local-llm/open_world.json").read_bytes())
    return data


def _bad_curve() -> dict[str, Any]:
    data = _shipped_open_world()
    data["objects"]["confidence"]["nearest_cosine"].reverse()
    return data


GHOST = {"source": "prop:sharp edge", "target": "obj:ghost", "weight": 0.9, "provenance": []}
CASES: list[tuple[str, Edit, str, str]] = [
    ("weight-above-1", edit_graph(lambda g: g["edges"][0].update(weight=5.0)), "graph.json",
     r"'edges.0.weight': weight 5.0 is outside \[0, 1\]"),
    ("weight-below-0", edit_graph(lambda g: g["edges"][1].update(weight=-1.0)), "graph.json",
     r"'edges.1.weight': weight -1.0 is outside \[0, 1\]"),
    ("edge-to-ghost", edit_graph(lambda g: g["edges"].append(GHOST)), "graph.json",
     r"edges\[4\] .*'obj:ghost' is not a node of the graph"),
    ("duplicate-node", edit_graph(lambda g: g["nodes"].append(dict(g["nodes"][0]))), "graph.json",
     "'verb:cut' appears twice"),
    ("duplicate-edge", edit_graph(lambda g: g["edges"].append(dict(g["edges"][0]))), "graph.json",
     r"edges\[4\] 'verb:cut' -> 'prop:sharp edge' appears twice"),
    ("verb-to-object-edge", edit_graph(lambda g: g["edges"].append(
        {"source": "verb:cut", "target": "obj:knife", "weight": 0.5, "provenance": []})), "graph.json",
     "goes verb -> object; edges go verb -> property or property -> object"),
    ("empty-graph", edit_graph(lambda g: g.update(nodes=[], edges=[])), "graph.json",
     "has no node 'verb:cut', yet the manifest lists verb 'cut'"),
    ("node-not-in-manifest", edit_graph(lambda g: g["nodes"].append(
        {"id": "obj:cup", "kind": "object", "name": "cup"})), "graph.json",
     "node 'obj:cup' is not one of the manifest's objects"),
    ("id-not-kind-and-name", edit_graph(lambda g: _node(g, "obj:bowl").update(name="dish")), "graph.json",
     "has id 'obj:bowl' but kind 'object' and name 'dish'"),
    ("forbids-unknown-object", edit_graph(lambda g: _node(g, "verb:cut").update(forbidden_objects=["cup"])),
     "graph.json", "forbids 'cup', which is not an object of the bundle"),
    ("energy-plus-7", set_energy(lambda e: e.__setitem__((0, 0), 7.0)), "affordance_energy.npy",
     r"E_aff\('cut', 'knife'\) = 7; every E_aff form lies in \[-1, 0\]"),
    ("energy-below-minus-1", set_energy(lambda e: e.__setitem__((1, 2), -3.0)), "affordance_energy.npy",
     r"E_aff\('scoop', 'bowl'\) = -3"),
    ("forbidden-value-unmarked", set_energy(lambda e: e.__setitem__((0, 2), 1.0)), "affordance_energy.npy",
     r"E_aff\('cut', 'bowl'\) = 1; .*never pick"),
    ("marked-pair-not-forbidden", edit_graph(lambda g: _node(g, "verb:cut").update(forbidden_objects=["bowl"])),
     "affordance_energy.npy", "but graph.json marks the pair \"never pick\""),
    ("zero-embedding-row", _zero_object_row, "embeddings.safetensors",
     r"tensor 'object' row 1 \('spoon'\) is all zeros"),
    ("embeddings-of-other-order", _index_embeddings(reorder=True), "embeddings.safetensors",
     r"row 0 of its objects is 'knife', the manifest's objects\[0\] is 'spoon'"),
    ("open-world-not-a-model", write_json("open_world.json", {"objects": 3}), "open_world.json", "schema: Field required"),
    ("open-world-decreasing-curve", write_json("open_world.json", _bad_curve()), "open_world.json",
     "objects.confidence: .*nearest_cosine decreases"),
    ("report-not-a-report", write_json("report.json", {"x": 1}), "report.json", "kb_name: Field required"),
    ("duplicate-object", edit_manifest(lambda m: m.update(objects=["knife", "knife", "bowl"])), MANIFEST_FILE,
     r"objects\[1\] 'knife' is listed twice"),
    ("verb-not-normalized", edit_manifest(lambda m: m.update(verbs=["CUT", "scoop"])), MANIFEST_FILE,
     r"verbs\[0\] 'CUT' is not in the normalized form .* normalized it is 'cut'"),
    ("object-not-normalized", edit_manifest(lambda m: m.update(objects=["knives", "spoon", "bowl"])), MANIFEST_FILE,
     r"objects\[0\] 'knives' is not in the normalized form .*singular.* normalized it is 'knife'"),
    ("unknown-text-encoder", edit_manifest(lambda m: m["text_encoder"].update(id="bogus-encoder")), MANIFEST_FILE,
     "text_encoder.id 'bogus-encoder' is not a text space any image encoder of this runtime embeds into"),
    ("template-without-verb", edit_manifest(lambda m: m["text_encoder"].update(verb_template="")), MANIFEST_FILE,
     "verb_template '' is not a template with one {verb} field"),
]


@pytest.mark.parametrize(("edit", "name", "says"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_an_inconsistent_bundle_never_verifies(tmp_path: Path, edit: Edit, name: str, says: str) -> None:
    folder = make_bundle(tmp_path / "kb")
    edit(folder)
    with pytest.raises(BundleError, match=says) as loaded:
        load_bundle(folder, check_encoder=False)
    assert f"{folder / name}: " in str(loaded.value)
    with pytest.raises(BundleError, match=says):  # what craftc pack and craft install run
        verify_files(folder, read_manifest(folder))


def test_a_consistent_bundle_with_every_optional_part_verifies(tmp_path: Path) -> None:
    folder = make_bundle(tmp_path / "kb")
    forbid_cut_bowl(folder)
    _index_embeddings(reorder=False)(folder)
    write_json("open_world.json", _shipped_open_world())(folder)
    kb = load_bundle(folder, check_encoder=False)
    assert kb.index.forbidden_pairs() == [("cut", "bowl")] and kb.energy[0, 2] == 1.0
    assert kb.open_world is not None and kb.open_world["objects"]["k"] >= 1
    verify_files(folder, read_manifest(folder))


def test_pack_refuses_an_inconsistent_bundle(tmp_path: Path) -> None:
    folder = make_bundle(tmp_path / "kb")
    write_json("open_world.json", {"objects": 3})(folder)
    pair = keygen(tmp_path / "keys")
    with pytest.raises(UnverifiedBundleError, match=r"open_world\.json"):
        pack_bundle(folder, pair.private_key, tmp_path / "kb.craft")
    assert not (tmp_path / "kb.craft").exists()


def test_a_callers_own_text_space_is_accepted_only_when_it_asks_for_it(tmp_path: Path) -> None:
    folder = make_bundle(tmp_path / "kb")
    edit_manifest(lambda m: m["text_encoder"].update(id="my-encoder"))(folder)
    with pytest.raises(BundleError, match="'my-encoder' is not a text space"):
        load_bundle(folder, check_encoder=False)
    assert load_bundle(folder, encoder_id="my-encoder").manifest.text_encoder.id == "my-encoder"


def test_the_shipped_bundles_still_verify() -> None:
    bundles = sorted(p for p in (ROOT / "artifacts/kb").iterdir() if (p / MANIFEST_FILE).is_file())
    assert bundles
    schema = json.loads((SCHEMA_DIR / "open_world.schema.json").read_text("utf-8"))
    for folder in bundles:
        verify_files(folder, read_manifest(folder))
        open_world = json.loads((folder / "open_world.json").read_bytes())
        OpenWorld.model_validate(open_world)
        jsonschema.Draft202012Validator(schema).validate(open_world)


def test_names_the_normalizer_can_give() -> None:
    assert all(is_normalized(n) for n in ("knife", "glasses", "scissors", "men", "sit on", "box"))
    assert not any(is_normalized(n) for n in ("knives", "cups", "Knife", "kitchen_knife", " knife", ""))
    assert is_normalized("pour from", singular=False) and not is_normalized("CUT", singular=False)


# -- reading the files: a folder, a manifest that is no object -------------------------------------


@pytest.mark.parametrize("name", [MANIFEST_FILE, "graph.json"])
def test_a_folder_in_place_of_a_bundle_file_is_called_a_folder(tmp_path: Path, name: str) -> None:
    folder = make_bundle(tmp_path / "kb")
    (folder / name).unlink()
    (folder / name).mkdir()
    with pytest.raises(BundleError, match=f"{name}: is a folder, not a file"):
        load_bundle(folder, check_encoder=False)


@pytest.mark.parametrize(("doc", "kind"), [("[]", "a list"), ("null", "null"), ('"x"', "a string")])
def test_a_manifest_that_is_no_json_object_is_said_so(tmp_path: Path, doc: str, kind: str) -> None:
    folder = make_bundle(tmp_path / "kb")
    (folder / MANIFEST_FILE).write_text(doc)
    with pytest.raises(BundleError, match=f"not a JSON object \\(the document is {kind}\\)"):
        load_bundle(folder, check_encoder=False)


# -- --trusted-key on the commands that read a bundle ---------------------------------------------


def craftc(*args: str | Path) -> Result:
    return CliRunner().invoke(craftc_app, [str(a) for a in args], env={"COLUMNS": "2000"})


def test_validate_explain_and_diff_read_a_signed_package_with_trusted_key(tmp_path: Path) -> None:
    folder = make_bundle(tmp_path / "kb")
    pair = keygen(tmp_path / "keys")
    package = pack_bundle(folder, pair.private_key, tmp_path / "kb.craft").out
    ok = craftc("validate", package, "--trusted-key", pair.public_key)
    assert ok.exit_code == 0 and ok.stdout.startswith("ok: tiny 1.0.0"), ok.output
    explained = craftc("explain", package, "cut", "knife", "--trusted-key", pair.public_key)
    assert explained.exit_code == 0 and "cut -> knife" in explained.stdout, explained.output
    diffed = craftc("diff", package, folder, "--trusted-key", pair.public_key)
    assert diffed.exit_code == 0 and "No changes" in diffed.stdout, diffed.output
    unkeyed = craftc("validate", package)  # the advice names an option the command has
    assert unkeyed.exit_code == 1 and "--trusted-key" in unkeyed.output
    missing = craftc("validate", package, "--trusted-key", tmp_path / "nope.pub")
    assert missing.exit_code == 2 and "--trusted-key" in missing.output and "no such file" in missing.output
    shutil.rmtree(folder)  # nothing of the package was left unpacked beside it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kb.craft", "keys"]


def test_review_and_diagnose_read_a_signed_package_with_trusted_key(tmp_path: Path) -> None:
    """``craftc review`` and ``craftc diagnose`` had no --trusted-key: a .craft file was refused
    with advice naming an option they did not take ("No such option" when given)."""
    folder = make_bundle(tmp_path / "kb")
    pair = keygen(tmp_path / "keys")
    package = pack_bundle(folder, pair.private_key, tmp_path / "kb.craft").out
    reviewed = craftc("review", package, "--sample", "2", "--trusted-key", pair.public_key)
    assert reviewed.exit_code == 0, reviewed.output
    assert reviewed.stdout == craftc("review", folder, "--sample", "2").stdout != ""
    diagnosed = craftc("diagnose", package, "--format", "json", "--trusted-key", pair.public_key)
    assert diagnosed.exit_code == 0, diagnosed.output
    assert diagnosed.stdout == craftc("diagnose", folder, "--format", "json").stdout
    for command in (("review", package), ("diagnose", package)):
        unkeyed = craftc(*command)  # the advice names an option the command has
        assert unkeyed.exit_code == 2 and "--trusted-key" in unkeyed.output, unkeyed.output
        missing = craftc(*command, "--trusted-key", tmp_path / "nope.pub")
        assert missing.exit_code == 2 and "--trusted-key" in missing.output and "no such file" in missing.output
    shutil.rmtree(folder)  # nothing of the package was left unpacked beside it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kb.craft", "keys"]


# -- E_aff recomputed from the graph: craftc validate and craftc pack ------------------------------


def _validate(folder: Path) -> Result:
    return CliRunner().invoke(craftc_app, ["validate", str(folder)])


def test_validate_and_pack_refuse_energies_that_are_not_the_graphs(tmp_path: Path) -> None:
    """A manifest whose energy form was relabelled, or one E_aff value edited within [-1, 0], passes
    every load-time check; validate and pack recompute E_aff from graph.json and refuse it."""
    from craft_e.runtime.kb.energy_check import check_energy_matches_graph

    folder = make_bundle(tmp_path / "kb")
    check_energy_matches_graph(load_bundle(folder, check_encoder=False))
    assert _validate(folder).exit_code == 0
    form = read_manifest(folder).energy.form
    other = "sum-tanh" if form != "sum-tanh" else "normalized-product"
    relabelled = tmp_path / "relabelled"
    shutil.copytree(folder, relabelled)
    edit_manifest(lambda m: m["energy"].update(form=other))(relabelled)
    load_bundle(relabelled, check_encoder=False)  # loading alone does not recompute
    result = _validate(relabelled)
    assert result.exit_code == 1, result.output
    said = " ".join(result.output.split())
    assert "affordance_energy.npy: E_aff(" in said and f"in the manifest's form '{other}'" in said
    edited = tmp_path / "edited"
    shutil.copytree(folder, edited)
    set_energy(lambda e: e.__setitem__((0, 0), -0.5 if e[0, 0] != -0.5 else -0.25))(edited)
    result = _validate(edited)
    assert result.exit_code == 1 and "not this graph's" in " ".join(result.output.split()), result.output
    pair = keygen(tmp_path / "keys")
    for bad in (relabelled, edited):
        with pytest.raises(UnverifiedBundleError, match=r"affordance_energy\.npy: E_aff"):
            pack_bundle(bad, pair.private_key, tmp_path / f"{bad.name}.craft")
        assert not (tmp_path / f"{bad.name}.craft").exists()


def test_the_shipped_bundles_energies_are_their_graphs() -> None:
    from craft_e.runtime.kb.energy_check import check_energy_matches_graph

    folders = sorted(p.parent for p in (ROOT / "artifacts" / "kb").glob("*/manifest.json"))
    assert len(folders) >= 5
    for folder in folders:
        check_energy_matches_graph(load_bundle(folder, check_encoder=False))


def test_validate_and_pack_refuse_a_turtle_that_is_not_the_graphs(tmp_path: Path) -> None:
    """The runtime never reads graph.ttl, so loading cannot notice it is stale or edited; validate
    regenerates it from graph.json (byte for byte what craftc writes) and pack refuses to sign it.
    A signed package is checked on what it holds."""
    folder = make_bundle(tmp_path / "kb")
    pair = keygen(tmp_path / "keys")
    package = pack_bundle(folder, pair.private_key, tmp_path / "kb.craft").out
    result = CliRunner().invoke(craftc_app, ["validate", str(package), "--trusted-key", str(pair.public_key)])
    assert result.exit_code == 0, result.output
    ttl = (folder / "graph.ttl").read_bytes()
    reseal(folder, "graph.ttl", ttl.replace(b"0.900000", b"0.100000"))
    load_bundle(folder, check_encoder=False)  # loading alone does not read the Turtle
    result = _validate(folder)
    assert result.exit_code == 1, result.output
    assert f"{folder / 'graph.ttl'}: is not the Turtle of graph.json" in " ".join(result.output.split())
    with pytest.raises(UnverifiedBundleError, match=r"graph\.ttl: is not the Turtle"):
        pack_bundle(folder, pair.private_key, tmp_path / "stale.craft")
    assert not (tmp_path / "stale.craft").exists()
