"""ConSE image encoder: ImageNet class probabilities mapped into the text embedding space.

No CLIP weights can be had offline, so ``phi_I`` is built from parts that can: an EfficientNet-Lite
classifier (Lite1 by default, Lite0 on request) gives ``p(y | x)`` over the 1000 ImageNet classes,
and (Norouzi et al., ICLR 2014, "ConSE")

    phi_I(x) = normalize( sum_{t <= k} p(y_t | x) * phi_T(name(y_t)) / sum_{t <= k} p(y_t | x) )

over the top-k classes, with ``phi_T`` the bundle's text encoder (MiniLM). The result lives in the
bundle's text space, so the paper's cosines against object names and verb queries apply
unchanged. The 1000 class-name embeddings are computed once and cached as safetensors under
``artifacts/cache/encoders/`` (keyed by text encoder id, its weights hash and the class list
hash), never pickled.

Each class name is read in its sense, as the vocabulary's names are (``grounding/senses.py``): its
embedding is the unit mean of the name's and its WordNet 3.0 gloss's (``imagenet_glosses.tsv``,
``scripts/make_class_glosses.py``), the gloss weighing ``sense_weight``. A bare class name is
ambiguous ("crane": the bird and the machine; "cup": a punch) and sits where MiniLM puts the word;
its gloss says what the classifier's class is, in the words the vocabulary's glosses use. On the
dev data (``docs/recognition.md``, "Class names read in their sense") it raised the renders'
top-1 and the sim-dev choices. ``sense_weight`` 0 reads the bare names (every result stored
before 2026-12-06, session 33).

ConSE's weights are the classifier's probabilities at a softmax temperature (``temperature``,
default 2: ``p(y | x) ** (1 / T)`` renormalised over the top-k, i.e. ``softmax(logits / T)``
restricted to them). On rendered and cluttered objects, outside ImageNet's photographs, the
classifier often puts most of its mass on one look-alike class ("ballpoint" for a knife); at
T = 2 the runner-up classes, which often name the object's kind, weigh more in the mean. Chosen
on the dev data (``docs/recognition.md``, "ConSE's weights at temperature 2"); ``temperature`` 1
is ConSE's own weighting (every result stored before 2026-12-06, session 34).
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import os
from collections.abc import Callable, Sequence
from functools import cache
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ...paths import CACHE_DIR
from .image import FloatArray, UInt8Image, resize_center_crop, resize_fit
from .text import (
    MINILM_DIM,
    MINILM_ID,
    MINILM_SHA256,
    EncoderError,
    load_text_encoder,
    sense_mean,
)

if TYPE_CHECKING:
    from torch import nn

CONSE_TOP_K = 10
ENCODER_CACHE_DIR = CACHE_DIR / "encoders"
CLASSES_FILE = "imagenet_classes.txt"
GLOSSES_FILE = "imagenet_glosses.tsv"
#: How much of a class name's embedding is its gloss's: the weight the vocabulary's names are read
#: with by default (``grounding.settings.DEFAULT_SENSE_WEIGHT``, kept equal by a test), so both
#: sides of ConSE's cosine read names the same way. ``GroundingSettings.sense_weight`` sets both.
DEFAULT_CLASS_SENSE_WEIGHT = 0.5
#: The classifier's softmax temperature for ConSE's weights (module docstring): 1 is the paper's
#: ConSE; 2 chosen on the dev renders, the sim-dev scenes and the ImageNet dev labels.
DEFAULT_CONSE_TEMPERATURE = 2.0
PREPROCESS = ("center", "fit")
#: How the robot reads its ROI crops: whole and square, context included (``fit``; chosen on
#: ``craft eval recognition``, docs/recognition.md). The testbed's encoder
#: (``sim_eval.default_encoder``) and ``craft serve``'s ``POST /perceive`` both read it here.
ROBOT_PREPROCESS = "fit"


@cache
def imagenet_class_names() -> tuple[str, ...]:
    """The 1000 ImageNet-1k class names in logit order (the common short names; two 'crane's
    and two 'maillot's, as in the original synsets)."""
    text = resources.files("craft_e.runtime.encoders").joinpath(CLASSES_FILE).read_text("utf-8")
    names = tuple(line.strip() for line in text.splitlines() if line.strip())
    if len(names) != 1000:
        raise EncoderError(f"{CLASSES_FILE}: {len(names)} class names, expected 1000")
    return names


@cache
def imagenet_class_index() -> dict[str, int]:
    """Each class name's index in logit order (a name two classes share: the first), built once:
    requests and answers name classes, the runtime carries indices."""
    index: dict[str, int] = {}
    for i, name in enumerate(imagenet_class_names()):
        index.setdefault(name, i)
    return index


@cache
def imagenet_class_glosses() -> tuple[str, ...]:
    """The 1000 classes' WordNet 3.0 glosses in logit order (``imagenet_glosses.tsv``: wnid,
    class name, gloss; its names are checked against ``imagenet_classes.txt`` line by line)."""
    text = resources.files("craft_e.runtime.encoders").joinpath(GLOSSES_FILE).read_text("utf-8")
    return parse_class_glosses(text, imagenet_class_names())


def parse_class_glosses(text: str, names: Sequence[str]) -> tuple[str, ...]:
    """The glosses of ``imagenet_glosses.tsv``'s ``text``, one per class of ``names`` in order;
    ``EncoderError`` naming the file, the line and the fix for any line that does not fit."""
    glosses: list[str] = []
    for n, line in enumerate(text.splitlines(), start=1):
        fields = line.split("\t")
        if len(fields) != 3 or not fields[2].strip():
            raise EncoderError(f"{GLOSSES_FILE} line {n}: expected 'wnid<TAB>class name<TAB>gloss'; "
                               "regenerate it with scripts/make_class_glosses.py")
        if n > len(names) or fields[1] != names[n - 1]:
            expected = names[n - 1] if n <= len(names) else "no class"
            raise EncoderError(f"{GLOSSES_FILE} line {n}: class {fields[1]!r}, {CLASSES_FILE} has "
                               f"{expected!r} there; regenerate it with scripts/make_class_glosses.py")
        glosses.append(fields[2].strip())
    if len(glosses) != len(names):
        raise EncoderError(f"{GLOSSES_FILE}: {len(glosses)} glosses, expected {len(names)}")
    return tuple(glosses)


def check_sense_weight(sense_weight: float) -> float:
    """``sense_weight`` as a float in [0, 1], else ``ValueError`` naming it."""
    w = float(sense_weight)
    if not 0.0 <= w <= 1.0:  # also rejects NaN
        raise ValueError(f"sense_weight must be in [0, 1], got {sense_weight}")
    return w


def check_temperature(temperature: float) -> float:
    """``temperature`` as a float, or ``ValueError`` naming it: finite and > 0."""
    value = float(temperature)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"temperature must be a finite number > 0, got {temperature!r}")
    return value


def _class_list_sha256(names: Sequence[str]) -> str:
    return hashlib.sha256("\n".join(names).encode()).hexdigest()


def class_embeddings_path(cache_dir: Path, text_id: str, text_sha256: str, names: Sequence[str]) -> Path:
    """Cache file of the class-name embeddings for one text encoder and one class list."""
    return cache_dir / f"imagenet1k-classes.{text_id}.{text_sha256[:12]}.{_class_list_sha256(names)[:12]}.safetensors"


def class_glosses_path(cache_dir: Path, text_id: str, text_sha256: str, glosses: Sequence[str]) -> Path:
    """Cache file of the class glosses' embeddings for one text encoder and one gloss list."""
    return cache_dir / f"imagenet1k-glosses.{text_id}.{text_sha256[:12]}.{_class_list_sha256(glosses)[:12]}.safetensors"


