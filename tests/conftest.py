"""Shared fixtures for the compiler tests.

The knowledge used here is a *test fixture*: tiny answer files in ``tests/fixtures/kb_small``,
written for the project's own prompts and stored as records in a temporary cache under provider
``test-fixture`` (never ``curated``, never in ``artifacts/``). Loading the text encoder costs a
few seconds, so the base bundle is built once per session and every later build starts from a
copy of its cache, whose embeddings are already computed.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import shutil
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from craft_e.compiler.build import BuildConfig
    from craft_e.compiler.sources.llm import LLMSource
    from craft_e.runtime.evaluation.sim_eval import EpisodeSpec
    from craft_e.runtime.sim.gripper import GripperConfig
    from craft_e.runtime.sim.robot import CR3Robot

# The package finds artifacts/ through configuration (craft_e.paths: $CRAFT_ARTIFACTS, default
# ./artifacts); the suite pins it to this checkout's folder so pytest may run from any directory.
# Set before any craft_e module is imported (conftest is imported first).
os.environ.setdefault("CRAFT_ARTIFACTS", str(Path(__file__).resolve().parents[1] / "artifacts"))

FIXTURES = Path(__file__).resolve().parent / "fixtures"
KB_SMALL = FIXTURES / "kb_small"
PROVIDER = "test-fixture"
MODEL = "fixture-v1"
KB_NAME = "fixture-kb"
NOTE = "test fixture from tests/fixtures/kb_small (not knowledge to ship)"


def fixture_source(cache_root: Path) -> LLMSource:
    """An ``LLMSource`` over ``cache_root`` that reads and writes fixture records."""
    from craft_e.compiler.cache import RecordCache
    from craft_e.compiler.sources.llm import LLMSource

    return LLMSource(RecordCache(cache_root), provider=PROVIDER, model=MODEL)


def record_fixture(
    cache_root: Path,
    prompt: str,
    answers: str,
    verbs: str = "verbs.txt",
    objects: str = "objects.txt",
) -> None:
    """Store the answers of ``tests/fixtures/kb_small/<answers>`` as records of their prompts
    (``replace``: a fixture may revise an answer in its own cloned cache, to build a changed KB)."""
    from craft_e.compiler.curate import record_answers
    from craft_e.compiler.vocab import read_vocabulary

    result = record_answers(
        fixture_source(cache_root),
        prompt,
        KB_SMALL / answers,
        read_vocabulary(KB_SMALL / verbs, kind="verbs").names,
        read_vocabulary(KB_SMALL / objects, kind="objects").names,
        note=NOTE,
        version="v1",
        replace=True,
    )
    assert not result.skipped, result.skipped


def build_config(
    cache_root: Path,
    out: Path,
    verbs: str = "verbs.txt",
    objects: str = "objects.txt",
) -> BuildConfig:
    """The ``BuildConfig`` of a fixture build (replaying ``test-fixture`` records)."""
    from craft_e.compiler.build import BuildConfig

    return BuildConfig(
        verbs_file=KB_SMALL / verbs,
        objects_file=KB_SMALL / objects,
        out=out,
        name=KB_NAME,
        provider=PROVIDER,
        model=MODEL,
        cache_root=cache_root,
        prompt_version="v1",
    )


@dataclass(frozen=True)
class FixtureKB:
    """A built fixture bundle and the cache it was built from (treat both as read-only)."""

    cache: Path
    bundle: Path
    embedding_misses: int
    embedding_hits: int


def _build(
    cache: Path, out: Path, verbs: str = "verbs.txt", objects: str = "objects.txt"
) -> FixtureKB:
    from craft_e.compiler.build import build

    result = build(build_config(cache, out, verbs, objects))
    return FixtureKB(cache, out, result.embedding_misses, result.embedding_hits)


@pytest.fixture(scope="session")
def kb_a(tmp_path_factory: pytest.TempPathFactory) -> FixtureKB:
    """The base fixture bundle: verbs cut/scoop/pour, objects knife/spoon/bowl/cup (cold build)."""
    root = tmp_path_factory.mktemp("kb_a")
    record_fixture(root / "cache", "verb_properties", "verb_properties.jsonl")
    record_fixture(root / "cache", "object_properties", "object_properties.jsonl")
    return _build(root / "cache", root / "bundle")


@pytest.fixture(scope="session")
def clone_cache(kb_a: FixtureKB) -> Callable[[Path], Path]:
    """Copy the base cache (records + warm embeddings) to a new folder and return it."""

    def clone(dest: Path) -> Path:
        shutil.copytree(kb_a.cache, dest)
        return dest

    return clone


@pytest.fixture(scope="session")
def kb_scoop_v2(
    tmp_path_factory: pytest.TempPathFactory, clone_cache: Callable[[Path], Path]
) -> FixtureKB:
    """The base bundle after a revised answer for "scoop": its top-1 flips spoon -> cup."""
    root = tmp_path_factory.mktemp("kb_scoop_v2")
    cache = clone_cache(root / "cache")
    record_fixture(cache, "verb_properties", "scoop_v2.verb_properties.jsonl")
    return _build(cache, root / "bundle")


@pytest.fixture(scope="session")
def kb_b2(
    tmp_path_factory: pytest.TempPathFactory, clone_cache: Callable[[Path], Path]
) -> FixtureKB:
    """Structural change: verb "pour" removed, object "cup" replaced by "ladle"."""
    root = tmp_path_factory.mktemp("kb_b2")
    cache = clone_cache(root / "cache")
    record_fixture(
        cache,
        "object_properties",
        "ladle.object_properties.jsonl",
        "verbs_b2.txt",
        "objects_b2.txt",
    )
    return _build(cache, root / "bundle", "verbs_b2.txt", "objects_b2.txt")


def bundle_bytes(folder: Path) -> dict[str, bytes]:
    """Every file of a bundle folder by name."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.fixture(scope="module")
