"""Version 1 of the CRAFT-E artifact schemas (records, payloads, bundle manifest, report)."""

from .bundle import (
    BUNDLE_FILES,
    BuildInfo,
    BundleReport,
    FileDigest,
    Manifest,
    SourceInfo,
    TextEncoderInfo,
)
from .payloads import (
    ObjectProperties,
    PropertyScore,
    RankedObject,
    ScoredProperty,
    VerbObjects,
    VerbProperties,
)
from .records import Record, RecordRequest

SCHEMA_VERSION = 1

__all__ = [
    "BUNDLE_FILES",
    "SCHEMA_VERSION",
    "BuildInfo",
    "BundleReport",
    "FileDigest",
    "Manifest",
    "ObjectProperties",
    "PropertyScore",
    "RankedObject",
    "Record",
    "RecordRequest",
    "ScoredProperty",
    "SourceInfo",
    "TextEncoderInfo",
    "VerbObjects",
    "VerbProperties",
]
