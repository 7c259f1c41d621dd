"""The installed package works outside a checkout (issue 13, item 6).

Builds a wheel of this checkout, installs it into a fresh virtual environment and, from a
temporary directory that holds nothing but a copied record cache and a tiny vocabulary, runs
``craftc build`` and ``craft ground`` with the wheel's console scripts. Prompts and JSON Schemas
must come from the wheel (package data) and every data path from configuration (the current
directory's ``artifacts/``), or the build fails.

The fresh environment reuses the project venv's third-party packages (torch, numpy, the encoder
weight packages) through a ``.pth`` path line — a plain path line, so the project venv's own
``.pth`` files, among them the editable install's finder, are *not* run and the checkout stays
unimportable; the test checks that ``craft_e`` is imported from the wheel.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VERB = "cut"
OBJECTS = ("knife", "scissors", "spoon")
RECORD_PROMPTS = ("verb_properties@v1", "object_properties@v1")
#: What the wheel is built from: pyproject's package-dir folders, the readme it names.
DIST_FILES = ("pyproject.toml", "README.md", "craft_e_pkg", "compiler", "runtime", "schemas", "prompts")


def copy_records(src: Path, dst: Path, subjects: set[str]) -> int:
    """The curated v1 records of ``subjects`` (a few files of the 80 MB cache)."""
    dst.mkdir(parents=True)
    n = 0
    for f in sorted(src.glob("*.json")):
        request = json.loads(f.read_text(encoding="utf-8"))["request"]
        if (request["provider"] == "curated" and request["prompt"] in RECORD_PROMPTS
                and request["subject"] in subjects):
            shutil.copy2(f, dst / f.name)
            n += 1
    return n


def run(args: list[str], cwd: Path, env: dict[str, str], timeout: int = 600) -> str:
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{args[0]} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
    return done.stdout


@pytest.mark.timeout(900)
def test_wheel_builds_and_grounds_outside_the_checkout(tmp_path: Path) -> None:
    dist, venv, work = tmp_path / "dist", tmp_path / "venv", tmp_path / "work"
    env = {k: v for k, v in os.environ.items()
           if k not in ("CRAFT_ARTIFACTS", "CRAFT_CACHE", "PYTHONPATH", "VIRTUAL_ENV")}
    env.update(HF_HUB_OFFLINE="1", TRANSFORMERS_OFFLINE="1", COLUMNS="200")

    # 1. a wheel of this checkout, without the network (setuptools from the project venv), built
    #    from a copy of the distribution's files so no stale build/ folder can leak into it
    source = tmp_path / "source"
    source.mkdir()
    for name in DIST_FILES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(ROOT / name, source / name)
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--quiet",
         "-w", str(dist), str(source)], cwd=tmp_path, env=env)
    (wheel,) = dist.glob("craft_e-*.whl")

    # 2. a fresh venv that sees the project venv's third-party packages, then the wheel in it
    run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=tmp_path, env=env)
    new_python = venv / "bin" / "python"
    purelib = Path(run([str(new_python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                       cwd=tmp_path, env=env).strip())
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (purelib / "_project_deps.pth").write_text("\n".join(sorted(deps)) + "\n", encoding="utf-8")
    run([sys.executable, "-m", "pip", "--python", str(new_python), "install", "--quiet", "--no-deps",
         "--no-index", str(wheel)], cwd=tmp_path, env=env)

    # 3. a working directory with only a copied record cache and a tiny vocabulary
    cache = work / "artifacts" / "cache"
    assert copy_records(ROOT / "artifacts/cache/llm", cache / "llm", {VERB, *OBJECTS}) >= 1 + len(OBJECTS)
    for derived in ("embeddings", "encoders"):  # content-addressed; copied only to save time
        if (ROOT / "artifacts/cache" / derived).is_dir():
            shutil.copytree(ROOT / "artifacts/cache" / derived, cache / derived)
    (work / "verbs.txt").write_text(VERB + "\n", encoding="utf-8")
    (work / "objects.txt").write_text("\n".join(OBJECTS) + "\n", encoding="utf-8")

    where = run([str(new_python), "-c",
                 "import craft_e, craft_e.compiler.prompts as p, craft_e.schemas.generate as g\n"
                 "print(craft_e.__file__); print(p.PROMPTS_DIR); print(g.SCHEMA_DIR)"], cwd=work, env=env)
    for line in where.split():
        assert Path(line).resolve().is_relative_to(venv.resolve()), where  # the wheel, not the checkout

    # 4. craftc build: prompts from the wheel, records and output under ./artifacts by default
    run([str(venv / "bin" / "craftc"), "build", "--verbs", "verbs.txt", "--objects", "objects.txt",
         "--prompts", "v1", "--name", "tiny", "--quiet"], cwd=work, env=env)
    bundle = work / "artifacts" / "kb" / "tiny"
    assert (bundle / "manifest.json").is_file() and (bundle / "graph.json").is_file()

    # 5. craft ground against the built bundle
    from PIL import Image

    image = Image.new("RGB", (96, 48), (200, 200, 200))
    image.paste((40, 40, 40), (4, 8, 44, 40))
    image.paste((160, 60, 30), (52, 8, 92, 40))
    image.save(work / "scene.png")
    run([str(venv / "bin" / "craft"), "ground", "--kb", str(bundle), "--verb", VERB, "--image", "scene.png",
         "--box", "4,8,40,32", "--box", "52,8,40,32", "--vocab", "objects.txt", "--threads", "1",
         "--json", "ground.json"], cwd=work, env=env)
    result = json.loads((work / "ground.json").read_text(encoding="utf-8"))
    assert result["verb"] == VERB and result["kb"].startswith("tiny@")
    assert result["chosen"] in (0, 1) and sorted(r["index"] for r in result["ranked"]) == [0, 1]
    assert {h["object"] for r in result["ranked"] for h in r["hypotheses"]} <= set(OBJECTS)