def bare_robot() -> Iterator[Callable[..., CR3Robot]]:
    """Make CR3 robots alone in their own pybullet clients (gravity on, no table or scene), for
    tests of the arm and the hands; every client is closed when the module's tests are done."""
    import pybullet as p

    from craft_e.runtime.sim.robot import CR3Robot

    clients: list[int] = []

    def make(gripper_config: GripperConfig | None = None) -> CR3Robot:
        client = p.connect(p.DIRECT)
        clients.append(client)
        p.setGravity(0, 0, -9.81, physicsClientId=client)

        made: list[CR3Robot] = []

        def step(n: int) -> None:  # as SimEnv.step: the hand's linkage is held before each step
            for _ in range(n):
                if made:
                    made[0].gripper.hold_linkage()
                p.stepSimulation(physicsClientId=client)

        robot = CR3Robot(client, step, gripper_config=gripper_config)
        made.append(robot)
        return robot

    try:
        yield make
    finally:
        for client in clients:
            p.disconnect(physicsClientId=client)


def episode_spec(labels_path: Path, episode_id: str, seed: int = 0) -> EpisodeSpec:
    """One episode of a sim labels file by its id (``verb/object/layout``), built alone: its pair
    only, its layout only (``make_episode_specs(only_layout=)``), the same scene the full run builds."""
    import dataclasses

    from craft_e.runtime.evaluation.sim_eval import load_sim_labels, make_episode_specs

    verb, obj, layout = episode_id.rsplit("/", 2)
    labels = load_sim_labels(labels_path)
    pairs = tuple(p for p in labels.pairs if (p.verb, p.object) == (verb, obj))
    (spec,) = make_episode_specs(dataclasses.replace(labels, pairs=pairs), seed=seed, only_layout=int(layout))
    assert spec.id == episode_id, spec.id
    return spec


def load_script(path: Path) -> ModuleType:
    """Import a script of scripts/ or benchmarks/ (no package, maybe no .py suffix) as a module,
    to call its functions. It is in ``sys.modules`` only while it runs: its dataclasses look
    their module up while they are built. Its folder is on ``sys.path`` while it loads, as when
    it runs as a program, so that it can import its neighbours (``benchmarks/dev_scenes.py``)."""
    name = path.name.removesuffix(".py")
    loader = importlib.machinery.SourceFileLoader(name, str(path))
    spec = importlib.util.spec_from_loader(name, loader)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    sys.path.insert(0, str(path.parent))
    try:
        loader.exec_module(module)
    finally:
        sys.modules.pop(name, None)
        sys.path.remove(str(path.parent))
    return module