def load_class_embeddings(
    cache_dir: Path = ENCODER_CACHE_DIR,
    *,
    text_id: str = MINILM_ID,
    text_sha256: str = MINILM_SHA256,
    text_encoder: Any | None = None,
    sense_weight: float = DEFAULT_CLASS_SENSE_WEIGHT,
) -> FloatArray:
    """``[1000, d]`` unit embeddings of the class names read in their sense (``sense_weight`` of
    each is its gloss's; 0: the bare names), each part from the cache or computed and cached.

    A cache file whose metadata does not match (another encoder, class or gloss list) is
    recomputed, never trusted: cosines across embedding spaces are meaningless.
    """
    w = check_sense_weight(sense_weight)
    names = imagenet_class_names()
    path = class_embeddings_path(cache_dir, text_id, text_sha256, names)
    meta = {"text_encoder": text_id, "weights_sha256": text_sha256,
            "classes_sha256": _class_list_sha256(names)}
    loaded: list[Any] = []

    def encoder() -> Any:  # loaded once even when both parts are computed
        if not loaded:
            loaded.append(text_encoder if text_encoder is not None else load_text_encoder(text_id))
        return loaded[0]

    emb = cached_text_embeddings(path, meta, "class_embeddings", names, encoder, batched=True)
    if w == 0:
        return emb
    glosses = imagenet_class_glosses()
    gloss_meta = {"text_encoder": text_id, "weights_sha256": text_sha256,
                  "glosses_sha256": _class_list_sha256(glosses)}
    gloss_emb = cached_text_embeddings(class_glosses_path(cache_dir, text_id, text_sha256, glosses),
                                       gloss_meta, "gloss_embeddings", glosses, encoder, batched=True)
    return sense_mean(emb, gloss_emb, w)


