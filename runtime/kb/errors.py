"""The error every bundle check raises, in a module of its own.

Why: ``verify`` (hashes) and ``content`` (the files checked against each other) both raise it,
and ``verify`` runs ``content``; defining it in either would make the two import each other.
``verify`` and ``bundle`` re-export it, so ``from .verify import BundleError`` keeps working.
"""

from __future__ import annotations


class BundleError(RuntimeError):
    """A bundle cannot be trusted or read; the message names the file and the fix."""
