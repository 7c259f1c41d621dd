"""``craft serve``: the HTTP service (``app``) over a loaded bundle and ``Grounder``."""