def cached_text_embeddings(path: Path, meta: dict[str, str], tensor: str, texts: Sequence[str],
                           encoder: Callable[[], Any], *, batched: bool) -> FloatArray:
    """``[n, d]`` embeddings of ``texts`` read from the safetensors file ``path`` when its stored
    ``meta`` matches (the encoder's identity and the texts' hash), else computed with
    ``encoder()`` (called only then) and cached. A file that does not match is recomputed, never
    trusted; the cache is best effort (an unwritable folder costs the next process the
    computation, never the answer, and leaves no ``.tmp``). ``batched``: the encoder's batched
    pass where it has one (its last bits depend on the batch: runtime caches only), else one
    text per pass (each text's vector independent of the others)."""
    from safetensors.numpy import load_file, save_file

    if path.is_file():
        from safetensors import SafetensorError, safe_open

        try:
            with safe_open(str(path), framework="numpy") as handle:
                stored = json.loads((handle.metadata() or {}).get("key", "{}"))
            emb = load_file(str(path)).get(tensor)
        except (OSError, SafetensorError, ValueError):  # a damaged cache file: recomputed
            stored, emb = None, None
        if stored == meta and emb is not None and emb.shape[0] == len(texts):
            return np.asarray(emb, dtype=np.float32)
    model = encoder()
    in_batches = getattr(model, "embed_batched", None) if batched else None
    vecs = in_batches(list(texts)) if callable(in_batches) else model.embed(list(texts))
    emb = np.asarray(vecs, dtype=np.float32)  # [n, d]
    tmp = path.with_suffix(f".{os.getpid()}.tmp")  # processes filling one cache never share a file
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_file({tensor: emb}, str(tmp), metadata={"key": json.dumps(meta, sort_keys=True)})
        tmp.replace(path)
    except OSError:
        # a cache, not an input: a read-only or full cache folder costs the next process this
        # computation again, never the answer (every grounder of a MiniLM bundle reads the class
        # names for its hubness correction, grounding/hubness.py, even where no image is encoded)
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
    return emb


def conse_embed(probs: npt.NDArray[np.floating[Any]], class_emb: FloatArray, top_k: int = CONSE_TOP_K,
                temperature: float = 1.0) -> FloatArray:
    """ConSE: probability-weighted mean of the top-k class embeddings, renormalized.

    ``probs`` ``[N, C]``, ``class_emb`` ``[C, d]`` -> ``[N, d]`` unit vectors. ``temperature``
    ``T``: the weights are ``probs ** (1 / T)`` over the top-k (the classifier's softmax at
    ``T``, renormalised there; the top-k are the same classes at any ``T``); 1 is ConSE's own.
    """
    p = np.asarray(probs, dtype=np.float64)  # [N, C]
    k = min(top_k, p.shape[1])
    idx = np.argpartition(-p, k - 1, axis=1)[:, :k]  # [N, k] top-k classes (unordered)
    w = np.take_along_axis(p, idx, axis=1)  # [N, k]
    if temperature != 1.0:  # at 1, no power at all: the same bits as before the temperature
        w = w ** (1.0 / check_temperature(temperature))
    w = w / np.maximum(w.sum(axis=1, keepdims=True), 1e-12)
    emb = np.einsum("nk,nkd->nd", w, class_emb.astype(np.float64)[idx])  # [N, d]
    emb /= np.maximum(np.linalg.norm(emb, axis=1, keepdims=True), 1e-12)
    out: FloatArray = emb.astype(np.float32)
    return out


#: One crop's most probable ImageNet classes: (class index, probability), most probable first.
ClassTop = tuple[tuple[int, float], ...]
#: How many classes an ROI carries (the look-alike cue reads them; ConSE's own top-k is the same).
CLASS_TOP_K = 10


def top_classes(probs: npt.NDArray[np.floating[Any]], k: int = CLASS_TOP_K) -> list[ClassTop]:
    """The ``k`` most probable classes of each row of ``probs`` ``[N, C]``, most probable first
    (ties by class index)."""
    p = np.asarray(probs, dtype=np.float64)
    order = np.argsort(-p, axis=1, kind="stable")[:, :k]  # [N, k]
    return [tuple((int(j), float(p[i, j])) for j in row) for i, row in enumerate(order.tolist())]


def encode_with_classes(encoder: Any, crops: Sequence[UInt8Image]) -> tuple[FloatArray, list[ClassTop | None]]:
    """``encoder.embed_images(crops)`` and, for an encoder with ImageNet class probabilities
    (ConSE), each crop's top classes from the same forward pass (the embeddings are the same
    bits: ConSE embeds exactly these probabilities). Other encoders: ``None`` per crop."""
    if len(crops) == 0:
        return np.zeros((0, int(encoder.dim)), dtype=np.float32), []
    probabilities = getattr(encoder, "class_probabilities", None)
    embed = getattr(encoder, "embed_probabilities", None)
    if not (callable(probabilities) and callable(embed)):
        return np.asarray(encoder.embed_images(crops), dtype=np.float32), [None] * len(crops)
    probs = probabilities(crops)
    classes: list[ClassTop | None] = list(top_classes(probs))
    return np.asarray(embed(probs), dtype=np.float32), classes


def check_crop(preprocess: str, tta: int) -> None:
    """ValueError unless ``preprocess`` and ``tta`` name a crop ``ConSEImageEncoder`` makes."""
    if preprocess not in PREPROCESS:
        raise ValueError(f"preprocess must be one of {', '.join(PREPROCESS)}, got {preprocess!r}")
    if tta not in (1, 2):
        raise ValueError(f"tta must be 1 (none) or 2 (+ mirror image), got {tta}")


class ConSEImageEncoder:
    """EfficientNet-Lite (``classifier``) + MiniLM class names -> ``[N, 384]`` image embeddings (ConSE).

    ``classifier``: ``efficientnet-lite1`` (the default) or ``efficientnet-lite0`` (the encoder
    of every result before 2026-12-04; ``docs/recognition.md`` compares them). Crops are resized
    to the classifier's own training resolution (Lite1 240, Lite0 224). ``sense_weight``: how the
    class names are read; ``temperature``: the classifier's softmax temperature for ConSE's
    weights (module docstring); None: their defaults. The ``id`` says all three.

    ``threads`` caps torch's intra-op threads during forward passes: on a busy 2-core host one
    thread was measured at ~65 ms per image against 0.2-2.4 s with two contending threads.
    """

    text_encoder_id = MINILM_ID
    dim = MINILM_DIM

    def __init__(
        self,
        top_k: int = CONSE_TOP_K,
        *,
        cache_dir: Path = ENCODER_CACHE_DIR,
        weights: Path | None = None,
        text_encoder: Any | None = None,
        threads: int | None = None,
        preprocess: str = "center",
        tta: int = 1,
        classifier: str | None = None,
        sense_weight: float | None = None,
        temperature: float | None = None,
    ) -> None:
        import torch

        from .efficientnet import DEFAULT_CLASSIFIER, load_efficientnet, variant

        if top_k < 1:
            raise ValueError(f"top_k must be >= 1, got {top_k}")
        check_crop(preprocess, tta)
        self.top_k = top_k
        self.preprocess = preprocess
        self.tta = tta
        self.threads = threads  # torch intra-op threads during forward passes (None: torch's default)
        self._torch = torch
        lite = variant(classifier or DEFAULT_CLASSIFIER)
        self.size = lite.resolution  # the classifier's input size
        self.resize = round(lite.resolution * 256 / 224)  # ``center``: short side, as 256 is for 224
        self.classifier: nn.Module = load_efficientnet(lite, weights)
        self.class_names = imagenet_class_names()
        # how the class names are read (None: the default, the vocabulary's own weight)
        self.sense_weight = check_sense_weight(DEFAULT_CLASS_SENSE_WEIGHT if sense_weight is None else sense_weight)
        self.class_embeddings = load_class_embeddings(cache_dir, text_encoder=text_encoder,
                                                      sense_weight=self.sense_weight)  # [1000, d]
        # the classifier's softmax temperature for ConSE's weights (None: the default)
        self.temperature = check_temperature(DEFAULT_CONSE_TEMPERATURE if temperature is None else temperature)
        self._lite = lite
        self._fused_twin: ConSEImageEncoder | None = None
        self.id = self._make_id()

    def _make_id(self) -> str:
        """The id that names every setting that changes an embedding (a cache key downstream)."""
        suffix = "" if (self.preprocess, self.tta) == ("center", 1) else (
            f"-{self.preprocess}" + ("-tta2" if self.tta == 2 else ""))
        return (f"conse-k{self.top_k}{suffix}:{self._lite.name}@{self._lite.sha256[:12]}"
                f"+{MINILM_ID}@{MINILM_SHA256[:12]}"
                + (f"+senses{self.sense_weight:g}" if self.sense_weight > 0 else "")
                + (f"+t{self.temperature:g}" if self.temperature != 1.0 else ""))

    def with_preprocess(self, preprocess: str, tta: int = 1) -> ConSEImageEncoder:
        """This encoder cropping another way (``preprocess``, ``tta``), sharing its classifier
        and class embeddings: a server that embeds caller boxes (``center``) and the robot's
        whole square crops (``fit``) holds one classifier and one table of class names, not
        two. Its ``id`` is what ``ConSEImageEncoder(preprocess=..., tta=...)`` with the other
        settings equal would give."""
        check_crop(preprocess, tta)
        if (preprocess, tta) == (self.preprocess, self.tta):
            return self
        fused = self._fused_twin is self  # this encoder is a fused twin: so is the new one
        twin = copy.copy(self)
        twin.preprocess = preprocess
        twin.tta = tta
        twin._fused_twin = twin if fused else None  # else built on demand, cropping as the twin does
        twin.id = twin._make_id() + ("+fused" if fused else "")
        return twin

    def class_probabilities(self, crops: Sequence[UInt8Image], batch_size: int = 16) -> npt.NDArray[np.float32]:
        """ImageNet softmax ``[N, 1000]`` for RGB crops of any size.

        ``preprocess`` ``center``: short side to 256, centre 224 for Lite0 (the ImageNet
        evaluation transform; 274 / 240 for Lite1); ``fit``: the whole crop resized to the
        classifier's size (224 x 224 for Lite0, 240 x 240 for Lite1; ROI crops are already square
        with context, so a centre crop would only cut the object). ``tta`` 2 averages the
        probabilities of the crop and its mirror image (one batch of 2N)."""
        torch = self._torch
        out = np.zeros((len(crops), len(self.class_names)), dtype=np.float32)
        previous = torch.get_num_threads()
        if self.threads:
            torch.set_num_threads(self.threads)
        try:
            for start in range(0, len(crops), max(1, batch_size)):
                part = crops[start : start + batch_size]
                chunk = ([resize_center_crop(c, self.size, self.resize) for c in part] if self.preprocess == "center"
                         else [resize_fit(c, self.size) for c in part])
                x = torch.from_numpy(np.stack(chunk)).permute(0, 3, 1, 2).float()  # [B, 3, S, S]
                x = x / 127.5 - 1.0  # [-1, 1], the range the weights expect
                if self.tta == 2:
                    x = torch.cat([x, x.flip(3)])  # [2B, 3, S, S]: + mirror images
                with torch.inference_mode():
                    probs = self.classifier(x).softmax(dim=-1)  # [B or 2B, 1000]
                if self.tta == 2:
                    probs = (probs[: len(chunk)] + probs[len(chunk) :]) / 2
                out[start : start + len(chunk)] = probs.numpy()
        finally:
            if self.threads:
                torch.set_num_threads(previous)
        return out

    def fused(self) -> ConSEImageEncoder:
        """This encoder with the classifier's inference rewrite (``encoders.fused``: batch norm
        folded, channels-last; the same embeddings to float rounding), built once and shared
        with this encoder's class embeddings. Its ``id`` says so."""
        twin = self._fused_twin
        if twin is None:
            from .efficientnet import EfficientNetLite
            from .fused import FusedEfficientNetLite

            assert isinstance(self.classifier, EfficientNetLite)
            twin = copy.copy(self)
            twin.classifier = FusedEfficientNetLite.from_reference(self.classifier, self.size)
            twin.id = f"{self.id}+fused"
            twin._fused_twin = twin
            self._fused_twin = twin
        return twin

    def top_classes(self, crops: Sequence[UInt8Image], k: int = 5) -> list[list[tuple[str, float]]]:
        """The k most probable class names per crop, for inspection and sanity checks."""
        probs = self.class_probabilities(crops)
        order = np.argsort(-probs, axis=1)[:, :k]
        return [[(self.class_names[j], float(probs[i, j])) for j in row] for i, row in enumerate(order)]

    def embed_probabilities(self, probs: npt.NDArray[np.floating[Any]]) -> FloatArray:
        """ConSE embeddings ``[N, d]`` from precomputed class probabilities ``[N, 1000]``."""
        return conse_embed(probs, self.class_embeddings, self.top_k, self.temperature)

    def embed_images(self, crops: Sequence[UInt8Image], batch_size: int = 16) -> FloatArray:
        """``[N, 384]`` unit vectors in MiniLM space for ``N`` RGB uint8 crops."""
        if len(crops) == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        return self.embed_probabilities(self.class_probabilities(crops, batch_size))
